"""Zaber ASCII stage driver against the Zaber chain emulator on a pseudo-terminal."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.errors import (
    DeviceCancelledError,
    DeviceProtocolError,
    DeviceStateError,
    StageMotionError,
    StageTimeoutError,
)
from drivers.zaber_ascii import ZaberAsciiStage, lrc
from tests.drivers.conformance import StageConformance, unplug_mid_move
from tests.mocks import ZaberEmulator

STEP = 0.047625e-3  # mm per microstep
#: The longest a wait that should end at once may take: a hang guard, never the verdict
#: (a loaded host answers seconds late).
HANG_GUARD_S = 30.0


@pytest.fixture
def emulator(tmp_path):
    emu = ZaberEmulator({1: 1, 2: 2}, time_scale=100.0,
                        link=tmp_path / "usb-Zaber_Technologies_X-MCC_AB123-if00-port0")
    emu.start()
    yield emu
    emu.stop()


def make_stage(emu, **kw):
    kw.setdefault("axes", ["x", "y", "z"])
    kw.setdefault("device_numbers", {"x": 1, "y": 2, "z": 2})
    kw.setdefault("axis_numbers", {"z": 2})
    kw.setdefault("speed_mm_s", 5.0)
    kw.setdefault("reply_timeout_s", 30.0)  # a hang guard: a loaded host answers late
    return ZaberAsciiStage("mask", port=emu.port, **kw)


class TestZaberConformance(StageConformance):
    position_tolerance = 1e-4

    @pytest.fixture
    def device(self, emulator):
        self.emu = emulator
        stage = make_stage(emulator, home_on_open=True)
        stage.open()
        yield stage
        stage.close()

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)  # 1 s, not the fixture's 30


def test_checksum_example():
    assert lrc("01 tools echo") == "8F"


def test_byte_exact_commands_and_replies(emulator):
    with make_stage(emulator, axes=["x"], device_numbers={"x": 1}, axis_numbers=None,
                    home_on_open=True) as stage:
        emulator.commands.clear()
        emulator.sent.clear()
        stage.move_to({"x": 10.0})
        cmds = list(emulator.commands)
        move = next(c for c in cmds if "move" in c)
        body = move[1:move.index(":")]
        assert body.split(" ", 3)[3] == f"move abs {round(10.0 / STEP)}"
        assert move.endswith(":" + lrc(body))
        assert any(c.startswith("/1 1 ") and c.count(" ") == 2 for c in cmds)  # status poll
        replies = bytes(emulator.sent).decode().split("\r\n")
        mid = body.split()[2]
        assert f"@01 1 {mid} OK BUSY -- 0" in replies  # the move's immediate reply
        assert stage.velocity == {"x": 5.0}
    assert emulator.axis(1).maxspeed == round(5.0 / STEP * 1.6384)


def test_rejections_name_the_reason(emulator):
    with make_stage(emulator, home_on_open=True) as stage:
        with pytest.raises(DeviceProtocolError, match="BADCOMMAND"):
            stage.command(1, 1, "frobnicate")
        with pytest.raises(DeviceProtocolError, match="BADDATA.*out of range"):
            stage.command(1, 1, f"move abs {10**9}")
        with pytest.raises(DeviceProtocolError, match="BADAXIS"):
            stage.command(1, 3, "get pos")
        stage.move_to({"x": 1.0})  # still usable


def test_move_refused_until_homed(emulator):
    with make_stage(emulator) as stage:
        with pytest.raises(DeviceStateError, match="WR"):
            stage.move_to({"y": 2.0})
        stage.home()
        stage.move_to({"y": 2.0, "z": 3.0})
        assert stage.position("z") == pytest.approx(3.0, abs=STEP)
        assert stage.status()["warnings"] == {"x": [], "y": [], "z": []}


def test_limit_stall_and_interruption_flags(emulator):
    with make_stage(emulator, home_on_open=True) as stage:
        emulator.set_limit_switch(round(12.0 / STEP), device=2, axis=1)
        with pytest.raises(StageMotionError, match="WL .unexpected limit trigger. at 12 mm"):
            stage.move_to({"y": 20.0})
        emulator.set_limit_switch(None, device=2, axis=1)
        stage.move_to({"y": 20.0})  # warnings were cleared
        # moves of tens of seconds (at time_scale 100): still under way when the stall and
        # the other client's move come, however late a loaded host runs the next line
        stage.velocity = {"x": 0.02}
        stage.move_to({"x": 30.0}, wait=False)
        assert emulator.axis(1).motion is not None
        emulator.stall(1, 1)
        with pytest.raises(StageMotionError, match="FS .stalled and stopped."):
            stage.wait_until_idle()
        stage.move_to({"x": 5.0}, wait=False)
        assert emulator.axis(1).motion is not None
        stage.command(1, 1, "move abs 0")  # another client replaces the move: NI
        with pytest.raises(StageMotionError, match="NI"):
            stage.wait_until_idle()


def test_silent_device_times_out_with_kind_error(emulator):
    with make_stage(emulator, home_on_open=True, reply_timeout_s=1.0) as stage:
        emulator.silence(2)
        t0 = time.monotonic()
        with pytest.raises(stage.timeout_error, match="reply to '/2 1"):
            stage.positions()
        assert 1.0 <= time.monotonic() - t0 < HANG_GUARD_S  # waited its reply timeout
        emulator.silence(2, False)
        stage.positions()


def test_open_timeout_bounds_each_reply_of_the_open(emulator):
    """A device silent at open: the open given timeout_s ends within it, though the
    driver's reply timeout is far longer (before, each reply waited its full reply
    timeout: 60 s here, past the hang guard); without a timeout_s the reply timeout
    applies, and afterwards it is the driver's again.

    The open's and the reply timeouts are far apart, so a loaded host's late answers
    cannot blur them: the lower bounds say each timeout was waited for, the upper
    bound is a hang guard the fault exceeds."""
    emulator.silence(2)
    stage = make_stage(emulator, reply_timeout_s=60.0)
    t0 = time.monotonic()
    with pytest.raises(stage.timeout_error, match="within the open's timeout_s = 0.4 s"):
        stage.open(timeout_s=0.4)
    assert 0.4 <= time.monotonic() - t0 < HANG_GUARD_S, time.monotonic() - t0
    assert not stage.is_open and stage._reply_timeout == 60.0
    stage._reply_timeout = 2.0  # without a timeout_s each reply waits the driver's timeout
    t0 = time.monotonic()
    with pytest.raises(stage.timeout_error, match="reply to '/2 1"):
        stage.open()
    assert 2.0 <= time.monotonic() - t0 < HANG_GUARD_S


def test_unplug_mid_move_then_reconnect(emulator):
    stage = make_stage(emulator, home_on_open=True)
    stage.open()
    try:
        unplug_mid_move(stage, emulator, "x", 40.0, velocity=2.0)
        emulator.replug()
        stage.reconnect()
        assert stage.velocity["x"] == 2.0
        assert emulator.axis(1).maxspeed == round(2.0 / STEP * 1.6384)  # re-applied
        stage.move_to({"x": 1.0})
    finally:
        stage.close()


def test_homing_at_open_is_bounded_by_the_callers_timeout_and_cancel():
    """An open without a timeout waits for the homing up to home_timeout_s (a long
    travel homes in tens of seconds); an open given a timeout_s ends within it, naming
    it; a cancel event set during the homing stops the axes and leaves the stage
    closed; home_timeout_s shorter than the open's timeout is named when it runs out."""
    emu = ZaberEmulator({1: 1}, time_scale=1.0)
    with emu:
        def far_from_home(mm: float = 20.0):
            emu.axis(1, 1).position = mm * 1e-3 / 0.047625e-6  # homing at 1 mm/s
            emu.axis(1, 1).flags.add("WR")

        far_from_home(1.2)
        kw = {"axes": ["x"], "device_numbers": {"x": 1}, "speed_mm_s": 1.0,
              "home_on_open": True, "port": emu.port}
        stage = ZaberAsciiStage("mask", **kw)
        t0 = time.monotonic()
        stage.open()  # no timeout given: home_timeout_s (120 s) bounds the 1.2 s homing
        try:
            assert time.monotonic() - t0 > 1.0
            assert stage.position("x") == pytest.approx(0.0, abs=1e-3)
        finally:
            stage.close()

        far_from_home()
        with pytest.raises(StageTimeoutError, match="within the open's timeout_s"):
            stage.open(timeout_s=0.4)
        assert not stage.is_open
        assert emu.axis(1, 1).position > 10e-3 / 0.047625e-6  # far from done: not waited

        far_from_home()
        cancel = threading.Event()
        wait = stage._wait_homing_at_open

        def cancelled_once_homing(home_timeout_s):  # the cancel comes during the homing
            cancel.set()  # (a timer could fire before the open, on a loaded host)
            return wait(home_timeout_s)

        stage._wait_homing_at_open = cancelled_once_homing
        with pytest.raises(DeviceCancelledError, match="cancelled while homing"):
            stage.open(timeout_s=60.0, cancel=cancel)
        assert not stage.is_open
        assert emu.axis(1, 1).position > 10e-3 / 0.047625e-6  # stopped far from home
        hang_guard = time.monotonic() + HANG_GUARD_S  # the stop's deceleration ends
        while emu.axis(1, 1).motion is not None and time.monotonic() < hang_guard:
            time.sleep(0.01)
        stopped_at = emu.axis(1, 1).position
        time.sleep(0.2)
        assert emu.axis(1, 1).position == stopped_at  # not still homing

        far_from_home()
        short = ZaberAsciiStage("mask", home_timeout_s=0.2, **kw)
        with pytest.raises(StageTimeoutError, match="home_timeout_s = 0.2 s"):
            short.open(timeout_s=5.0)
        assert not short.is_open


def test_a_speed_above_the_stages_limit_is_rejected_by_the_device(tmp_path):
    """The emulator enforces a stage's speed limit as the template's does (Zaber: ``set
    maxspeed`` above it is rejected BADDATA): a bench file allowing 20 mm/s on a 10 mm/s
    stage gets the device's rejection, in one line, and the setting stays."""
    limit = round(10.0 / STEP * 1.6384)
    with ZaberEmulator({1: {"axes": 1, "speed_limit": limit}}, time_scale=100.0) as emu:
        with make_stage(emu, axes=["x"], device_numbers={"x": 1}, axis_numbers={}) as stage:
            with pytest.raises(DeviceProtocolError, match=r"rejected 'set maxspeed \d+': BADDATA"):
                stage.velocity = {"x": 15.0}
            assert stage.velocity == {"x": 5.0}
            assert emu.axis(1).maxspeed == round(5.0 / STEP * 1.6384)
            stage.velocity = {"x": 9.5}
            assert emu.axis(1).maxspeed == round(9.5 / STEP * 1.6384)


def test_a_reply_wait_cut_by_the_opens_deadline_names_the_opens_timeout():
    """Replies later than what is left of the open's timeout_s (a loaded host): the
    last reply wait, cut to the open's deadline, runs out there. The user reads that
    the open did not finish within its timeout_s, not that the device may be off."""
    with ZaberEmulator({1: 1}, time_scale=1.0) as emu:
        emu.delay_replies(0.3, n=1000)  # every reply 0.3 s late: the open needs several
        stage = ZaberAsciiStage("mask", axes=["x"], device_numbers={"x": 1}, port=emu.port,
                                speed_mm_s=1.0, reply_timeout_s=30.0)
        with pytest.raises(StageTimeoutError, match="within the open's timeout_s = 1 s") as e:
            stage.open(timeout_s=1.0)
        assert "powered" not in e.value.problem and not stage.is_open
