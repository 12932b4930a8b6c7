"""Thorlabs APT stage driver against the APT emulator on a pseudo-terminal."""

from __future__ import annotations

import struct
import sys
import threading
import time

import pytest

from drivers.errors import (
    DeviceDisconnectedError,
    DeviceStateError,
    DeviceValueError,
    MissingDependencyError,
    StageMotionError,
    StageTimeoutError,
)
from drivers.thorlabs_apt import ThorlabsAptStage
from drivers.thorlabs_apt_protocol import AptFramer, AptMessage, pack_message
from tests.drivers.conformance import StageConformance, unplug_mid_move
from tests.mocks import AptEmulator

Z8 = 34554.96


@pytest.fixture
def emulator(tmp_path):
    emu = AptEmulator("kdc101", serial_number=27000001, time_scale=200.0, update_period_s=0.01,
                      link=tmp_path / "usb-Thorlabs_Brushed_Motor_Controller_27000001-if00-port0")
    emu.start()
    yield emu
    emu.stop()


def make_stage(emu, tmp_path, **kw):
    kw.setdefault("axes", ["z"])
    kw.setdefault("serial_numbers", {"z": "27000001"})
    kw.setdefault("limits_mm", {"z": [0.0, 25.0]})
    kw.setdefault("speed_mm_s", 2.0)
    kw.setdefault("reply_timeout_s", 30.0)  # a hang guard: a loaded host answers late
    return ThorlabsAptStage("stage", search_dirs=[str(tmp_path)], **kw)


class TestAptConformance(StageConformance):
    position_tolerance = 1e-4  # one count is 29 nm; the wait accepts 2 counts

    @pytest.fixture
    def device(self, emulator, tmp_path):
        self.emu = emulator
        stage = make_stage(emulator, tmp_path, home_on_open=True)
        stage.open()
        yield stage
        stage.close()

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)


def test_byte_exact_messages(emulator, tmp_path):
    """The worked examples of the protocol notes (KDC101 + Z8 stage)."""
    with make_stage(emulator, tmp_path, home_on_open=True) as stage:
        sent = bytes(emulator.received)
        assert sent.startswith(bytes.fromhex("05 00 00 00 50 01"))  # HW_REQ_INFO
        # velocity 2 mm/s, 1.5 mm/s²
        vel = "13 04 0E 00 D0 01 01 00 00 00 00 00 8C 01 00 00 EB 96 17 00"
        assert bytes.fromhex(vel) in sent
        assert bytes.fromhex("11 00 00 00 50 01") in sent  # START_UPDATEMSGS
        assert bytes.fromhex("43 04 01 00 50 01") in sent  # MOVE_HOME
        emulator.received.clear()
        stage.move_to({"z": 10.0})
        sent = bytes(emulator.received)
        assert bytes.fromhex("29 04 01 00 50 01") in sent  # REQ_STATUSBITS
        assert bytes.fromhex("11 04 01 00 50 01") in sent  # REQ_POSCOUNTER
        assert bytes.fromhex("53 04 06 00 D0 01 01 00 CE 45 05 00") in sent  # 345550 counts
        emulator.received.clear()
        stage.stop()  # no reply: waited for as the emulator reads it (not a sleep)
        assert emulator.wait_received(bytes.fromhex("65 04 01 02 50 01"))  # profiled
    assert emulator.wait_received(bytes.fromhex("12 00 00 00 50 01"))  # updates off


def test_framer_by_length_resync_and_interleaving():
    status28 = pack_message(0x0481, 0x01, 0x21, data=struct.pack("<HiiI", 1, 5, 5, 0x400)
                            + bytes(14))
    homed = bytes.fromhex("44 04 01 00 01 50")
    reply = pack_message(0x0412, 0x01, 0x50, data=struct.pack("<Hi", 1, -7))
    framer = AptFramer()
    stream = b"\xff\x13" + status28 + homed + b"\x00\x99" + reply
    msgs = framer.feed(stream[:9]) + framer.feed(stream[9:])
    assert [m.msg_id for m in msgs] == [0x0481, 0x0444, 0x0412]
    assert len(msgs[0].data) == 28
    assert msgs[1] == AptMessage(0x0444, 0x01, 0x50, 1, 0, None)
    assert struct.unpack("<Hi", msgs[2].data) == (1, -7)
    assert framer.resyncs == 4


def test_counts_per_unit_is_per_axis_constant(emulator, tmp_path):
    with make_stage(emulator, tmp_path, home_on_open=True, counts_per_unit=34304.0) as stage:
        stage.move_to({"z": 10.0})
        assert emulator.position() == 343040  # not 345550: the configured constant is used
        assert stage.position("z") == pytest.approx(10.0, abs=1e-6)


def test_move_refused_until_homed(emulator, tmp_path):
    with make_stage(emulator, tmp_path) as stage:
        with pytest.raises(DeviceStateError, match="not homed"):
            stage.move_to({"z": 5.0})
        assert emulator.position() == 0
        stage.home()
        stage.move_to({"z": 5.0})
        assert stage.status()["homed"] == {"z": True}


def test_move_interrupted_by_limit_switch(emulator, tmp_path):
    with make_stage(emulator, tmp_path, home_on_open=True) as stage:
        emulator.set_limit_switch(round(12.0 * Z8))
        with pytest.raises(StageMotionError, match="limit switch at 12 mm, target 20"):
            stage.move_to({"z": 20.0})
        assert not stage.is_moving()
        emulator.set_limit_switch(None)
        stage.move_to({"z": 3.0})  # usable again


def test_controller_error_report_and_garbage(emulator, tmp_path):
    with make_stage(emulator, tmp_path, home_on_open=True) as stage:
        emulator.garbage(b"\xff\xfe\x00\x13")
        stage.move_to({"z": 1.0}, wait=False)
        emulator.rich_response(0x2A, "Motor overtemp")
        with pytest.raises(StageMotionError, match="error 42: Motor overtemp"):
            stage.wait_until_idle()
        stage.move_to({"z": 2.0})
        assert stage.status()["controllers"]["sn:27000001"]["resyncs"] >= 4


def test_keepalive_keeps_updates_flowing(emulator, tmp_path):
    """The controller goes silent after 50 updates without an ACK: with the keepalive
    it sends more than 50, however slowly a loaded host runs either side (waited for,
    a 60 s hang guard; without the ACKs they stop at 50 and the guard fails it)."""
    with make_stage(emulator, tmp_path, keepalive_s=0.2):
        hang_guard = time.monotonic() + 60.0
        while time.monotonic() < hang_guard:
            with emulator.lock:
                if emulator.acks >= 5 and emulator.updates_sent >= 80:
                    break
            time.sleep(0.01)
        with emulator.lock:
            assert emulator.acks >= 5 and emulator.updates_sent >= 80
            assert emulator.updates_on
        assert bytes.fromhex("92 04 00 00 50 01") in bytes(emulator.received)


def test_stall_times_out_and_stops(emulator, tmp_path):
    with make_stage(emulator, tmp_path, home_on_open=True) as stage:
        emulator.stall()
        with pytest.raises(StageTimeoutError, match="stopped"):
            stage.move_to({"z": 10.0}, timeout_s=0.3)
        emulator.stall(stalled=False)
        assert not stage.is_moving()  # the driver sent MOVE_STOP


def test_unplug_mid_move_then_reconnect_restores_settings(emulator, tmp_path):
    stage = make_stage(emulator, tmp_path, home_on_open=True)
    stage.open()
    try:
        stage.limits = {"z": (1.0, 24.0)}
        unplug_mid_move(stage, emulator, "z", 20.0, velocity=1.0)
        with pytest.raises(DeviceDisconnectedError, match="27000001"):
            stage.reconnect()  # still unplugged: the serial number is not found
        emulator.replug()  # a new pty; the by-id style link follows it
        stage.reconnect()
        assert stage.velocity == {"z": 1.0} and stage.limits == {"z": (1.0, 24.0)}
        ch = emulator.channels[0x50]
        assert ch.velocity[2] == round(Z8 * 2048 / 6e6 * 65536 * 1.0)  # re-sent after reconnect
        assert stage.status()["homed"] == {"z": True}  # USB unplug only: position kept
        stage.move_to({"z": 5.0})
    finally:
        stage.close()


def test_bsc20x_bays_on_one_port(tmp_path):
    emu = AptEmulator("bsc20x", channels=2, travel_counts=(0, 50 * 409600), time_scale=500.0,
                      update_period_s=0.01, counts_per_unit=409600)
    with emu:
        assert not emu.channels[0x21].enabled  # powers up disabled, "stuck" velocities
        stage = ThorlabsAptStage("rack", axes=["x", "y"], port=emu.port, bays={"x": 0, "y": 1},
                                 limits_mm={"x": [0, 50], "y": [0, 50]}, speed_mm_s=2.0,
                                 home_on_open=True, reply_timeout_s=30.0)
        with stage:
            assert emu.channels[0x21].enabled and emu.channels[0x22].enabled
            stage.move_to({"x": 3.0, "y": 4.5})
            assert emu.position(0x21) == 3 * 409600 and emu.position(0x22) == round(4.5 * 409600)
            assert stage.status()["controllers"]["port:" + emu.port]["model"] == "BSC203"
        assert emu.acks == 0  # BSC20x: no status updates, polled instead


def test_missing_pyserial_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "serial", None)
    stage = ThorlabsAptStage("stage", axes=["z"], port=str(tmp_path / "nope"),
                             limits_mm={"z": [0, 25]})
    with pytest.raises(MissingDependencyError, match=r"diffuserlab\[hardware\]"):
        stage.open()
    assert not stage.is_open


def test_moves_from_two_threads_do_not_mix_replies(emulator, tmp_path):
    with make_stage(emulator, tmp_path, home_on_open=True) as stage:
        errors = []

        def poll():
            try:
                for _ in range(50):
                    stage.positions()
            except Exception as exc:  # pragma: no cover - reported below
                errors.append(exc)

        t = threading.Thread(target=poll)
        t.start()
        for _ in range(50):
            stage.is_moving()
        t.join()
        assert not errors


def test_kst101_stepper_profile(tmp_path):
    """KST101: microsteps (ZST actuator 2008645.63 per mm), stepper velocity units and the
    28-byte GET_STATUSUPDATE framed by its length while the keepalive runs."""
    emu = AptEmulator("kst101", serial_number=26000042, time_scale=200.0,
                      travel_counts=(0, round(25 * 2008645.63)), update_period_s=0.01,
                      counts_per_unit=2008645.63,
                      link=tmp_path / "usb-Thorlabs_Stepper_Motor_Controller_26000042-if00-port0")
    with emu:
        stage = ThorlabsAptStage("stage", axes=["x"], serial_numbers={"x": "26000042"},
                                 limits_mm={"x": [0, 25]}, speed_mm_s=1.0, home_on_open=True,
                                 keepalive_s=0.2, reply_timeout_s=30.0,
                                 search_dirs=[str(tmp_path)])
        with stage:
            vel = emu.channels[0x50].velocity[2]
            assert vel == round(2008645.63 * 1.0 * 53.68)  # microsteps/s x 53.68
            stage.move_to({"x": 12.5})
            assert emu.position() == round(12.5 * 2008645.63)
            hang_guard = time.monotonic() + 30.0  # keepalives every 0.2 s, ACKed
            while emu.acks < 1 and time.monotonic() < hang_guard:
                time.sleep(0.01)
            info = stage.status()["controllers"]["sn:26000042"]
            assert info["model"] == "KST101" and info["resyncs"] == 0
            assert b"\x81\x04\x1c\x00\x81\x50" in bytes(emu.sent)  # 28-byte updates were sent
            assert emu.acks >= 1


# ------------------------------------------------------------------ model, stage, scaling
def test_profile_comes_from_the_model_the_controller_reports(tmp_path):
    """Serial prefix 70 is a BSC203 or a legacy BSC103: HW_GET_INFO's model decides."""
    with AptEmulator("bsc20x", model="BSC103", channels=1, time_scale=200.0) as emu:
        stage = ThorlabsAptStage("rack", axes=["x"], port=emu.port, bays={"x": 0},
                                 limits_mm={"x": [0, 2]}, reply_timeout_s=30.0)
        with pytest.raises(DeviceValueError, match="BSC103.*legacy stepper"):
            stage.open()
    with AptEmulator("kdc101", time_scale=200.0) as emu:
        stage = ThorlabsAptStage("s", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 profile="kst101", reply_timeout_s=30.0)
        with pytest.raises(DeviceValueError, match="contradicts.*KDC101"):
            stage.open()
    with AptEmulator("kdc101", model="XYZ999", time_scale=200.0) as emu:
        stage = ThorlabsAptStage("s", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 reply_timeout_s=30.0)
        with pytest.raises(DeviceValueError, match="'XYZ999'.*set profile"):
            stage.open()
        stage = ThorlabsAptStage("s", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 profile="kdc101", reply_timeout_s=30.0)
        with stage:  # an explicit profile for an unknown model: used, with a warning
            assert stage.status()["axes_setup"]["z"]["profile"] == "kdc101"


def test_rotation_axis_needs_its_counts_per_degree(tmp_path):
    with AptEmulator("kdc101", time_scale=200.0) as emu:
        kw = dict(axes=["rotation"], port=emu.port, limits_deg={"rotation": [0, 360]},
                  reply_timeout_s=30.0)
        with pytest.raises(DeviceValueError, match="rotation axis.*PRM1-Z8"):
            ThorlabsAptStage("r", **kw).open()
        with ThorlabsAptStage("r", stages={"rotation": "PRM1-Z8"}, **kw) as stage:
            assert stage.status()["axes_setup"]["rotation"]["counts_per_unit"] == \
                pytest.approx(1919.6418578623391)
        with ThorlabsAptStage("r", counts_per_unit=2000.0, **kw) as stage:
            assert stage.status()["axes_setup"]["rotation"]["counts_per_unit"] == 2000.0
    with AptEmulator("kdc101", stage_id=6, time_scale=200.0) as emu:  # reports a PRM1-Z8
        kw["port"] = emu.port
        with ThorlabsAptStage("r", home_on_open=True, **kw) as stage:
            stage.move_to({"rotation": 90.0})
            assert emu.position() == round(90 * 1919.6418578623391)
    with pytest.raises(DeviceValueError, match="moves in mm"):
        ThorlabsAptStage("r", axes=["rotation"], port="x", limits_deg={"rotation": [0, 9]},
                         stages={"rotation": "Z825"})


def test_homing_parameters_are_left_alone_unless_set(emulator, tmp_path):
    with emulator.lock:
        emulator.channels[0x50].home_params = (1, 4, 999, 1234)  # stored by the user
    with make_stage(emulator, tmp_path, home_on_open=True):
        pass
    assert emulator.channels[0x50].home_params == (1, 4, 999, 1234)
    assert struct.pack("<H", 0x0440) not in bytes(emulator.received)
    with make_stage(emulator, tmp_path, home_velocity=0.5):
        pass
    vel = round(Z8 * 2048 / 6e6 * 65536 * 0.5)
    assert emulator.channels[0x50].home_params == (1, 4, vel, 1234)  # only the velocity


def test_position_tolerance_per_stage(emulator, tmp_path):
    with emulator.lock:
        emulator.channels[0x50].end_offset = 12  # a DC servo settling 12 counts off
    with make_stage(emulator, tmp_path, home_on_open=True) as stage:
        stage.move_to({"z": 5.0})  # within the DC default (20 counts)
        assert stage.status()["axes_setup"]["z"]["position_tolerance_counts"] == 20
    with make_stage(emulator, tmp_path, position_tolerance_counts={"z": 5}) as stage:
        with pytest.raises(StageMotionError, match="stopped at"):
            stage.move_to({"z": 6.0})


def test_velocity_quantisation_is_accepted(tmp_path):
    with AptEmulator("kdc101", velocity_quantum=64, time_scale=200.0) as emu:
        with ThorlabsAptStage("s", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                              speed_mm_s=1.0, reply_timeout_s=30.0) as stage:
            sent = round(Z8 * 2048 / 6e6 * 65536)
            took = emu.channels[0x50].velocity[2]
            assert took % 64 == 0 and took != sent
            assert stage.velocity["z"] == pytest.approx(took / sent)  # what it runs at
            stage.velocity = {"z": 1.7}
            assert stage.velocity["z"] == pytest.approx(1.7, rel=1e-3)
            assert stage.velocity["z"] != 1.7


def test_homing_at_open_waits_for_home_timeout_when_the_open_has_no_timeout(tmp_path):
    """Homing a long travel takes longer than an open's 5 s answer bound: an open given no
    timeout waits up to home_timeout_s for the homing, and names that setting when it
    runs out (an open given a timeout_s ends sooner: test_driver_faults.py)."""
    emu = AptEmulator("kdc101", time_scale=1.0, update_period_s=0.01)
    with emu:
        emu.channels[0x50].position = 1.2 * Z8  # 1.2 mm from home, homed at 1 mm/s
        stage = ThorlabsAptStage("stage", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 home_velocity=1.0, home_on_open=True, reply_timeout_s=30.0)
        stage.open()  # the homing takes about 1.2 s
        try:
            assert stage.status()["homed"] == {"z": True}
        finally:
            stage.close()
        emu.channels[0x50].position, emu.channels[0x50].homed = 1.2 * Z8, False
        short = ThorlabsAptStage("stage", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 home_velocity=1.0, home_on_open=True, home_timeout_s=0.2,
                                 reply_timeout_s=30.0)
        with pytest.raises(StageTimeoutError, match="home_timeout_s = 0.2 s"):
            short.open(timeout_s=5.0)
        assert not short.is_open


def test_a_velocity_above_the_stages_limit_is_refused_naming_it(emulator, tmp_path):
    """The emulator keeps a KDC101's Z8 within 2.6 mm/s as the controller does (the
    template's emulator refuses a VEL above its limit): a bench file allowing 10 mm/s
    learns the limit from the value read back, in one line, and the setting stays."""
    with make_stage(emulator, tmp_path, max_velocity=10.0) as stage:
        with pytest.raises(DeviceValueError, match=r"took 2\.6 mm/s of the 5 mm/s sent"):
            stage.velocity = {"z": 5.0}
        assert stage.velocity["z"] == 2.0  # the setting stays, on the controller too
        assert emulator.channels[0x50].velocity[2] == round(2.0 * Z8 * 2048 / 6e6 * 65536)
        stage.velocity = {"z": 2.5}
        assert stage.velocity["z"] == pytest.approx(2.5, rel=0.01)
