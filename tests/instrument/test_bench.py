"""Bench roles, safe state, prompts, and the virtual bench's operator actions and
bare-sensor optics; bracketed auto-exposure on a sharp PSF."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.errors import DeviceError
from instrument.acquisition.exposure import autoexpose
from instrument.devices.bench import Bench, BenchRoleError, PromptRefused
from instrument.devices.virtual_bench import VirtualBench


@pytest.fixture
def vb():
    with VirtualBench(seed=2) as bench:
        yield bench


def test_roles_and_ids(vb):
    assert vb.device("camera") is vb.camera
    assert vb.device("source_stage") is vb.devices["source_stage"]
    assert "rotation" in vb.mask_stage.axes and "rotation" not in vb.source_stage.axes
    with pytest.raises(BenchRoleError, match="neither a device id"):
        vb.device("laser")
    with pytest.raises(BenchRoleError, match="not open"):
        Bench().device("camera")
    only_cam = Bench({"camera": vb.camera})
    assert only_cam.has("camera") and not only_cam.has("slm")
    with pytest.raises(BenchRoleError, match="no slm"):
        _ = only_cam.slm


def test_safe_state_turns_leds_off_and_survives_a_dead_device(vb):
    vb.led_array.set_leds([1, 2, 3])
    vb.camera.faults.disconnect()  # a dead camera must not stop the LEDs going off
    problems = vb.safe_state()
    assert vb.led_array.lit() == {}
    assert problems == {}  # a camera that is not streaming needs nothing
    vb.led_array.faults.disconnect()
    assert "led_array" in vb.safe_state()
    snap = vb.settings_snapshot()
    assert "error" in snap["led_array"] and "settings" in snap["source_stage"]


def test_prompt_needs_an_operator(vb):
    with pytest.raises(PromptRefused, match="cap"):
        Bench(vb.devices).prompt("cap_camera", "cap the camera")
    with pytest.raises(PromptRefused, match="cannot"):
        vb.prompt("polish_lens", "polish the lens")


def test_operator_actions_change_what_the_camera_sees(vb):
    vb.source_stage.move_to({"z": 40.0})
    vb.led_array.set_leds(np.arange(vb.led_array.n_leds))
    caustics = vb.irradiance(vb.camera).copy()
    vb.prompt("cap_camera", "cap")
    assert not np.any(vb.irradiance(vb.camera))
    vb.prompt("uncap_camera", "uncap")
    vb.prompt("remove_diffuser", "remove the diffuser")
    bare = vb.irradiance(vb.camera)
    # bare sensor: smooth, everywhere lit, brightest near the axis
    assert bare.min() > 0 and bare.max() / bare.min() < 1.5
    assert caustics.max() / caustics.mean() > 5
    # incidence fall-off: moving the source off axis dims the centre pixel beyond cos^3
    centre = bare[128, 160]
    vb.source_stage.move_to({"x": 20.0})
    theta = np.arctan(20.0 / (40.0 + vb.geometry.d_mm))
    expected = np.cos(theta) ** 3 * np.exp(-theta**2 / (2 * np.radians(20.0) ** 2))
    assert vb.irradiance(vb.camera)[128, 160] / centre == pytest.approx(expected, rel=0.02)
    vb.prompt("install_diffuser", "put it back")
    vb.prompt("remove_pinhole", "remove the pinhole")
    pos = vb.led_array.positions_mm
    vb.led_array.set_leds([int(np.argmin(np.hypot(*pos.T)))])  # the LED nearest the axis
    assert vb.irradiance(vb.camera).sum() > 0  # one LED seen through the diffuser


def test_autoexpose_closes_its_bracket_on_a_sharp_peak(vb):
    """A caustic PSF can saturate a few pixels before its 99.99th percentile reaches
    a high target: the search ends at the longest unsaturated exposure."""
    vb.source_stage.move_to({"z": 60.0})
    vb.led_array.set_leds(np.arange(vb.led_array.n_leds))
    vb.camera.exposure_s = 1e-4
    result = autoexpose(vb.camera, target=0.95, tolerance=0.01, bounds_s=(1e-5, 1.0))
    assert result.peak_fraction < 0.94 and result.trials <= 12  # target out of reach
    assert vb.camera.exposure_s == result.exposure_s
    vb.camera.exposure_s = result.exposure_s * 0.8
    assert vb.camera.snap().saturated_pixels == 0
    vb.camera.exposure_s = result.exposure_s * 1.25
    assert vb.camera.snap().saturated_pixels > 0  # the bracket was closed at saturation
    with pytest.raises(DeviceError):
        autoexpose(vb.camera, target=0.5, bounds_s=(1e-5, 1e-5 * 1.01))
