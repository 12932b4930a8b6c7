"""pylablib's Kinesis driver (``pylablib.devices.Thorlabs.KinesisMotor``, its own
framing and its own unit scaling per controller model and stage) drives the APT
emulator, and reads back what our driver set: positions, velocities and homing
parameters in metres, from a scaling written independently of ours.
"""

from __future__ import annotations

import struct
import time

import pytest

from drivers.thorlabs_apt import ThorlabsAptStage
from tests.drivers.interop.clients import client
from tests.mocks import AptEmulator

client("pylablib", "pylablib-lightweight")
from pylablib.devices import Thorlabs  # noqa: E402
from pylablib.devices.Thorlabs import kinesis  # noqa: E402

Z8_PYLABLIB = 34304.0  # pylablib's counts/mm for Z8 stages (older protocol documents)


@pytest.fixture(autouse=True)
def no_rts_cycle(monkeypatch):
    """pylablib toggles RTS at connect (for an FTDI chip); a pseudo-terminal has no
    modem lines and refuses the ioctl, so the toggle is skipped here."""
    monkeypatch.setattr(kinesis.BasicKinesisDevice, "_cycle_rts", staticmethod(lambda i: None))


def motor(emu, scale="stage"):
    return Thorlabs.KinesisMotor(("serial", emu.port), scale=scale)


def test_kdc101_session_with_the_stage_it_reports(tmp_path):
    emu = AptEmulator("kdc101", time_scale=50.0, update_period_s=0.01, stage_id=7)
    with emu:
        dev = motor(emu)
        try:
            info = dev.get_device_info()
            assert (info.serial_no, info.model_no, info.nchannels) == (27000001, "KDC101", 1)
            assert dev.get_stage() == "MTS25-Z8" and dev.get_scale_units() == "m"
            assert "homed" not in dev.get_status() and "enabled" in dev.get_status()
            dev.home(sync=True, force=True, timeout=10)
            assert dev.is_homed() and emu.channels[0x50].homed
            dev.move_to(5e-3)
            dev.wait_move(timeout=10)
            assert emu.position() == round(5 * Z8_PYLABLIB)
            dev.move_by(-1e-3)
            dev.wait_move(timeout=10)
            assert emu.position() == round(4 * Z8_PYLABLIB)
            assert dev.get_position() == pytest.approx(4e-3, abs=1e-7)
            dev.setup_velocity(max_velocity=1e-3, acceleration=2e-3)
            vel = dev.get_velocity_parameters()
            assert vel.max_velocity == pytest.approx(1e-3, rel=1e-5)
            assert abs(emu.channels[0x50].velocity[2] - Z8_PYLABLIB * 2048 / 6e6 * 65536) <= 1
            dev.setup_jog(mode="step", step_size=1e-4)
            # pylablib's KinesisMotor sends direction 2 for "+" and 1 for "-" (its
            # _forward_positive = False); the emulator takes 1 as forward, to larger
            # counts, as the protocol document defines it (docs/drivers/thorlabs-apt.md,
            # "Which way is forward"): "+" moves it back, "-" on
            p = emu.position()
            dev.jog("+", kind="builtin")
            dev.wait_move(timeout=10)
            assert emu.position() - p == -round(0.1 * Z8_PYLABLIB)
            p = emu.position()
            dev.jog("-", kind="continuous")  # MOVE_VELOCITY, until stopped or at the end
            deadline = time.monotonic() + 60.0  # a hang guard: the move starts at once
            while (moved := emu.position() - p) == 0:
                assert time.monotonic() < deadline, "no move at velocity"
                time.sleep(0.005)
            assert moved > 0  # direction 1: forward
            dev.stop(sync=True, timeout=10)
            assert not dev.is_moving() and emu.channels[0x50].motion is None
            assert dev.get_homing_parameters().home_direction == "reverse"
            assert dev.get_limit_switch_parameters().sw_kind == "ignore"
            assert dev.get_kcube_trigio_parameters().trig1_mode is not None
        finally:
            dev.close()
        assert not emu.unknown


def test_kst101_stepper_units():
    """pylablib's stepper scaling (microsteps/s x 53.68, /s² x 53.68 x 204.94e-6) read
    against the emulator's: a ZST actuator at 2008645.63 microsteps/mm."""
    emu = AptEmulator("kst101", time_scale=50.0, update_period_s=0.01,
                      travel_counts=(0, round(25 * 2008645.63)), counts_per_unit=2008645.63)
    with emu:
        dev = motor(emu, scale="ZST")
        try:
            dev.home(sync=True, force=True, timeout=10)
            dev.setup_velocity(max_velocity=0.5e-3, acceleration=1e-3)
            # pylablib truncates where our driver rounds: one unit apart at most
            assert abs(emu.channels[0x50].velocity[2] - 2008645.63 * 0.5 * 53.68) <= 1
            dev.move_to(2e-3)
            dev.wait_move(timeout=10)
            assert emu.position() == round(2 * 2008645.63)
            assert dev.get_position() == pytest.approx(2e-3, abs=1e-9)
        finally:
            dev.close()


def test_our_driver_settings_read_by_pylablib(tmp_path):
    """What our driver set (velocity, position, homing parameters left alone) is what
    pylablib reads, through its own scaling of the same stage."""
    emu = AptEmulator("kdc101", time_scale=50.0, update_period_s=0.01, stage_id=7)
    with emu:
        with emu.lock:  # homing parameters as a previous user stored them
            emu.channels[0x50].home_params = (1, 1, 12345, 678)
        stage = ThorlabsAptStage("stage", axes=["z"], port=emu.port, limits_mm={"z": [0, 25]},
                                 counts_per_unit=Z8_PYLABLIB, speed_mm_s=1.5,
                                 home_on_open=True, reply_timeout_s=30.0)
        with stage:
            stage.move_to({"z": 7.25})
        assert emu.channels[0x50].home_params == (1, 1, 12345, 678)  # untouched
        dev = motor(emu)
        try:
            assert dev.get_position() == pytest.approx(7.25e-3, abs=1e-7)
            assert dev.get_velocity_parameters().max_velocity == pytest.approx(1.5e-3, rel=1e-5)
            home = dev.get_homing_parameters()
            assert home.home_direction == "forward" and home.offset_distance == pytest.approx(
                678 / (Z8_PYLABLIB * 1e3))
        finally:
            dev.close()
    sent = bytes(emu.received)
    assert struct.pack("<H", 0x0440) not in sent  # no MOT_SET_HOMEPARAMS from anyone


@pytest.mark.parametrize("profile, scale, cpu, rack", [
    ("kst101", "ZST", 2008645.63, False),
    ("bsc20x", "DRV013", 409600.0, True),
])
def test_stepper_velocity_and_acceleration_read_by_pylablib(profile, scale, cpu, rack):
    """The velocity and acceleration our driver sets on a stepper (KST101; a BSC20x bay)
    are what pylablib reads through its own stepper scaling (microsteps/s x 53.68,
    microsteps/s² x 53.68 x 204.94e-6): a 10x error in either is caught here."""
    emu = AptEmulator(profile, time_scale=200.0, update_period_s=0.01,
                      travel_counts=(0, round(25 * cpu)), counts_per_unit=cpu)
    params = {"bays": {"x": 0}} if rack else {}
    with emu:
        stage = ThorlabsAptStage("stage", axes=["x"], port=emu.port, limits_mm={"x": [0, 25]},
                                 counts_per_unit=cpu, speed_mm_s=1.25, acceleration=3.0,
                                 home_on_open=True, reply_timeout_s=30.0, **params)
        with stage:
            stage.move_to({"x": 2.5})
        dev = Thorlabs.KinesisMotor(("serial", emu.port), scale=scale, is_rack_system=rack)
        try:
            vel = dev.get_velocity_parameters()
            assert vel.max_velocity == pytest.approx(1.25e-3, rel=1e-4)
            assert vel.acceleration == pytest.approx(3.0e-3, rel=1e-3)
            assert dev.get_position() == pytest.approx(2.5e-3, abs=1e-8)
        finally:
            dev.close()
