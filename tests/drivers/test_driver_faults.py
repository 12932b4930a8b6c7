"""Fault cases of the serial drivers, beside the unplug and silent-device ones of each
driver's tests: stray bytes on the line, a port another program opens, a controller
that went on moving while the host was away, homing at open within the caller's
timeout, one silent device on a Zaber chain. Each must end in a clear error or in
normal operation, never in a hang.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import threading
import time

import pytest
import serial

from drivers.errors import DeviceCancelledError, DeviceDisconnectedError
from drivers.thorlabs_apt import ThorlabsAptStage
from drivers.thorlabs_apt_protocol import AptFramer
from drivers.transports import port_holders
from drivers.zaber_ascii import ZaberAsciiStage
from tests.mocks import AptEmulator, ZaberEmulator

Z8 = 34554.96
#: Five bytes the old framer took for a header (id 0x2211, data flag, length 64, to the
#: host, and the next byte, 0x2A, as a bay's source): it waited for 64 bytes and
#: swallowed the reply behind them.
POSING_AS_HEADER = bytes([0x11, 0x22, 0x40, 0x00, 0x81])


@pytest.fixture
def apt(tmp_path):
    emu = AptEmulator("kdc101", serial_number=27000001, time_scale=20.0, update_period_s=0.01,
                      link=tmp_path / "usb-Thorlabs_Brushed_Motor_Controller_27000001-if00-port0")
    with emu:
        yield emu


#: A reply that should come at once may take this long: a hang guard, never the verdict
#: (a loaded host answers seconds late); a lost reply still fails, only later.
HANG_GUARD_S = 30.0


def apt_stage(tmp_path, **kw):
    kw.setdefault("limits_mm", {"z": [0.0, 25.0]})
    kw.setdefault("speed_mm_s", 2.0)
    return ThorlabsAptStage("stage", axes=["z"], serial_numbers={"z": "27000001"},
                            search_dirs=[str(tmp_path)], reply_timeout_s=HANG_GUARD_S, **kw)


# ------------------------------------------------------------------ stray bytes
def test_apt_stray_bytes_during_a_move_cost_no_reply(apt, tmp_path):
    with apt_stage(tmp_path, home_on_open=True) as stage:
        stage.move_to({"z": 8.0}, wait=False)
        for _ in range(5):
            apt.stray_before_reply(POSING_AS_HEADER)
            stage.position("z")  # answered despite the bytes before the reply
        apt.stray_before_reply(POSING_AS_HEADER)
        stage.wait_until_idle(timeout_s=20.0)
        assert apt.position() == round(8.0 * Z8)
        assert stage.status()["controllers"]["sn:27000001"]["resyncs"] >= 30


def test_apt_framer_refuses_what_is_not_for_the_host():
    framer = AptFramer()
    reply = bytes.fromhex("2A 04 06 00 81 50 01 00 00 04 00 80")  # GET_STATUSBITS
    to_a_bay = bytes.fromhex("2A 04 06 00 A1 01 01 00 00 04 00 80")  # host -> bay: not ours
    unknown = bytes.fromhex("99 09 06 00 81 50 00 00 00 00 00 00")  # no such inbound id
    wrong_length = bytes.fromhex("2A 04 09 00 81 50") + bytes(9)  # STATUSBITS is 6 bytes
    msgs = framer.feed(to_a_bay + unknown + wrong_length + POSING_AS_HEADER + reply)
    assert [(m.msg_id, m.source, len(m.data)) for m in msgs] == [(0x042A, 0x50, 6)]


def test_zaber_noise_before_a_reply(tmp_path):
    with ZaberEmulator({1: 1}, time_scale=100.0) as emu:
        with ZaberAsciiStage("stage", axes=["x"], port=emu.port, speed_mm_s=5.0,
                             require_homed=False, reply_timeout_s=HANG_GUARD_S) as stage:
            for noise in (b"\x13\x00garbage", b"\xff\xfe", b"@0"):
                emu.stray_before_reply(noise)
                assert stage.command(1, 1, "get pos")[0] == "IDLE"


# ------------------------------------------------------------------ stolen port
def _child(target, *args) -> int:
    """Fork a child that runs ``target(*args)`` and exits with its return value."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - runs in the child
        code = 1
        try:
            code = target(*args)
        finally:
            os._exit(code)
    return pid


HOLDER = ("import os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY); "
          "print('ready', flush=True); time.sleep(60)")  # a plain open, as others do


def _try_open(path: str) -> int:  # pragma: no cover - runs in the child
    if os.geteuid() == 0:  # root passes TIOCEXCL: open as an ordinary user instead
        os.setgid(65534)
        os.setuid(65534)
    try:
        os.close(os.open(path, os.O_RDWR | os.O_NOCTTY))
    except OSError as exc:
        return 10 if exc.errno == errno.EBUSY else 20
    return 0


def test_port_held_by_another_program_is_refused_naming_it(apt, tmp_path):
    thief = subprocess.Popen([sys.executable, "-c", HOLDER, apt.tty], stdout=subprocess.PIPE,
                             close_fds=True)
    try:
        assert thief.stdout.readline().strip() == b"ready"
        assert thief.pid in [p for p, _ in port_holders(apt.port)]
        with pytest.raises(DeviceDisconnectedError,
                           match=f"process {thief.pid}.*close that program"):
            apt_stage(tmp_path).open()
    finally:
        thief.kill()
        thief.wait(10)
    with apt_stage(tmp_path) as stage:  # free again
        stage.position("z")


def test_port_open_here_cannot_be_opened_by_another_program(apt, tmp_path):
    os.chmod(apt.tty, 0o666)  # so only the exclusive mode can stop the other user
    with apt_stage(tmp_path) as stage:
        pid = _child(_try_open, apt.tty)
        _, status = os.waitpid(pid, 0)
        assert os.waitstatus_to_exitcode(status) == 10  # EBUSY (TIOCEXCL)
        for _ in range(20):
            stage.position("z")  # every reply still comes here
    pid = _child(_try_open, apt.tty)  # closed: the mode is released with the port
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_a_second_exclusive_opener_in_this_process_is_refused(apt, tmp_path):
    with apt_stage(tmp_path):
        with pytest.raises(serial.SerialException):
            serial.Serial(apt.tty, exclusive=True)


# ------------------------------------------------------------------ moving after reconnect
def test_apt_moving_after_reconnect_is_stopped_and_reported(apt, tmp_path, caplog):
    stage = apt_stage(tmp_path, home_on_open=True, speed_mm_s=0.5)
    stage.open()
    try:
        stage.move_to({"z": 20.0}, wait=False)  # 40 s of motion, 2 s at time_scale 20
        deadline = time.monotonic() + 5.0  # the move command reached the controller
        while apt.channels[0x50].motion is None and time.monotonic() < deadline:
            time.sleep(0.005)
        assert apt.channels[0x50].motion is not None
        apt.unplug()
        with pytest.raises(DeviceDisconnectedError):
            stage.wait_until_idle(timeout_s=30.0)
        time.sleep(0.1)
        apt.replug()
        assert apt.channels[0x50].motion is not None  # the controller went on moving
        with apt.lock:
            apt.received.clear()
        stage.reconnect()
        assert apt.channels[0x50].motion is None  # stopped at open
        with apt.lock:
            sent = bytes(apt.received)
        # MGMSG_MOT_MOVE_STOP, channel 1, stop mode 2: profiled (1 would be immediate)
        assert bytes.fromhex("65 04 01 02 50 01") in sent
        assert bytes.fromhex("65 04 01 01 50 01") not in sent
        stopped = stage.status()["stopped_at_open"]["z"]
        assert 0.0 < stopped < 20.0
        assert stage.position("z") == pytest.approx(apt.position() / Z8, abs=1e-6)
        assert stage.position("z") == pytest.approx(stopped, abs=1e-6)  # not drifting
        assert "were moving when the stage opened" in caplog.text
        stage.move_to({"z": 1.0})
    finally:
        stage.close()


# ------------------------------------------------------------------ timeouts
def test_home_on_open_honours_home_timeout(apt, tmp_path):
    with apt.lock:  # the controller is homing slowly (its front panel, another program)
        ch = apt.channels[0x50]
        ch.position = 800_000.0
        ch.home_params = (2, 1, apt.velocity_units(0.05 * Z8, Z8)[0], 0)
        apt._start(ch, apt.now(), ch.travel[0], "home")
    stage = apt_stage(tmp_path, home_on_open=True, home_timeout_s=0.5)
    t0 = time.monotonic()
    with pytest.raises(stage.timeout_error, match="home_timeout_s = 0.5 s"):
        stage.open(timeout_s=60.0)
    assert 0.5 <= time.monotonic() - t0 < HANG_GUARD_S  # not the open's 60 s, nor 120 s
    assert apt.channels[0x50].motion.kind == "home"  # left homing, not stopped


def test_apt_home_on_open_within_the_opens_timeout_and_cancel(apt, tmp_path):
    """home_timeout_s is 120 s, but the caller's open(timeout_s) ends the wait, naming
    it; a cancel event set during the homing stops the axis and leaves it closed."""
    def homing_slowly():
        with apt.lock:
            ch = apt.channels[0x50]
            ch.position, ch.homed = 800_000.0, False
            ch.home_params = (2, 1, apt.velocity_units(0.05 * Z8, Z8)[0], 0)

    homing_slowly()
    stage = apt_stage(tmp_path, home_on_open=True)  # home_timeout_s: 120 s
    with pytest.raises(stage.timeout_error, match="within the open's timeout_s"):
        stage.open(timeout_s=0.5)
    assert not stage.is_open and apt.channels[0x50].motion.kind == "home"
    homing_slowly()
    with apt.lock:
        apt.channels[0x50].motion = None
    cancel = threading.Event()
    wait = stage._wait_homing_at_open

    def cancelled_once_homing(home_timeout_s):  # not a timer: on a loaded host it
        cancel.set()  # could fire before the homing, even before the open
        return wait(home_timeout_s)

    stage._wait_homing_at_open = cancelled_once_homing
    with pytest.raises(DeviceCancelledError, match="cancelled while homing"):
        stage.open(timeout_s=60.0, cancel=cancel)
    assert not stage.is_open
    with apt.lock:
        assert apt.channels[0x50].motion is None and not apt.channels[0x50].homed  # stopped


def test_zaber_silent_device_does_not_block_the_healthy_axes():
    with ZaberEmulator({1: 1, 2: 2}, time_scale=100.0) as emu:
        with ZaberAsciiStage("stage", axes=["x", "y", "z"], port=emu.port,
                             device_numbers={"x": 1, "y": 2, "z": 2}, axis_numbers={"z": 2},
                             speed_mm_s=5.0, home_on_open=True,
                             reply_timeout_s=HANG_GUARD_S) as stage:
            emu.silence(2)
            emu.commands.clear()
            t0 = time.monotonic()
            stage.move_to({"x": 4.0})
            stage.move_by({"x": -1.0})
            assert stage.position("x") == pytest.approx(3.0, abs=1e-4)
            assert time.monotonic() - t0 < HANG_GUARD_S
            asked = list(emu.commands)
            assert asked and not [c for c in asked if not c.startswith("/1 ")]  # no wait on 2
            stage._reply_timeout = 0.3  # the silent one's reply is waited for 0.3 s
            with pytest.raises(stage.timeout_error):
                stage.move_to({"y": 1.0})  # the silent one: a clear error, no hang
            emu.silence(2, False)
            stage.move_to({"y": 1.0})


def test_zaber_home_on_open_honours_home_timeout():
    with ZaberEmulator({1: 1}, time_scale=1.0) as emu:
        with emu.lock:
            emu.axis(1).position = 500_000.0  # 24 mm out, homing at 0.5 mm/s: ~48 s
        stage = ZaberAsciiStage("stage", axes=["x"], port=emu.port, speed_mm_s=0.5,
                                home_on_open=True, home_timeout_s=0.5,
                                reply_timeout_s=HANG_GUARD_S)
        t0 = time.monotonic()
        with pytest.raises(stage.timeout_error, match="home_timeout_s = 0.5 s"):
            stage.open(timeout_s=60.0)
        assert 0.5 <= time.monotonic() - t0 < HANG_GUARD_S  # not the open's 60 s
        assert emu.axis(1).motion is not None and emu.axis(1).motion.kind == "home"
