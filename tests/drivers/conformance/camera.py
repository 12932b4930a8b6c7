"""Conformance suite of cameras: settings, snap, streaming and frame counters."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from drivers.camera import EXTRA_FORMATS, PIXEL_FORMATS, FrameRing
from drivers.errors import (
    CameraTimeoutError,
    DeviceStateError,
    DeviceValueError,
)

from .base import DeviceConformance


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
            "frame_rate_hz": device.frame_rate_hz / 2,
            "gain": 3.0 if device.gain != 3.0 else 1.0,
            "trigger_mode": "software" if device.trigger_mode != "software" else "free_run",
        }

    def invalid_settings(self, device):
        rows, cols = device.sensor_shape
        return [
            {"exposure_s": 0}, {"exposure_s": -1e-3}, {"exposure_s": math.nan},
            {"exposure_s": "fast"}, {"exposure_s": 1e9}, {"gain": -1.0}, {"gain": math.inf},
            {"frame_rate_hz": 0}, {"frame_rate_hz": -5.0}, {"frame_rate_hz": math.nan},
            {"frame_rate_hz": "fast"}, {"frame_rate_hz": True}, {"frame_rate_hz": 1e9},
            {"pixel_format": "cmyk8"}, {"pixel_format": 12},
            *[{"pixel_format": f} for f in sorted(EXTRA_FORMATS)
              if f not in device.info["pixel_formats"]][:1],
            {"roi": [0, 0, cols + 1, rows]}, {"roi": [cols, 0, 1, 1]}, {"roi": [0, 0, 10]},
            {"roi": [0, 0, 0, 10]}, {"roi": [-1, 0, 10, 10]}, {"roi": "full"},
            {"binning": 0}, {"binning": 1.5}, {"binning": True},
            {"roi": [0, 0, 2, 2], "binning": 4},
            {"trigger_mode": "external"},
        ]

    def assert_settings_in_effect(self, device, settings):
        assert device.frame_rate_hz == pytest.approx(settings["frame_rate_hz"], rel=0.01)
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

    def test_snap_in_the_extra_formats_offered(self, device):
        rows, cols = device.sensor_shape
        for fmt in [f for f in device.info["pixel_formats"] if f in EXTRA_FORMATS]:
            binning = 1 if fmt.startswith("bayer") else 2
            device.apply_settings({"pixel_format": fmt, "roi": (2, 4, cols // 2, rows // 2),
                                   "binning": binning})
            frame = device.snap()
            assert frame.image.shape == device.image_shape
            assert frame.image.shape[2:] == ((3,) if fmt.startswith("rgb") else ())
            assert frame.image.dtype == (np.uint8 if EXTRA_FORMATS[fmt] == 8 else np.uint16)
            assert int(frame.image.max()) < 2 ** EXTRA_FORMATS[fmt]

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
        # until three came one after another: a real-time camera whose grab thread a
        # loaded host wakes late loses frames in between (counted, below)
        ring = FrameRing(8)
        device.start_stream(ring)
        frames = []
        try:
            while len(frames) < 60:
                frames.append(ring.get(timeout_s=30.0))  # a hang guard
                last3 = [f.index for f in frames[-3:]]
                if len(last3) == 3 and last3 == list(range(last3[0], last3[0] + 3)):
                    break
        finally:
            device.stop_stream()
        indices = [f.index for f in frames]
        assert indices[-3:] == list(range(indices[-3], indices[-3] + 3))
        assert indices == sorted(set(indices))  # in order, none twice
        c = ring.counters()
        assert ring.read == len(frames)
        assert c["acquired"] == c["read"] + c["skipped"] + c["buffered"]
        assert indices[-1] - indices[0] + 1 - len(indices) <= c["skipped"]  # gaps counted

    def test_stream_counts_skipped_frames_when_not_read(self, device):
        device.trigger_mode = "software"
        ring = FrameRing(2)
        device.start_stream(ring)
        try:
            for taken in range(1, 6):
                device.trigger()
                self.advance_time(device, device.exposure_s * 2 + 0.1)
                hang_guard = time.monotonic() + 30.0  # the frame is in, however late a
                while ring.acquired < taken and time.monotonic() < hang_guard:  # loaded
                    time.sleep(0.01)  # host delivers it
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

    #: Free-run intervals within this fraction of the expected period count as seen.
    PERIOD_REL = 0.02

    def _assert_stream_period(self, device, period_s: float, needed: int = 3,
                              max_frames: int = 60) -> None:
        """Free-run frames come ``period_s`` apart: read frames until ``needed`` intervals
        of their device timestamps lie within :attr:`PERIOD_REL` of ``period_s``, or fail
        after ``max_frames`` frames naming the intervals seen.

        An event, not a median: a camera whose thread wakes late on a loaded machine (the
        fake cameras stamp frames when their thread wakes) stretches some intervals and
        shortens the next, but the frames that come on time still come ``period_s``
        apart; a camera running at another rate gives no such interval. The first frame
        of the stream is left out: a real camera's first interval after the start is not
        its steady period (aravis's fake GigE camera aligns frames to a period grid)."""
        ring = FrameRing(8)
        device.start_stream(ring)
        intervals = []
        try:
            ring.get(timeout_s=30.0)
            last = ring.get(timeout_s=30.0).device_timestamp_s
            for _ in range(max_frames):
                stamp = ring.get(timeout_s=30.0).device_timestamp_s
                intervals.append(stamp - last)
                last = stamp
                on_time = [d for d in intervals
                           if abs(d - period_s) <= self.PERIOD_REL * period_s]
                if len(on_time) >= needed:
                    return
        finally:
            device.stop_stream()
        pytest.fail(f"no {needed} free-run intervals of {period_s:.4f} s (+-"
                    f"{self.PERIOD_REL:.0%}) in {len(intervals)}: "
                    f"{[round(d, 4) for d in intervals]}")

    def test_frame_rate_setting_sets_the_free_run_rate(self, device):
        lo_exposure = device.exposure_s
        device.exposure_s = min(lo_exposure, 0.002)
        rate = min(20.0, device.frame_rate_hz)
        device.frame_rate_hz = rate
        assert device.frame_rate_hz == pytest.approx(rate, rel=0.01)  # read back
        resulting = device.resulting_frame_rate_hz
        assert 0 < resulting <= min(rate, 1.0 / device.exposure_s) * (1 + 1e-6)
        self._assert_stream_period(device, 1.0 / resulting)
        device.frame_rate_hz = rate / 2  # changing the rate while streaming is allowed
        device.start_stream(FrameRing(2))
        try:
            device.frame_rate_hz = rate
        finally:
            device.stop_stream()

    def test_exposure_longer_than_the_frame_period_limits_the_rate(self, device):
        rate = min(20.0, device.frame_rate_hz)
        device.frame_rate_hz = rate
        device.exposure_s = 2.0 / rate  # twice the requested period: accepted
        assert device.frame_rate_hz == pytest.approx(rate, rel=0.01)  # the setting stays
        resulting = device.resulting_frame_rate_hz
        assert resulting <= rate / 2 * (1 + 1e-6)
        self._assert_stream_period(device, 1.0 / resulting)
