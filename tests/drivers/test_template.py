"""The driver template (drivers/template.py) against its emulator on a pseudo-terminal.

The template must stay a working driver: it passes the shared stage conformance
suite, speaks its protocol byte for byte, and handles refusals, a wrong device on
the port, a limit switch, a silent controller and an unplug as a real driver must.
"""

from __future__ import annotations

import time

import pytest
import serial

from drivers.errors import (
    DeviceProtocolError,
    DeviceValueError,
    StageMotionError,
    StageTimeoutError,
)
from drivers.template import TemplateStage
from tests.drivers.conformance import StageConformance, unplug_mid_move
from tests.mocks import TemplateStageEmulator

SERIAL = "TS0042"


@pytest.fixture
def emulator(tmp_path):
    emu = TemplateStageEmulator(2, serial=SERIAL, time_scale=100.0,
                                link=tmp_path / f"usb-Template_Stage_{SERIAL}-if00-port0")
    emu.start()
    yield emu
    emu.stop()


def make_stage(emu, tmp_path, **kw):
    kw.setdefault("axes", ["x", "y"])
    kw.setdefault("velocity_mm_s", 5.0)
    kw.setdefault("reply_timeout_s", 30.0)  # a hang guard: a loaded host answers late
    return TemplateStage("stage", serial_number=SERIAL, search_dirs=[str(tmp_path)], **kw)


class TestTemplateConformance(StageConformance):
    position_tolerance = 1e-5  # POS? has 6 decimals

    @pytest.fixture
    def device(self, emulator, tmp_path):
        self.emu = emulator
        stage = make_stage(emulator, tmp_path)
        stage.open()
        yield stage
        stage.close()

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)


def test_protocol_table_with_a_plain_serial_client(emulator):
    """The emulator answers as the protocol table says, to pyserial without our driver."""
    with serial.Serial(emulator.port, 115200, timeout=1.0) as port:
        def ask(line: str) -> str:
            port.write(line.encode() + b"\n")
            reply = port.read_until(b"\r\n")
            assert reply.endswith(b"\r\n"), (line, reply)
            return reply.decode().strip()

        assert ask("*IDN?") == f"TPL-STAGE {SERIAL} 1.0"
        assert ask("AXES?") == "2"
        assert ask("TRAVEL? 2") == "0 50"
        assert ask("VEL 1 2.34567") == "OK"
        assert ask("VEL? 1") == "2.346"
        # slow enough that the move outlasts any stall of a loaded machine: 40 mm at
        # 0.001 mm/s is 400 s of emulated time even at time_scale 100 (a move of 1.5 mm at
        # 2.346 mm/s ended in 6 ms, before "MOVING?" was asked at load 30)
        assert ask("VEL 1 0.001") == "OK"
        assert ask("MOVE 1 40") == "OK"
        assert ask("MOVING?") == "1"
        assert ask("STOP") == "OK"
        assert ask("MOVING?") == "0"
        assert ask("FAULT? 1") == "0"
        assert ask("MOVE 1 51") == "ERR 2 value out of range"
        assert ask("POS? 3") == "ERR 3 no such axis"
        assert ask("JUMP 1") == "ERR 1 unknown command"


def test_byte_exact_commands(emulator, tmp_path):
    with make_stage(emulator, tmp_path) as stage:
        assert emulator.commands == ["*IDN?", "AXES?", "TRAVEL? 1", "TRAVEL? 2", "VMAX?",
                                     "VEL 1 5", "VEL? 1", "VEL 2 5", "VEL? 2"]
        emulator.commands.clear()
        emulator.sent.clear()
        stage.move_to({"y": 10.0})
        cmds = list(emulator.commands)
        assert cmds[0] == "MOVE 2 10.000000"
        assert set(cmds[1:-1]) == {"MOVING?"} and cmds[-1] == "FAULT? 2"
        assert bytes(emulator.sent).startswith(b"OK\r\n")
        assert stage.position("y") == pytest.approx(10.0, abs=1e-6)


def test_velocity_is_what_the_controller_took(emulator, tmp_path):
    with make_stage(emulator, tmp_path) as stage:
        stage.velocity = {"x": 1.23456}
        assert stage.velocity == {"x": 1.235, "y": 5.0}  # read back, 0.001 mm/s steps
        assert emulator.axes[0].velocity_mm_s == 1.235
        with pytest.raises(DeviceValueError, match=r"velocity\[x\]"):
            stage.velocity = {"x": 25.0}  # above VMAX? = 20, refused before sending


def test_refusal_names_the_reply_and_the_fix(emulator, tmp_path):
    with make_stage(emulator, tmp_path) as stage:
        with pytest.raises(DeviceProtocolError, match="ERR 1 unknown command.*firmware"):
            stage.query("JUMP 1")
        with pytest.raises(DeviceProtocolError, match="ERR 2 value out of range.*TRAVEL"):
            stage.query("MOVE 1 99")
        stage.move_to({"x": 1.0})  # still usable


def test_wrong_device_on_the_port(tmp_path):
    with TemplateStageEmulator(1, model="OTHER-CTRL") as emu:
        stage = TemplateStage("stage", port=emu.port)
        with pytest.raises(DeviceProtocolError, match="'OTHER-CTRL TS0001 1.0', not a "
                           "TPL-STAGE controller.*Fix: check the port"):
            stage.open()
        assert not stage.is_open
    with TemplateStageEmulator(1) as emu:
        stage = TemplateStage("stage", port=emu.port, axes=["x", "y"])
        with pytest.raises(DeviceValueError, match="exceed the controller's 1 axes"):
            stage.open()
        stage = TemplateStage("stage", port=emu.port, limits_mm={"x": [10, 60]})
        with pytest.raises(DeviceValueError, match="not within the controller's travel"):
            stage.open()
        with TemplateStage("stage", port=emu.port, limits_mm={"x": [10, 40]}) as stage:
            assert stage.travel == {"x": (10.0, 40.0)}


@pytest.mark.parametrize("params, match", [
    ({"axes": "x"}, "not a list"), ({"axes": ["x", "x"]}, "not distinct"),
    ({"axes": ["x", "rotation"]}, "linear axes"),
    ({"axes": ["x", "y"], "axis_numbers": {"x": 1}}, r"\['y'\] have no axis number"),
    ({"axis_numbers": {"x": 0}}, r"axis_numbers\[x\]"),
    ({"axes": ["x", "y"], "axis_numbers": {"x": 1, "y": 1}}, "repeat"),
    ({"limits_mm": {"z": [0, 1]}}, "does not have"), ({"velocity_mm_s": 0}, "velocity_mm_s"),
    ({"reply_timeout_s": -1}, "reply_timeout_s"),
])
def test_bad_parameters_are_refused_at_construction(params, match):
    with pytest.raises(DeviceValueError, match=match):
        TemplateStage("stage", port="/dev/null", **params)


def test_limit_switch_ends_the_move_with_a_motion_error(emulator, tmp_path):
    with make_stage(emulator, tmp_path) as stage:
        emulator.set_limit_switch(1, 12.0)
        with pytest.raises(StageMotionError, match="axis x: 1 limit switch at 12 mm"):
            stage.move_to({"x": 20.0})
        assert not stage.is_moving()
        emulator.set_limit_switch(1, None)
        stage.move_to({"x": 20.0})  # the fault cleared with the new move


def test_silent_controller_times_out_and_the_stage_works_again(emulator, tmp_path):
    with make_stage(emulator, tmp_path) as stage:
        emulator.silence()
        stage._reply_timeout = 0.5  # the silent controller is waited for 0.5 s
        t0 = time.monotonic()
        with pytest.raises(StageTimeoutError, match="reply to 'POS\\? 1'"):
            stage.positions()
        assert 0.5 <= time.monotonic() - t0 < 30.0  # its 0.5 s reply timeout; a hang guard
        emulator.silence(False)
        stage._reply_timeout = 30.0
        assert set(stage.positions()) == {"x", "y"}


def test_unplug_mid_move_then_reconnect_by_serial_number(emulator, tmp_path):
    stage = make_stage(emulator, tmp_path)
    stage.open()
    try:
        unplug_mid_move(stage, emulator, "x", 40.0, velocity=2.0)
        emulator.replug()  # a new pty; the by-id link follows it
        stage.reconnect()
        assert stage.velocity["x"] == 2.0
        stage.move_to({"x": 1.0})
        assert stage.position("x") == pytest.approx(1.0, abs=1e-6)
    finally:
        stage.close()
