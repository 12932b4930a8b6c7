"""Conformance suite of LED arrays."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from drivers.errors import (
    DeviceValueError,
    LedArrayTimeoutError,
)
from drivers.led_array import PATTERNS

from .base import DeviceConformance


class LedArrayConformance(DeviceConformance):
    """LED array behaviour: geometry, patterns and the lit state."""

    kind = "led_array"
    timeout_error = LedArrayTimeoutError

    def use(self, device):
        return device.lit()

    def leds_emitting(self, device) -> int:
        """How many LEDs the board itself (the emulator, the simulated array) lights now:
        what a camera would see, not what the driver remembers."""
        raise NotImplementedError

    def test_close_turns_every_led_off(self, device):
        """The board is cleared before its port closes: an array left lit after close
        lights the next experiment."""
        device.set_pattern("brightfield", timeout_s=5.0)
        assert self.leds_emitting(device) > 0
        device.close()
        assert self.leds_emitting(device) == 0

    def blocking_call(self, device):
        device.set_pattern("brightfield", timeout_s=1.0)

    def changed_settings(self, device):
        other = [c for c in device.colours if c != device.colour][0]
        return {
            "na_illum": device.na_illum / 2,
            "colour": other,
            "brightness": 0.5 if device.brightness != 0.5 else 0.25,
        }

    def invalid_settings(self, device):
        return [
            {"na_illum": 0.0}, {"na_illum": 1.5}, {"na_illum": "wide"},
            {"colour": "ultraviolet"}, {"brightness": 1.01}, {"brightness": -0.1},
        ]

    def assert_settings_in_effect(self, device, settings):
        idx = device.set_pattern("brightfield")
        na = device.na_per_led
        assert np.all(na[idx] <= settings["na_illum"] + 1e-12)
        assert set(device.lit().values()) == {(settings["colour"], settings["brightness"])}

    def test_geometry(self, device):
        pos = device.positions_mm
        assert pos.shape == (device.n_leds, 2) and device.n_leds > 0
        assert device.pitch_mm > 0 and device.distance_mm > 0
        assert device.colours and all(isinstance(k, str) for k in device.colours)
        na = device.na_per_led
        r = np.hypot(pos[:, 0], pos[:, 1])
        np.testing.assert_allclose(na, np.sin(np.arctan2(r, device.distance_mm)))

    def test_brightfield_and_darkfield(self, device):
        na = device.na_per_led
        for na_illum in (0.1, 0.3):
            bf = set(device.pattern_indices("brightfield", na_illum).tolist())
            df = set(device.pattern_indices("darkfield", na_illum).tolist())
            assert bf == set(np.flatnonzero(na <= na_illum).tolist())
            assert bf.isdisjoint(df) and bf | df == set(range(device.n_leds))
        assert len(device.pattern_indices("brightfield", 0.3)) >= len(
            device.pattern_indices("brightfield", 0.1))

    def test_dpc_halves_partition_brightfield(self, device):
        pos = device.positions_mm
        bf = set(device.pattern_indices("brightfield").tolist())
        halves = {p: set(device.pattern_indices(p).tolist()) for p in PATTERNS[2:]}
        for a, b in (("dpc_top", "dpc_bottom"), ("dpc_left", "dpc_right")):
            assert halves[a].isdisjoint(halves[b])
            assert halves[a] | halves[b] == bf
            assert halves[a] and halves[b]
        assert all(pos[i, 1] >= 0 for i in halves["dpc_top"])
        assert all(pos[i, 1] < 0 for i in halves["dpc_bottom"])
        assert all(pos[i, 0] < 0 for i in halves["dpc_left"])
        assert all(pos[i, 0] >= 0 for i in halves["dpc_right"])

    def test_set_pattern_lights_exactly_the_pattern(self, device):
        colour = list(device.colours)[0]
        idx = device.set_pattern("dpc_left", colour=colour, brightness=0.4)
        assert device.pattern == "dpc_left"
        assert device.lit() == {int(i): (colour, 0.4) for i in idx}
        with pytest.raises(DeviceValueError):
            device.set_pattern("phase_contrast")
        assert device.pattern == "dpc_left"

    def test_set_leds_replace_additive_off(self, device):
        colours = list(device.colours)
        device.set_leds([0, 1], colours[0], 0.5)
        assert device.lit() == {0: (colours[0], 0.5), 1: (colours[0], 0.5)}
        assert device.pattern is None
        device.set_leds(2, colours[-1], 1.0, additive=True)
        assert set(device.lit()) == {0, 1, 2}
        device.set_leds([1], colours[0], 0.0, additive=True)  # brightness 0 = off
        assert set(device.lit()) == {0, 2}
        device.set_leds([3])
        assert set(device.lit()) == {3}
        mask = np.zeros(device.n_leds, bool)
        mask[[4, 5]] = True
        device.set_leds(mask)
        assert set(device.lit()) == {4, 5}
        device.all_off()
        assert device.lit() == {}

    def test_set_leds_validates_before_changing(self, device):
        device.set_leds([0])
        before = device.lit()
        n = device.n_leds
        for args in ([[n]], [[-1]], [[0.5]], [np.zeros(n + 1, bool)], [[0], "ultraviolet"],
                     [[0], list(device.colours)[0], 1.5], [[0], list(device.colours)[0], -1]):
            with pytest.raises(DeviceValueError):
                device.set_leds(*args)
        assert device.lit() == before

    def test_reconnect_restores_lit_leds(self, device):
        idx = device.set_pattern("dpc_top")
        device.reconnect()
        assert set(device.lit()) == set(idx.tolist())
        assert device.pattern == "dpc_top"


class SerialLedArrayConformance(LedArrayConformance):
    """An LED array board on a serial port, served by a pty emulator (``self.emu``)."""

    def test_a_failed_clear_at_close_is_a_warning(self, device, caplog):
        device.set_pattern("brightfield", timeout_s=5.0)
        self.emu.drop_replies(1)  # the clear's reply lost: the LEDs may still be lit
        with caplog.at_level(logging.WARNING, logger="drivers"):
            device.close()
        assert not device.is_open
        assert [r for r in caplog.records if r.levelno == logging.WARNING
                and "could not be cleared on close" in r.getMessage()]
