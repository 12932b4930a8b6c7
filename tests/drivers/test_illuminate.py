"""illuminate LED array driver against the illuminate emulator on a pseudo-terminal."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.errors import DeviceDisconnectedError, DeviceProtocolError, DeviceValueError
from drivers.illuminate import IlluminateLedArray
from tests.drivers.conformance import SerialLedArrayConformance
from tests.mocks import IlluminateEmulator


@pytest.fixture
def emulator(tmp_path):
    emu = IlluminateEmulator((8, 8), pitch_mm=4.0, distance_mm=50.0,
                             link=tmp_path / "usb-Teensyduino_USB_Serial_1234560-if00")
    emu.start()
    yield emu
    emu.stop()


def make_array(emu, **kw):
    kw.setdefault("reply_timeout_s", 30.0)  # a hang guard: a loaded host answers late
    return IlluminateLedArray("leds", port=emu.port, shape=(8, 8), **kw)


class TestIlluminateConformance(SerialLedArrayConformance):
    @pytest.fixture
    def device(self, emulator):
        self.emu = emulator
        with make_array(emulator) as arr:
            yield arr

    def provoke_timeout(self, device):
        self.emu.drop_replies(1)
        self.wait_lost_reply(device)

    def leds_emitting(self, device):
        return len(self.emu.lit())


def test_open_sequence_and_geometry(emulator):
    with make_array(emulator) as arr:
        assert emulator.commands[:6] == [b"machine", b"pp", b"pledpos", b"ac.0", b"sb.255", b"x"]
        assert arr.n_leds == 64 and arr.pitch_mm == pytest.approx(4.0)
        assert arr.distance_mm == 50.0
        assert arr.colours == {"red": 625.0, "green": 525.0, "blue": 465.0, "white": None}
        assert arr.positions_mm[0].tolist() == [-14.0, 14.0]
        assert emulator.machine and not emulator.autoclear


def test_byte_exact_show(emulator):
    with make_array(emulator) as arr:
        emulator.received.clear()
        arr.set_leds([3, 1], "red", 0.5)
        arr.set_leds([9], "blue", 1.0, additive=True)
        wire = bytes(emulator.received)
        assert wire == (b"x\nsc.128.0.0\nl.1.3\n"
                        b"x\nsc.128.0.0\nl.1.3\nsc.0.0.255\nl.9\n")
        assert emulator.lit() == {1: (128, 0, 0), 3: (128, 0, 0), 9: (0, 0, 255)}
        assert b"\r" not in wire  # a CR would become part of the command


def test_pattern_matches_firmware_brightfield(emulator):
    with make_array(emulator) as arr:
        arr.na_illum = 0.25
        assert emulator.na == 0.25  # sent as na.25
        idx = arr.set_pattern("brightfield", colour="white", brightness=1.0)
        ours = set(emulator.lit())
        arr.command("bf")  # the firmware's own brightfield at the same NA
        assert set(emulator.lit()) == ours == set(idx.tolist())


def test_error_replies_raise(emulator):
    with make_array(emulator) as arr:
        with pytest.raises(DeviceProtocolError, match="not implemented"):
            arr.command("frobnicate")
        with pytest.raises(DeviceProtocolError, match="ERROR"):
            arr.command("l.999")
        with pytest.raises(DeviceProtocolError, match="too long"):
            arr.command("sc.12345678901")
        with pytest.raises(DeviceValueError, match="line break"):
            arr.command("bf\r")
        arr.set_pattern("dpc_top")  # still in step after errors


def test_many_leds_are_split_into_commands(tmp_path):
    with IlluminateEmulator((32, 32)) as emu:
        with IlluminateLedArray("leds", port=emu.port, reply_timeout_s=30.0) as arr:
            arr.set_leds(np.arange(1024), "green", 1.0)
            assert len(emu.lit()) == 1024
            assert max(len(c) for c in emu.commands) < 1500


def test_wrong_shape_is_a_clear_error(emulator):
    arr = IlluminateLedArray("leds", port=emulator.port, shape=(32, 32), reply_timeout_s=30.0)
    with pytest.raises(DeviceValueError, match="64 LEDs"):
        arr.open()
    assert not arr.is_open


def test_unplug_then_reconnect_restores_leds(emulator):
    with make_array(emulator) as arr:
        arr.brightness = 0.5
        idx = arr.set_pattern("dpc_left", colour="green")
        emulator.unplug()
        t0 = time.monotonic()
        with pytest.raises(DeviceDisconnectedError):
            arr.all_off()
        assert time.monotonic() - t0 < 30.0  # a hang guard: the error, not its speed
        emulator.replug()
        with emulator.lock:
            emulator.values[:] = 0  # as after a power cycle
        arr.reconnect()
        assert arr.brightness == 0.5 and arr.pattern == "dpc_left"
        assert set(emulator.lit()) == set(idx.tolist())
        assert set(emulator.lit().values()) == {(0, 128, 0)}


def test_an_unplugged_array_shows_disconnected_in_its_status_without_a_command(emulator):
    """Nobody talks to an idle LED array: its status sees the port's hang-up as a
    polled stage's does (it said "open" for over a minute)."""
    with make_array(emulator) as arr:
        assert arr.status()["disconnected"] is False
        emulator.unplug()
        status = arr.status()
        assert status["disconnected"] is True and "hung up" in status["error"]
        with pytest.raises(DeviceDisconnectedError):
            arr.all_off()
        emulator.replug()
        arr.reconnect()
        assert arr.status()["disconnected"] is False
