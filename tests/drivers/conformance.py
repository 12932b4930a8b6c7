"""Conformance suites every driver of a kind must pass.

Use one as a base class of a pytest test class that provides:

- a ``device`` fixture yielding an *opened* device (closed again afterwards);
- ``provoke_timeout(device)``: arrange for the next blocking call to time out
  (fault injection for simulated devices, an emulator delay for real drivers);
- optionally ``advance_time(device, seconds)``: let time pass (default: sleep,
  simulated devices advance their clock).

Example::

    class TestMyCamera(CameraConformance):
        @pytest.fixture
        def device(self):
            with MyCamera("cam0", port=...) as cam:
                yield cam

        def provoke_timeout(self, device):
            emulator.delay_next_reply(10.0)
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
import pytest

from drivers.camera import PIXEL_FORMATS, FrameRing
from drivers.errors import (
    CameraTimeoutError,
    DeviceError,
    DeviceStateError,
    DeviceTimeoutError,
    DeviceValueError,
    LedArrayTimeoutError,
    SlmTimeoutError,
    StageLimitError,
    StageTimeoutError,
)
from drivers.led_array import PATTERNS
from drivers.slm import TWO_PI, linear_lut


class DeviceConformance:
    """Lifecycle, settings and timeout behaviour common to every kind."""

    kind = ""
    timeout_error: type[DeviceTimeoutError] = DeviceTimeoutError

    # ------------------------------------------------------------- subclass hooks
    def provoke_timeout(self, device) -> None:
        raise NotImplementedError("the test class must implement provoke_timeout(device)")

    def advance_time(self, device, seconds: float) -> None:
        time.sleep(seconds)

    # ------------------------------------------------------------- kind hooks
    def use(self, device) -> Any:
        """A public call that needs an open device."""
        raise NotImplementedError

    def blocking_call(self, device) -> Any:
        """A call with a timeout (to be made to time out by provoke_timeout)."""
        raise NotImplementedError

    def changed_settings(self, device) -> dict[str, Any]:
        """Valid settings that differ from the current ones in every name."""
        raise NotImplementedError

    def invalid_settings(self, device) -> list[dict[str, Any]]:
        """Settings dicts that must each be rejected with DeviceValueError."""
        raise NotImplementedError

    def assert_settings_in_effect(self, device, settings: dict[str, Any]) -> None:
        """Check, through the device's behaviour, that ``settings`` are in effect."""

    # ------------------------------------------------------------- tests
    def test_kind_and_id(self, device):
        assert device.kind == self.kind
        assert device.timeout_error is self.timeout_error
        assert isinstance(device.device_id, str) and device.device_id
        assert device.device_id in repr(device)

    def test_open_close_idempotent(self, device):
        assert device.is_open
        device.open()  # no-op
        assert device.is_open
        device.close()
        device.close()
        assert not device.is_open
        device.open()
        device.open()
        assert device.is_open
        self.use(device)

    def test_context_manager(self, device):
        device.close()
        with device as d:
            assert d is device and device.is_open
            self.use(device)
        assert not device.is_open

    def test_use_before_open_raises_state_error(self, device):
        device.close()
        for call in (self.use, lambda d: d.settings(), lambda d: d.apply_settings({})):
            with pytest.raises(DeviceStateError, match=device.device_id) as info:
                call(device)
            assert "open()" in str(info.value) and "Fix:" in str(info.value)
        status = device.status()
        assert status["is_open"] is False and status["kind"] == self.kind

    def test_open_rejects_bad_timeout(self, device):
        device.close()
        for bad in (0, -1.0, math.nan, "5"):
            with pytest.raises(DeviceValueError):
                device.open(timeout_s=bad)
        assert not device.is_open

    def test_settings_json_roundtrip(self, device):
        original = device.settings()
        assert list(original) == list(type(device)._SETTINGS)
        text = json.dumps(original)
        changed = self.changed_settings(device)
        device.apply_settings(changed)
        after = device.settings()
        for name in changed:
            assert after[name] != original[name], name
        device.apply_settings(json.loads(text))
        assert device.settings() == original

    def test_reconnect_reapplies_settings(self, device):
        changed = self.changed_settings(device)
        device.apply_settings(changed)
        before = device.settings()
        device.reconnect()
        assert device.is_open
        assert device.settings() == before
        self.assert_settings_in_effect(device, before)

    def test_reconnect_after_close(self, device):
        device.apply_settings(self.changed_settings(device))
        before = device.settings()
        device.close()
        device.reconnect()
        assert device.settings() == before

    def test_unknown_setting_rejected(self, device):
        before = device.settings()
        with pytest.raises(DeviceValueError, match="unknown settings"):
            device.apply_settings({"no_such_setting": 1})
        with pytest.raises(DeviceValueError):
            device.apply_settings([("a", 1)])
        assert device.settings() == before

    def test_invalid_settings_rejected_atomically(self, device):
        before = device.settings()
        changed = self.changed_settings(device)
        for bad in self.invalid_settings(device):
            # a valid change next to the bad one must not be applied either
            mixed = {**changed, **bad}
            with pytest.raises(DeviceValueError, match=device.device_id) as info:
                device.apply_settings(mixed)
            assert isinstance(info.value, ValueError) and "Fix:" in str(info.value)
            assert device.settings() == before, bad

    def test_status_is_json(self, device):
        status = device.status()
        json.dumps(status)
        assert status["device_id"] == device.device_id
        assert status["is_open"] is True and status["disconnected"] is False

    def test_timeout_raises_kind_error(self, device):
        self.provoke_timeout(device)
        with pytest.raises(self.timeout_error) as info:
            self.blocking_call(device)
        exc = info.value
        assert isinstance(exc, DeviceTimeoutError) and isinstance(exc, TimeoutError)
        assert isinstance(exc, DeviceError) and exc.device_id == device.device_id
        assert "Fix:" in str(exc)
        self.blocking_call(device)  # the device works again afterwards


class CameraConformance(DeviceConformance):
    """Camera behaviour: settings, snap, streaming and frame counters."""

    kind = "camera"
    timeout_error = CameraTimeoutError

    def use(self, device):
        return device.snap()

    def blocking_call(self, device):
        return device.snap(timeout_s=1.0)

    def changed_settings(self, device):
        rows, cols = device.sensor_shape
        fmt = "mono8" if device.pixel_format != "mono8" else "mono16"
        return {
            "pixel_format": fmt,
            "roi": [1, 2, cols - 3, rows - 4],
            "binning": 2 if device.binning != 2 else 1,
            "exposure_s": device.exposure_s * 2,
            "gain": 3.0 if device.gain != 3.0 else 1.0,
            "trigger_mode": "software" if device.trigger_mode != "software" else "free_run",
        }

    def invalid_settings(self, device):
        rows, cols = device.sensor_shape
        return [
            {"exposure_s": 0}, {"exposure_s": -1e-3}, {"exposure_s": math.nan},
            {"exposure_s": "fast"}, {"exposure_s": 1e9}, {"gain": -1.0}, {"gain": math.inf},
            {"pixel_format": "rgb8"}, {"pixel_format": 12},
            {"roi": [0, 0, cols + 1, rows]}, {"roi": [cols, 0, 1, 1]}, {"roi": [0, 0, 10]},
            {"roi": [0, 0, 0, 10]}, {"roi": [-1, 0, 10, 10]}, {"roi": "full"},
            {"binning": 0}, {"binning": 1.5}, {"binning": True},
            {"roi": [0, 0, 2, 2], "binning": 4},
            {"trigger_mode": "external"},
        ]

    def assert_settings_in_effect(self, device, settings):
        if settings["trigger_mode"] == "hardware":
            return
        frame = device.snap()
        x, y, w, h = settings["roi"]
        b = settings["binning"]
        assert frame.image.shape == (h // b, w // b)
        assert frame.image.dtype == (np.uint8 if settings["pixel_format"] == "mono8" else np.uint16)
        assert frame.exposure_s == pytest.approx(settings["exposure_s"])
        assert frame.gain == pytest.approx(settings["gain"])

    def test_readonly_geometry(self, device):
        rows, cols = device.sensor_shape
        assert rows > 0 and cols > 0 and device.pixel_pitch_um > 0
        with pytest.raises(AttributeError):
            device.sensor_shape = (1, 1)
        with pytest.raises(AttributeError):
            device.bit_depth = 8
        assert device.roi == (0, 0, cols, rows) or device.roi[2] <= cols

    @pytest.mark.parametrize("fmt", sorted(PIXEL_FORMATS))
    @pytest.mark.parametrize("binning", [1, 2, 3])
    def test_snap_follows_roi_binning_format(self, device, fmt, binning):
        rows, cols = device.sensor_shape
        roi = (3, 5, cols // 2 + 1, rows // 2)
        device.apply_settings({"pixel_format": fmt, "roi": roi, "binning": binning})
        assert device.bit_depth == PIXEL_FORMATS[fmt]
        assert device.image_shape == (roi[3] // binning, roi[2] // binning)
        frame = device.snap()
        assert frame.image.shape == device.image_shape
        assert frame.image.dtype == (np.uint8 if fmt == "mono8" else np.uint16)
        assert int(frame.image.max()) < 2 ** PIXEL_FORMATS[fmt]
        device.roi = None
        assert device.roi == (0, 0, cols, rows)

    def test_frame_metadata_and_index(self, device):
        device.apply_settings({"exposure_s": 0.005, "gain": 2.0})
        frames = [device.snap() for _ in range(3)]
        assert [f.index for f in frames] == list(range(frames[0].index, frames[0].index + 3))
        stamps = [f.device_timestamp_s for f in frames]
        assert stamps[0] < stamps[1] < stamps[2]
        for f in frames:
            assert f.exposure_s == pytest.approx(0.005) and f.gain == pytest.approx(2.0)
            assert isinstance(f.saturated_pixels, int) and f.saturated_pixels >= 0
            assert f.host_timestamp_s > 0

    def test_settings_changes_while_streaming(self, device):
        ring = FrameRing(4)
        device.start_stream(ring)
        try:
            with pytest.raises(DeviceStateError, match="stop_stream"):
                device.snap()
            with pytest.raises(DeviceStateError):
                device.binning = 2
            with pytest.raises(DeviceStateError):
                device.start_stream(FrameRing(2))
            device.exposure_s = device.exposure_s * 1.5  # allowed while streaming
            device.binning = device.binning  # unchanged value is fine
        finally:
            device.stop_stream()
        device.stop_stream()  # idempotent
        assert not device.is_streaming
        with pytest.raises(DeviceValueError):
            device.start_stream("ring")

    def test_trigger_requires_software_stream(self, device):
        device.trigger_mode = "software"
        with pytest.raises(DeviceStateError, match="software"):
            device.trigger()  # not streaming
        device.trigger_mode = "free_run"
        device.start_stream(FrameRing(2))
        try:
            with pytest.raises(DeviceStateError):
                device.trigger()
        finally:
            device.stop_stream()

    def test_free_run_stream_delivers_consecutive_frames(self, device):
        ring = FrameRing(8)
        device.start_stream(ring)
        try:
            frames = [ring.get(timeout_s=2.0) for _ in range(3)]
        finally:
            device.stop_stream()
        indices = [f.index for f in frames]
        assert indices == list(range(indices[0], indices[0] + 3))
        assert ring.read == 3 and ring.dropped == 0
        c = ring.counters()
        assert c["acquired"] == c["read"] + c["skipped"] + c["buffered"]

    def test_stream_counts_skipped_frames_when_not_read(self, device):
        device.trigger_mode = "software"
        ring = FrameRing(2)
        device.start_stream(ring)
        try:
            for _ in range(5):
                device.trigger()
                self.advance_time(device, device.exposure_s * 2 + 0.1)
        finally:
            device.stop_stream()
        assert (ring.acquired, ring.read, ring.skipped, len(ring)) == (5, 0, 3, 2)
        first, second = ring.get(timeout_s=1.0), ring.get(timeout_s=1.0)
        assert second.index == first.index + 1  # the two newest frames survive
        assert ring.read == 2

    def test_stream_get_times_out_without_trigger(self, device):
        device.trigger_mode = "software"
        ring = FrameRing(2)
        device.start_stream(ring)
        try:
            with pytest.raises(CameraTimeoutError, match=device.device_id):
                ring.get(timeout_s=0.2)
        finally:
            device.stop_stream()

    def test_snap_rejects_bad_timeout(self, device):
        for bad in (0, -1, math.nan):
            with pytest.raises(DeviceValueError):
                device.snap(timeout_s=bad)


class StageConformance(DeviceConformance):
    """Stage behaviour: moves, homing, limits and backlash."""

    kind = "stage"
    timeout_error = StageTimeoutError
    position_tolerance = 1e-6

    def _axis(self, device) -> tuple[str, float, float]:
        axis = device.axes[0]
        lo, hi = device.limits[axis]
        return axis, lo, hi

    def use(self, device):
        return device.positions()

    def blocking_call(self, device):
        axis, lo, hi = self._axis(device)
        target = lo + 0.25 * (hi - lo) if device.position(axis) > (lo + hi) / 2 else hi - 0.25 * (
            hi - lo)
        device.move_to({axis: target}, timeout_s=60.0)

    def changed_settings(self, device):
        axis, lo, hi = self._axis(device)
        span = hi - lo
        return {
            "limits": {axis: [lo + 0.05 * span, hi - 0.05 * span]},
            "velocity": {axis: device.velocity[axis] / 2},
            "backlash": {axis: 0.01 * span},
        }

    def invalid_settings(self, device):
        axis, _, _ = self._axis(device)
        tlo, thi = device.travel[axis]
        return [
            {"velocity": {axis: 0}}, {"velocity": {axis: -1.0}}, {"velocity": {axis: 1e12}},
            {"velocity": 2.0}, {"velocity": {"w": 1.0}},
            {"limits": {axis: [tlo - 1, thi]}}, {"limits": {axis: [thi, tlo]}},
            {"limits": {axis: [tlo]}}, {"backlash": {axis: math.nan}},
        ]

    def assert_settings_in_effect(self, device, settings):
        axis = next(iter(settings["limits"]))
        lo, hi = settings["limits"][axis]
        with pytest.raises(StageLimitError):
            device.move_to({axis: hi + 1e-3 * (hi - lo)})

    def test_axes_units_and_positions(self, device):
        assert device.axes and set(device.positions()) == set(device.axes)
        for a in device.axes:
            assert device.units(a) in ("mm", "deg")
            tlo, thi = device.travel[a]
            lo, hi = device.limits[a]
            assert tlo <= lo < hi <= thi
        with pytest.raises(DeviceValueError, match="unknown axis"):
            device.position("w")

    def test_move_to_and_move_by(self, device):
        axis, lo, hi = self._axis(device)
        target = lo + 0.3 * (hi - lo)
        device.move_to({axis: target})
        assert not device.is_moving()
        assert device.position(axis) == pytest.approx(target, abs=self.position_tolerance)
        device.move_by({axis: 0.1 * (hi - lo)})
        assert device.position(axis) == pytest.approx(target + 0.1 * (hi - lo),
                                                      abs=self.position_tolerance)
        with pytest.raises(DeviceValueError):
            device.move_by([(axis, 1.0)])
        with pytest.raises(DeviceValueError):
            device.move_to({})

    def test_move_without_wait(self, device):
        axis, lo, hi = self._axis(device)
        start = device.position(axis)
        target = hi - 0.1 * (hi - lo) if start < (lo + hi) / 2 else lo + 0.1 * (hi - lo)
        device.move_to({axis: target}, wait=False)
        assert device.is_moving()
        device.wait_until_idle(timeout_s=60.0)
        assert not device.is_moving()
        assert device.position(axis) == pytest.approx(target, abs=self.position_tolerance)

    def test_home(self, device):
        axis, lo, hi = self._axis(device)
        device.move_to({axis: lo + 0.9 * (hi - lo)})
        device.home(timeout_s=120.0)
        assert not device.is_moving()
        device.home([axis], timeout_s=120.0)
        with pytest.raises(DeviceValueError):
            device.home(["w"])

    def test_limits_checked_before_anything_moves(self, device):
        before = device.positions()
        axes = device.axes
        lo, hi = device.limits[axes[-1]]
        targets = {a: sum(device.limits[a]) / 2 for a in axes[:-1]}
        targets[axes[-1]] = hi + 0.01 * (hi - lo)
        with pytest.raises(StageLimitError, match="outside the limits") as info:
            device.move_to(targets)
        assert isinstance(info.value, ValueError) and "Fix:" in str(info.value)
        assert not device.is_moving()
        assert device.positions() == before
        with pytest.raises(DeviceValueError):
            device.move_to({axes[0]: math.nan})
        with pytest.raises(DeviceValueError, match="unknown axis"):
            device.move_to({"w": 0.0})

    def test_narrowed_limits_apply(self, device):
        axis, lo, hi = self._axis(device)
        mid = (lo + hi) / 2
        device.limits = {axis: (lo, mid)}
        assert device.limits[axis] == (lo, mid)
        with pytest.raises(StageLimitError):
            device.move_to({axis: mid + 0.01 * (hi - lo)})
        device.move_to({axis: mid})

    def test_backlash_approaches_from_one_side(self, device):
        axis, lo, hi = self._axis(device)
        b = 0.02 * (hi - lo)
        device.backlash = {axis: b}
        low_t, high_t = lo + 0.3 * (hi - lo), lo + 0.6 * (hi - lo)
        device.move_to({axis: high_t})  # moving up: same direction as b > 0, direct
        assert len(device.last_path) == 1
        device.move_to({axis: low_t})  # moving down: overshoot to low_t - b, then up
        path = device.last_path
        assert [leg[axis] for leg in path] == pytest.approx([low_t - b, low_t])
        assert device.position(axis) == pytest.approx(low_t, abs=self.position_tolerance)
        device.backlash = {axis: 0.0}
        device.move_to({axis: lo + 0.1 * (hi - lo)})
        assert len(device.last_path) == 1

    def test_backlash_overshoot_must_be_within_limits(self, device):
        axis, lo, hi = self._axis(device)
        device.move_to({axis: lo + 0.5 * (hi - lo)})
        device.backlash = {axis: 0.1 * (hi - lo)}
        before = device.positions()
        with pytest.raises(StageLimitError, match="overshoot"):
            device.move_to({axis: lo + 0.05 * (hi - lo)})
        assert device.positions() == before and not device.is_moving()


class LedArrayConformance(DeviceConformance):
    """LED array behaviour: geometry, patterns and the lit state."""

    kind = "led_array"
    timeout_error = LedArrayTimeoutError

    def use(self, device):
        return device.lit()

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
