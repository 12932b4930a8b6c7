"""Conformance suite of DMD pattern sequencers."""

from __future__ import annotations

import pytest

from drivers.dmd import PatternEntry
from drivers.errors import DeviceStateError, DeviceValueError, DmdTimeoutError

from .base import DeviceConformance


class DmdConformance(DeviceConformance):
    """DMD behaviour: settings, sequence validation, load, start and stop."""

    kind = "dmd"
    timeout_error = DmdTimeoutError

    def _sequence(self, device, n=3):
        colour = next(iter(device.colours))
        return [PatternEntry(image=0, bit=i, colour=colour) for i in range(n)]

    def use(self, device):
        return device.sequence

    def blocking_call(self, device):
        device.load_sequence(self._sequence(device), timeout_s=1.0)

    def changed_settings(self, device):
        period = device.period_s * 2
        return {"period_s": period, "exposure_s": period / 4,
                "led_currents": {c: (0.25 if v != 0.25 else 0.5)
                                 for c, v in device.led_currents.items()}}

    def invalid_settings(self, device):
        colour = next(iter(device.colours))
        return [
            {"exposure_s": 0.0}, {"exposure_s": -1e-3}, {"period_s": "fast"},
            {"exposure_s": 0.02, "period_s": 0.01},  # exposure longer than the period
            {"led_currents": {colour: 1.5}}, {"led_currents": {"ultraviolet": 0.5}},
            {"led_currents": 0.5},
        ]

    def assert_settings_in_effect(self, device, settings):
        device.load_sequence(self._sequence(device))
        device.start()
        assert device.running
        device.stop()

    def test_geometry(self, device):
        rows, cols = device.resolution
        assert rows > 0 and cols > 0 and device.colours
        assert set(device.led_currents) == set(device.colours)
        assert device.exposure_s <= device.period_s

    def test_load_start_stop(self, device):
        assert device.sequence == () and not device.running
        with pytest.raises(DeviceStateError, match="load_sequence"):
            device.start()
        colour = list(device.colours)[-1]
        seq = device.load_sequence([{"image": 1, "bit": 5, "colour": colour},
                                    PatternEntry(2, 0, bit_depth=8, colour=colour, invert=True)])
        assert device.sequence == seq and seq[0] == PatternEntry(1, 5, 1, colour, False)
        device.start()
        assert device.running
        device.load_sequence(self._sequence(device))  # loading stops a running sequence
        assert not device.running
        device.start()
        device.stop()
        assert not device.running

    def test_invalid_sequences_are_refused_before_sending(self, device):
        device.load_sequence(self._sequence(device, 2))
        before = device.sequence
        colour = next(iter(device.colours))
        for bad in ([], [{"image": 0, "bit": 24}], [{"image": 0, "bit": 3, "bit_depth": 8}],
                    [{"image": 0, "bit": 0, "bit_depth": 9}], [{"image": -1, "bit": 0}],
                    [{"image": 0, "bit": 0, "colour": "ultraviolet"}], [{"img": 0}],
                    [{"image": 0, "bit": 0, "colour": colour, "invert": "yes"}]):
            with pytest.raises(DeviceValueError, match=device.device_id):
                device.load_sequence(bad)
        with pytest.raises(DeviceValueError):
            device.load_sequence([{"image": 1, "bit": 0}], source="video")  # video: image 0
        with pytest.raises(DeviceValueError):
            device.load_sequence(self._sequence(device), source="hdmi")
        assert device.sequence == before

    def test_reconnect_restores_the_running_sequence(self, device):
        seq = device.load_sequence(self._sequence(device, 4))
        device.start()
        device.reconnect()
        assert device.sequence == seq and device.running
