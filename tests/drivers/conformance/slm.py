"""Conformance suite of phase SLMs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.errors import (
    DeviceValueError,
    SlmTimeoutError,
)
from drivers.slm import TWO_PI, linear_lut

from .base import DeviceConformance


class SlmConformance(DeviceConformance):
    """SLM behaviour: LUT, phase wrapping, display and pattern ids."""

    kind = "slm"
    timeout_error = SlmTimeoutError

    def use(self, device):
        return device.current_image()

    def blocking_call(self, device):
        return device.show_phase(np.zeros(device.resolution), timeout_s=1.0)

    def changed_settings(self, device):
        return {"lut_rad": (TWO_PI * (np.arange(256) / 256) ** 1.3).tolist(),
                "settle_s": device.settle_s + 0.005}

    def invalid_settings(self, device):
        ramp = linear_lut()
        return [
            {"lut_rad": ramp[:255].tolist()}, {"lut_rad": np.r_[ramp[:128], ramp[:128]].tolist()},
            {"lut_rad": [1.0] * 256}, {"lut_rad": np.r_[ramp[:255], np.nan].tolist()},
            {"lut_rad": "linear"}, {"settle_s": -0.1}, {"settle_s": math.inf},
        ]

    def assert_settings_in_effect(self, device, settings):
        lut = np.asarray(settings["lut_rad"])
        device.show_phase(np.full(device.resolution, lut[77]))
        assert np.all(device.current_image() == 77)

    def test_geometry(self, device):
        rows, cols = device.resolution
        assert rows > 0 and cols > 0 and device.pixel_pitch_um > 0 and device.wavelength_nm > 0
        assert device.lut_rad.shape == (256,)
        img = device.current_image()
        assert img.shape == (rows, cols) and img.dtype == np.uint8

    def test_show_phase_applies_the_lut_inverse(self, device):
        lut = TWO_PI * (np.arange(256) / 256) ** 1.5  # a nonlinear, monotone LUT
        device.lut_rad = lut
        rows, cols = device.resolution
        grays = np.arange(rows * cols).reshape(rows, cols) % 256
        device.show_phase(lut[grays])
        np.testing.assert_array_equal(device.current_image(), grays.astype(np.uint8))
        np.testing.assert_allclose(device.current_phase(), lut[grays])
        # a phase between two levels goes to the nearer one
        mid = 0.3 * lut[100] + 0.7 * lut[101]
        device.show_phase(np.full((rows, cols), mid))
        assert np.all(device.current_image() == 101)

    def test_show_phase_wraps(self, device):
        rows, cols = device.resolution
        rng = np.random.default_rng(1)
        phase = rng.uniform(0, TWO_PI, (rows, cols))
        device.show_phase(phase)
        ref = device.current_image()
        for k in (-3, -1, 1, 2):
            device.show_phase(phase + k * TWO_PI)
            np.testing.assert_array_equal(device.current_image(), ref)
        device.lut_rad = linear_lut()
        device.show_phase(np.full((rows, cols), -1e-9))  # just below 0 wraps to ~2 pi -> 0
        assert np.all(device.current_image() == 0)
        device.show_phase(np.full((rows, cols), TWO_PI - 0.2 * TWO_PI / 256))
        assert np.all(device.current_image() == 0)  # nearest modulo 2 pi is level 0
        device.show_phase(np.full((rows, cols), 1.0))
        assert np.all(device.current_image() == round(256 / TWO_PI))

    def test_pattern_id_increments(self, device):
        start = device.pattern_id
        img = np.zeros(device.resolution, np.uint8)
        ids = [device.show_image(img), device.show_image(img),
               device.show_phase(np.zeros(device.resolution))]
        assert ids == [start + 1, start + 2, start + 3] and device.pattern_id == start + 3

    def test_show_image_roundtrip_and_validation(self, device):
        rows, cols = device.resolution
        img = (np.arange(rows * cols).reshape(rows, cols) * 7 % 256).astype(np.uint8)
        device.show_image(img)
        np.testing.assert_array_equal(device.current_image(), img)
        pid = device.pattern_id
        for bad in (img.astype(np.uint16), img[:-1], img.T if rows != cols else img[:, :-1]):
            with pytest.raises(DeviceValueError):
                device.show_image(bad)
        for bad in (np.zeros((rows, cols + 1)), np.full((rows, cols), np.nan),
                    np.zeros((rows, cols), complex)):
            with pytest.raises(DeviceValueError):
                device.show_phase(bad)
        assert device.pattern_id == pid
        np.testing.assert_array_equal(device.current_image(), img)
