"""Camera interface: :class:`Camera`, :class:`Frame` and the bounded :class:`FrameRing`.

Conventions
-----------
- ``gain`` is the analog gain in dB (>= 0; 0 dB is the sensor's native conversion
  gain, +6.02 dB doubles the digital numbers per electron).
- ``roi`` is ``(x, y, width, height)`` in unbinned sensor pixels, x along columns.
- ``binning`` averages ``binning x binning`` blocks of the ROI (values stay on the
  pixel-format scale); a partial block at the right/bottom edge is dropped, so the
  image shape is ``(height // binning, width // binning)``.
- ``pixel_format``: "mono8" -> uint8; "mono12" -> uint16 holding 0..4095;
  "mono16" -> uint16 on the full 16-bit scale (a 12-bit sensor's data shifted up
  by 4 bits, full scale 65520); the formats every camera offers
  (:data:`PIXEL_FORMATS`). A driver may offer more (:data:`EXTRA_FORMATS`): "mono10"
  (uint16 holding 0..1023), "rgb8"/"rgb16" (a colour sensor's image, demosaiced:
  ``(rows, cols, 3)``, red, green, blue) and "bayer8"/"bayer16" (its raw colour
  mosaic, 2D, pattern in ``info["bayer_pattern"]``; no binning, even ROI offsets).
- Frame indices count every frame the camera produced since open, including
  dropped ones, so a gap in indices shows a loss; losses are also counted.
"""

from __future__ import annotations

import abc
import collections
import contextlib
import copy
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from diffuserlab.errors import kept_error
from drivers.base import Device
from drivers.errors import CameraTimeoutError, DeviceError, DeviceStateError, DeviceValueError
from drivers.settings import Setting, info, setting_property

__all__ = ["EXTRA_FORMATS", "PIXEL_FORMATS", "PRODUCING_HANG_S", "TRIGGER_MODES", "Camera",
           "Frame", "FrameRing", "format_bits"]

#: Pixel formats every camera driver offers, and their bit depth.
PIXEL_FORMATS: dict[str, int] = {"mono8": 8, "mono12": 12, "mono16": 16}
#: Formats some drivers offer (a camera that has them): bit depth per channel.
EXTRA_FORMATS: dict[str, int] = {"mono10": 10, "rgb8": 8, "rgb16": 16, "bayer8": 8,
                                 "bayer16": 16}
_ALL_FORMATS = {**PIXEL_FORMATS, **EXTRA_FORMATS}


def format_bits(pixel_format: str) -> int:
    """Bits per pixel (per channel for rgb) of a pixel format name."""
    return _ALL_FORMATS[pixel_format]
#: Trigger modes: continuous, on :meth:`Camera.trigger`, on an external pulse.
TRIGGER_MODES: tuple[str, ...] = ("free_run", "software", "hardware")


@dataclass(frozen=True, eq=False)
class Frame:
    """One camera frame with its metadata.

    Attributes
    ----------
    image : ndarray
        ``(rows, cols)`` uint8 (mono8, bayer8) or uint16 (mono10/12/16, bayer16), or
        ``(rows, cols, 3)`` for rgb8/rgb16, after ROI and binning.
    index : int
        Frame number since the camera was opened (dropped frames use up numbers).
    device_timestamp_s : float
        Start of the exposure on the camera's clock, in seconds.
    host_timestamp_s : float
        Host wall-clock time (``time.time()``) when the frame was delivered, in seconds.
    exposure_s : float
        Exposure time, in seconds.
    gain : float
        Analog gain, in dB.
    saturated_pixels : int
        Number of unbinned sensor pixels inside the ROI that hit full well or the ADC
        full scale.
    """

    image: np.ndarray
    index: int
    device_timestamp_s: float
    host_timestamp_s: float
    exposure_s: float
    gain: float
    saturated_pixels: int


def _to_raise(error: BaseException) -> BaseException:
    """A copy of a producer's stored error, to raise to one reader (the same type,
    message and cause). Raising an exception gives it a traceback whose frames hold the
    ring: the stored error would make a reference cycle, and keep the readers' frames,
    once frozen for good (:func:`gui.workers.settle_heap`). An error that cannot be
    copied is raised itself."""
    try:
        fresh = copy.copy(error)
    except Exception:  # noqa: BLE001 (an exception type copy cannot rebuild)
        return error
    fresh.__cause__, fresh.__suppress_context__ = error.__cause__, True
    return fresh


#: Longest a reader's wait is extended while the camera is producing a frame
#: (:meth:`FrameRing.producing`), s: a render slower than this is a hang.
PRODUCING_HANG_S = 120.0


class FrameRing:
    """Bounded, thread-safe frame buffer with loss counters (never drops silently).

    A reader's wait (:meth:`get`, :meth:`get_latest`) runs out at its ``timeout_s``,
    unless the producer has said a frame is on its way (:meth:`producing`: a simulated
    camera rendering it on the CPU, which on a busy machine took more than a 30 fps
    recording's 5.3 s wait); the wait then goes on until that frame is in, for at most
    :data:`PRODUCING_HANG_S` more.

    Parameters
    ----------
    capacity : int
        Number of frames held; when full, a new frame overwrites the oldest one.

    Attributes
    ----------
    acquired : int
        Frames the camera produced into this ring (including dropped ones).
    read : int
        Frames returned by :meth:`get` / :meth:`get_latest`.
    skipped : int
        Frames never read: overwritten when full, discarded by ``get_latest`` or
        ``clear``, or dropped before delivery. ``acquired == read + skipped + len(ring)``.
    dropped : int
        The part of ``skipped`` lost before reaching the ring (transport, camera).
    """

    def __init__(self, capacity: int) -> None:
        ok = isinstance(capacity, int | np.integer) and not isinstance(capacity, bool)
        if not ok or capacity < 1:
            raise DeviceValueError(
                "frame_ring", f"capacity={capacity!r} is invalid", "use an integer >= 1"
            )
        self._capacity = int(capacity)
        self._buf: collections.deque[Frame] = collections.deque()
        self._cond = threading.Condition()
        self.device_id = "frame_ring"
        self.acquired = 0
        self.read = 0
        self.skipped = 0
        self.dropped = 0
        self._pump: Callable[[float], float] | None = None
        self._error: BaseException | None = None
        self._producing = 0

    @property
    def capacity(self) -> int:
        """Number of frames the ring holds."""
        return self._capacity

    def __len__(self) -> int:
        with self._cond:
            return len(self._buf)

    def counters(self) -> dict[str, int]:
        """Return ``acquired``, ``read``, ``skipped``, ``dropped``, ``buffered``, ``capacity``."""
        with self._cond:
            return {
                "acquired": self.acquired, "read": self.read, "skipped": self.skipped,
                "dropped": self.dropped, "buffered": len(self._buf), "capacity": self._capacity,
            }

    def put(self, frame: Frame) -> None:
        """Add a frame (producer side); overwrites and counts the oldest when full."""
        with self._cond:
            self.acquired += 1
            if len(self._buf) >= self._capacity:
                self._buf.popleft()
                self.skipped += 1
            self._buf.append(frame)
            self._cond.notify_all()

    @contextlib.contextmanager
    def producing(self) -> Iterator[None]:
        """Producer side: a frame is being made (rendered) in this block; a reader whose
        ``timeout_s`` runs out meanwhile waits for the block to end (at most
        :data:`PRODUCING_HANG_S` more), then takes the frame or times out as before.
        A camera whose frame takes CPU time the machine may not give it at once (the
        simulated camera) wraps each frame's making in it; a hardware camera does not."""
        with self._cond:
            self._producing += 1
        try:
            yield
        finally:
            with self._cond:
                self._producing -= 1
                self._cond.notify_all()

    def mark_dropped(self, n: int = 1) -> None:
        """Count ``n`` frames the camera produced but lost before delivery."""
        with self._cond:
            self.acquired += n
            self.skipped += n
            self.dropped += n

    def fail(self, error: BaseException) -> None:
        """Report a producer error (e.g. a lost camera): once the buffered frames are
        read, :meth:`get` raises ``error`` instead of waiting. :meth:`clear` resets it.
        ``error`` is kept without its traceback (:func:`diffuserlab.errors.kept_error`):
        the producer's frames would hold the ring, a cycle; log it before if wanted."""
        with self._cond:
            self._error = kept_error(error)
            self._cond.notify_all()

    def clear(self) -> None:
        """Discard buffered frames (counted as skipped)."""
        with self._cond:
            self.skipped += len(self._buf)
            self._buf.clear()
            self._error = None

    def get(self, timeout_s: float = 1.0) -> Frame:
        """Return the oldest buffered frame, waiting up to ``timeout_s`` seconds.

        Raises
        ------
        CameraTimeoutError
            No frame arrived in time.
        DeviceError
            The error a producer reported with :meth:`fail` (e.g. disconnected).
        """
        return self._take(timeout_s, latest=False)

    def get_latest(self, timeout_s: float = 1.0) -> Frame:
        """Return the newest frame; older buffered frames are counted as skipped.

        Raises
        ------
        CameraTimeoutError
            No frame arrived in time.
        """
        return self._take(timeout_s, latest=True)

    def _take(self, timeout_s: float, latest: bool) -> Frame:
        budget = float(timeout_s)
        if not budget >= 0:
            raise DeviceValueError(self.device_id, f"timeout_s={timeout_s!r}", "use >= 0")
        deadline = time.monotonic() + budget
        extended = False
        with self._cond:
            while not self._buf:
                if self._error is not None:
                    raise _to_raise(self._error)
                if budget <= 0 and self._producing and not extended:
                    # a frame is on its way: wait for it, not the clock (a hang guard)
                    extended = True
                    self._cond.wait_for(lambda: self._buf or self._error is not None
                                        or not self._producing, PRODUCING_HANG_S)
                    continue
                if budget <= 0:
                    raise CameraTimeoutError(
                        self.device_id,
                        f"no frame within {timeout_s:g} s (acquired={self.acquired}, "
                        f"read={self.read}, skipped={self.skipped})",
                        "check that the stream is running, the trigger mode and source, "
                        "and that timeout_s exceeds the frame period",
                    )
                if self._pump is not None:  # a simulated camera advances its clock
                    budget -= max(self._pump(budget), 1e-12)
                else:
                    self._cond.wait(budget)
                    budget = deadline - time.monotonic()
            if latest:
                self.skipped += len(self._buf) - 1
                frame = self._buf.pop()
                self._buf.clear()
            else:
                frame = self._buf.popleft()
            self.read += 1
            return frame

    def _attach(self, device_id: str, pump: Callable[[float], float] | None) -> None:
        with self._cond:
            self.device_id = device_id
            self._pump = pump


_LOCKED = frozenset({"stream_locked"})  # a setting the camera refuses while streaming


def _check_roi(device: Device, label: str, value: Any, low: Any, high: Any
               ) -> tuple[int, int, int, int]:
    """The ``roi`` setting as ``(x, y, width, height)`` within the sensor (None: all)."""
    rows, cols = device._info["sensor_shape"]
    if value is None:
        return (0, 0, int(cols), int(rows))
    if isinstance(value, str | bytes) or not isinstance(value, Sequence | np.ndarray) or (
        len(value) != 4
    ):
        raise device._error(
            DeviceValueError, f"roi={value!r} is not (x, y, width, height)",
            "pass four integers in sensor pixels, or None for the full sensor",
        )
    x = device._int("roi x", value[0], low=0, high=cols - 1)
    y = device._int("roi y", value[1], low=0, high=rows - 1)
    w = device._int("roi width", value[2], low=1, high=cols - x)
    h = device._int("roi height", value[3], low=1, high=rows - y)
    return (x, y, w, h)


class Camera(Device):
    """Abstract camera: validated settings, snap, streaming into a :class:`FrameRing`.

    Settable properties (applied in this order): ``pixel_format``, ``roi``,
    ``binning``, ``exposure_s``, ``frame_rate_hz``, ``gain`` (dB), ``trigger_mode``.
    While streaming, only ``exposure_s``, ``frame_rate_hz`` and ``gain`` may change.

    Frame rate: ``frame_rate_hz`` is the requested free-run rate, within the
    driver's ``frame_rate_range_hz``. An exposure longer than the frame period
    limits it: the camera runs at :attr:`resulting_frame_rate_hz`, by default
    ``min(frame_rate_hz, 1 / exposure_s)``; a driver whose sensor needs readout
    time between exposures overrides ``_do_resulting_frame_rate_hz()``. Setting an
    exposure longer than the period is allowed (the rate drops, the setting stays).

    Driver hooks, besides :class:`~drivers.base.Device`'s: ``_do_snap(timeout_s) ->
    Frame``, ``_do_start_stream(ring)``, ``_do_stop_stream()``, ``_do_trigger()``;
    optional ``_do_resulting_frame_rate_hz()``. ``_do_get_info()`` returns
    ``sensor_shape``, ``pixel_pitch_um``, ``exposure_range_s``,
    ``frame_rate_range_hz``, ``gain_range_db``, ``pixel_formats``, ``max_binning``.
    """

    kind: ClassVar[str] = "camera"
    timeout_error = CameraTimeoutError
    SETTINGS = (
        Setting("pixel_format", "str", description="pixel format of the images (see the "
                "camera module's conventions)", tags=_LOCKED,
                choices=info("pixel_formats", transform=lambda formats: [
                    p for p in formats if p in _ALL_FORMATS])),
        Setting("roi", "int[4]", "px", "region of interest (x, y, width, height) in unbinned "
                "sensor pixels; null sets the full sensor", tags=_LOCKED, check=_check_roi,
                bounds="within {sensor_shape[1]} x {sensor_shape[0]} px"),
        Setting("binning", "int", "", "binning factor, the same along rows and columns",
                low=1, high=info("max_binning"), tags=_LOCKED),
        Setting("exposure_s", "float", "s", "exposure time", positive=True,
                low=info("exposure_range_s[0]"), high=info("exposure_range_s[1]")),
        Setting("frame_rate_hz", "float", "Hz", "requested free-run frame rate (a long "
                "exposure lowers the rate the camera runs at)", positive=True,
                low=info("frame_rate_range_hz[0]"), high=info("frame_rate_range_hz[1]")),
        Setting("gain", "float", "dB", "analog gain (0 dB: the sensor's native conversion "
                "gain)", low=0.0, high=info("gain_range_db[1]")),
        Setting("trigger_mode", "str", description="free_run, software (trigger()) or "
                "hardware (an external pulse)", choices=TRIGGER_MODES, tags=_LOCKED),
    )

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        self._ring: FrameRing | None = None
        self._streaming = False
        self._dropped_frames = 0

    # ----------------------------------------------------------- fixed properties
    @property
    def sensor_shape(self) -> tuple[int, int]:
        """Full sensor size ``(rows, cols)`` in pixels (read-only)."""
        self._require_open()
        return tuple(self._info["sensor_shape"])

    @property
    def pixel_pitch_um(self) -> float:
        """Sensor pixel pitch in micrometres (read-only)."""
        self._require_open()
        return float(self._info["pixel_pitch_um"])

    # ----------------------------------------------------------- settings
    exposure_s = setting_property(
        "exposure_s",
        "Exposure time in seconds (> 0, within the driver's range).",
    )

    frame_rate_hz = setting_property(
        "frame_rate_hz",
        "Requested free-run frame rate in Hz (> 0, within the driver's "
        "``frame_rate_range_hz``); read back from the driver. The camera runs at "
        ":attr:`resulting_frame_rate_hz`, which a long exposure lowers.",
    )

    @property
    def resulting_frame_rate_hz(self) -> float:
        """Frame rate the camera actually runs at in free run, Hz (read-only): by
        default ``min(frame_rate_hz, 1 / exposure_s)``, lower if the driver's sensor
        needs readout time (see the class notes)."""
        self._require_open()
        with self._io():
            return float(self._do_resulting_frame_rate_hz())

    gain = setting_property("gain", "Analog gain in dB (>= 0).")

    pixel_format = setting_property(
        "pixel_format",
        '"mono8", "mono12", "mono16", or one of the driver\'s extra formats (see the '
        "module notes).",
    )

    @property
    def bit_depth(self) -> int:
        """Bits per pixel (per channel) of the current pixel format (8, 10, 12 or 16)."""
        return format_bits(self.pixel_format)

    @property
    def dtype(self) -> np.dtype:
        """Image dtype: uint8 for 8-bit formats, uint16 otherwise."""
        return np.dtype(np.uint8 if self.bit_depth == 8 else np.uint16)

    roi = setting_property(
        "roi",
        "``(x, y, width, height)`` in unbinned sensor pixels; None sets the full sensor.",
    )

    binning = setting_property("binning", "Binning factor (>= 1), the same along rows and columns.")

    trigger_mode = setting_property(
        "trigger_mode",
        '"free_run", "software" or "hardware".',
    )

    @property
    def image_shape(self) -> tuple[int, ...]:
        """Shape ``(rows, cols)`` (``(rows, cols, 3)`` for rgb) of the images delivered with
        the current ROI, binning and pixel format."""
        _, _, w, h = self.roi
        b = self.binning
        return (h // b, w // b, 3) if self.pixel_format.startswith("rgb") else (h // b, w // b)

    def _validate_setting(self, name: str, value: Any, pending: dict[str, Any]) -> Any:
        v = super()._validate_setting(name, value, pending)
        if self._streaming and "stream_locked" in self._SPECS[name].tags and (
                v != self._values[name]):
            raise self._error(
                DeviceStateError, f"cannot change {name} while streaming",
                "call stop_stream() first",
            )
        return v

    def _check_settings(self, pending: dict[str, Any]) -> None:
        x, y, w, h = pending["roi"]
        if str(pending["pixel_format"]).startswith("bayer") and (
                pending["binning"] != 1 or x % 2 or y % 2):
            raise self._error(
                DeviceValueError, f"{pending['pixel_format']} (a raw colour mosaic) with "
                f"binning {pending['binning']} and roi offset ({x}, {y})",
                "use binning 1 and an even roi x and y (or rgb8/rgb16, demosaiced)",
            )
        if min(w, h) < pending["binning"]:
            raise self._error(
                DeviceValueError,
                f"binning={pending['binning']} exceeds the roi size {w}x{h}",
                "use a larger roi or a smaller binning",
            )

    # ----------------------------------------------------------- acquisition
    @property
    def is_streaming(self) -> bool:
        """True between :meth:`start_stream` and :meth:`stop_stream`."""
        return self._streaming

    @property
    def dropped_frames(self) -> int:
        """Frames the camera produced but lost (snap and stream), since the object was made."""
        return self._dropped_frames

    def snap(self, timeout_s: float | None = None) -> Frame:
        """Acquire one frame with the current settings.

        In "software" mode the camera triggers itself; in "hardware" mode it waits
        for the external trigger.

        Parameters
        ----------
        timeout_s : float, optional
            Longest wait in seconds; default ``max(5, 2 * exposure_s + 1)``.

        Raises
        ------
        CameraTimeoutError
            No frame within ``timeout_s``.
        DeviceStateError
            The camera is streaming.
        """
        self._require_open()
        if timeout_s is None:
            timeout_s = max(5.0, 2.0 * self.exposure_s + 1.0)
        timeout_s = self._check_timeout(timeout_s)
        if self._streaming:
            raise self._error(
                DeviceStateError, "snap() while streaming", "call stop_stream() first"
            )
        with self._io():
            frame = self._do_snap(timeout_s)
        if frame.image.shape != self.image_shape or frame.image.dtype != self.dtype:
            raise self._error(
                DeviceError,
                f"driver returned {frame.image.shape} {frame.image.dtype}, expected "
                f"{self.image_shape} {self.dtype}",
                "report this driver bug; re-open the camera",
            )
        self._log.debug("%s: snap index=%d", self.device_id, frame.index)
        return frame

    def start_stream(self, ring: FrameRing) -> None:
        """Start continuous acquisition into ``ring`` (per the trigger mode).

        Raises
        ------
        DeviceStateError
            Already streaming.
        """
        self._require_open()
        if not isinstance(ring, FrameRing):
            raise self._error(
                DeviceValueError, f"ring must be a FrameRing, got {type(ring).__name__}",
                "pass FrameRing(capacity)",
            )
        if self._streaming:
            raise self._error(
                DeviceStateError, "already streaming", "call stop_stream() before a new stream"
            )
        ring._attach(self.device_id, None)
        with self._io():
            self._do_start_stream(ring)
        self._ring, self._streaming = ring, True
        self._log.info("%s: stream started (ring capacity %d)", self.device_id, ring.capacity)

    def stop_stream(self) -> None:
        """Stop acquisition; idempotent. The ring keeps its frames and counters."""
        if not self._streaming:
            return
        try:
            with self._io():
                self._do_stop_stream()
        finally:
            self._streaming = False
            ring = self._ring
            self._log.info(
                "%s: stream stopped (%s)", self.device_id, ring.counters() if ring else {}
            )

    def trigger(self) -> None:
        """Send a software trigger (trigger_mode "software", while streaming).

        Raises
        ------
        DeviceStateError
            Not streaming, or another trigger mode.
        """
        self._require_open()
        if not self._streaming or self.trigger_mode != "software":
            raise self._error(
                DeviceStateError,
                f"trigger() needs a stream in software mode (streaming={self._streaming}, "
                f"trigger_mode={self.trigger_mode!r})",
                "set trigger_mode='software' and start_stream(ring) first",
            )
        with self._io():
            self._do_trigger()

    def _count_dropped(self, n: int = 1) -> None:
        """Drivers call this for every frame lost; it is logged, never silent."""
        self._dropped_frames += n
        self._log.warning("%s: %d frame(s) dropped (total %d)", self.device_id, n,
                          self._dropped_frames)

    def _before_close(self) -> None:
        self.stop_stream()

    def _do_status(self) -> dict[str, Any]:
        return {
            "streaming": self._streaming,
            "dropped_frames": self._dropped_frames,
            "ring": self._ring.counters() if self._ring is not None else None,
        }

    # ----------------------------------------------------------- hooks
    def _do_resulting_frame_rate_hz(self) -> float:
        """Free-run rate with the current settings; override when readout adds time."""
        return min(self._values["frame_rate_hz"], 1.0 / self._values["exposure_s"])

    @abc.abstractmethod
    def _do_snap(self, timeout_s: float) -> Frame: ...

    @abc.abstractmethod
    def _do_start_stream(self, ring: FrameRing) -> None: ...

    @abc.abstractmethod
    def _do_stop_stream(self) -> None: ...

    @abc.abstractmethod
    def _do_trigger(self) -> None: ...
