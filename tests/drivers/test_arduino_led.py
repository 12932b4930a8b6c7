"""LEDMX (DIY Arduino LED array) driver against the LEDMX emulator on a pseudo-terminal."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.arduino_led import ArduinoLedArray
from drivers.errors import DeviceDisconnectedError, DeviceProtocolError, LedArrayTimeoutError
from tests.drivers.conformance import SerialLedArrayConformance
from tests.mocks import ArduinoLedEmulator


@pytest.fixture
def emulator(tmp_path):
    emu = ArduinoLedEmulator((6, 8), link=tmp_path / "usb-Arduino_Uno_8573-if00")
    emu.start()
    yield emu
    emu.stop()


def make_array(emu, **kw):
    kw.setdefault("reply_timeout_s", 30.0)  # a hang guard: a loaded host answers late
    return ArduinoLedArray("leds", port=emu.port, pitch_mm=3.0, distance_mm=40.0, **kw)


class TestArduinoConformance(SerialLedArrayConformance):
    @pytest.fixture
    def device(self, emulator):
        self.emu = emulator
        with make_array(emulator) as arr:
            yield arr

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)

    def leds_emitting(self, device):
        return int(self.emu.output().any(axis=1).sum())


def test_byte_exact_session(emulator):
    with make_array(emulator) as arr:
        assert emulator.lines[:3] == ["*IDN?", "AUTO 0", "BRI 255"]
        assert arr.identity == {"model": "emu-ws2812", "rows": 6, "cols": 8, "channels": 3,
                                "firmware": "1.0"}
        emulator.received.clear()
        arr.set_leds([0, 9], "green", 0.5)
        frame = np.zeros((48, 3), np.uint8)
        frame[[0, 9], 1] = 128
        assert bytes(emulator.received) == b"FRAME 144\n" + frame.tobytes() + b"SHOW\n"
        out = emulator.output()
        assert out[9].tolist() == [0, 128, 0] and out.sum() == 256
        assert arr.positions_mm[9].tolist() == [-7.5, 4.5]  # row 1, column 1 of 6x8 at 3 mm


def test_errors_quote_the_reply(emulator):
    with make_array(emulator) as arr:
        with pytest.raises(DeviceProtocolError, match="ERR 3 value out of range"):
            arr.command("PIX 48 1 2 3")
        with pytest.raises(DeviceProtocolError, match="ERR 1 unknown command"):
            arr.command("BLINK")
        with pytest.raises(DeviceProtocolError, match="ERR 2"):
            arr.command("PIX 1 2")
        with pytest.raises(DeviceProtocolError, match="ERR 4 frame length mismatch"):
            arr.command("FRAME 3", b"\x01\x02\x03")
        assert arr.command("GET 0") == "0 0 0"
        arr.set_pattern("brightfield")


def test_board_that_resets_on_open(tmp_path):
    with ArduinoLedEmulator((4, 4), boot_s=0.8) as emu:
        with ArduinoLedArray("leds", port=emu.port, ready_timeout_s=30.0) as arr:  # a guard
            # *IDN? repeated until the board booted: open returned after the boot (measured
            # from the emulator's own start; run R, under load, spent 0.15 s between that
            # start and the test's clock, and a 0.7 s bound from there failed)
            assert time.monotonic() >= emu.booted_at
            assert arr.n_leds == 16
    with ArduinoLedEmulator((4, 4), boot_s=600.0) as emu:  # not before the 0.6 s, however late
        arr = ArduinoLedArray("leds", port=emu.port, ready_timeout_s=0.6)
        with pytest.raises(LedArrayTimeoutError, match="no LEDMX identity"):
            arr.open()


def test_mono_array(tmp_path):
    with ArduinoLedEmulator((2, 2), channels=1) as emu:
        with ArduinoLedArray("leds", port=emu.port) as arr:
            assert arr.colours == {"white": None}
            arr.set_leds([3], "white", 1.0)
            assert emu.output()[:, 0].tolist() == [0, 0, 0, 255]


def test_unplug_then_reconnect_restores_leds(emulator):
    with make_array(emulator) as arr:
        idx = arr.set_pattern("dpc_right", colour="red", brightness=0.25)
        emulator.unplug()
        with pytest.raises(DeviceDisconnectedError):
            arr.set_pattern("dpc_left")
        emulator.replug()
        with emulator.lock:
            emulator.shown[:] = 0  # the board reset
        arr.reconnect()
        lit = np.flatnonzero(emulator.output().any(axis=1))
        assert lit.tolist() == sorted(idx.tolist())
        assert emulator.output()[lit[0]].tolist() == [64, 0, 0]
