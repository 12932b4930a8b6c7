"""USB (UVC) and other Video4Linux2 cameras through OpenCV: :class:`V4l2Camera`.

Protocol facts, settings and pitfalls: docs/drivers/v4l2.md.

- The camera is chosen by a stable path (``/dev/v4l/by-id/usb-...-video-index0`` or
  ``/dev/v4l/by-path/...``) or by its USB serial number (looked up in
  ``/dev/v4l/by-id``), never by ``/dev/videoN``, whose number changes with the order
  devices appear in. The path is resolved again on every open, so a camera plugged
  back into another port is found by :meth:`Device.reconnect`.
- Controls through ``cv2.VideoCapture(path, cv2.CAP_V4L2)``: exposure is manual
  (``CAP_PROP_AUTO_EXPOSURE`` = 1; 3 is aperture priority, i.e. auto) in units of
  100 us; gain in the driver's raw units, mapped to dB by ``gain_db_per_unit``;
  FOURCC and frame size set at open; frame rate with ``CAP_PROP_FPS``. A V4L2 driver may
  clamp a value without an error, so every setting is read back and the value the
  camera took is what :meth:`settings` reports (a difference is logged).
- The ROI is cropped and binned on the host (:mod:`drivers.camera_image`); mono8 comes
  from 8-bit formats (GREY, YUYV, MJPG) as luma, mono12/mono16 from ``Y16 ``.
- Stale frames: a camera keeps up to ``buffers`` frames queued, exposed with the old
  settings. After a setting change (and for every snap) frames are discarded until one
  whose buffer timestamp (``CAP_PROP_POS_MSEC``, CLOCK_MONOTONIC) shows it was exposed
  after the change; while streaming the discarded frames are counted as dropped.
- Trigger modes: "free_run"; "software" delivers the first frame exposed after each
  :meth:`Camera.trigger` (UVC cameras have no trigger input, so "hardware" is refused).

Every read has a timeout: OpenCV's V4L2 select timeout is set to ``read_timeout_s``
(``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT``) unless the environment sets it.
"""

from __future__ import annotations

import math
import os
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera import Camera, Frame, FrameRing
from drivers.camera_image import frame_image
from drivers.errors import (
    DeviceDisconnectedError,
    DeviceError,
    DeviceStateError,
    DeviceValueError,
    MissingDependencyError,
)
from drivers.grab_thread import GrabStream
from drivers.settings import with_settings

__all__ = ["BY_ID_DIR", "V4l2Camera"]

#: Where udev links V4L2 devices by vendor, model and serial number.
BY_ID_DIR = "/dev/v4l/by-id"
_VIDEO_N = re.compile(r"^/dev/video\d+$")
# cv2.CAP_PROP_* numbers (stable across OpenCV 4.x and 5.x)
POS_MSEC, FOURCC, FRAME_WIDTH, FRAME_HEIGHT, FPS = 0, 6, 3, 4, 5
GAIN, EXPOSURE, CONVERT_RGB, AUTO_EXPOSURE, BUFFERSIZE = 14, 15, 16, 21, 38
#: V4L2_CID_EXPOSURE_AUTO menu values: manual, aperture priority (auto).
EXPOSURE_MANUAL, EXPOSURE_AUTO = 1, 3
#: CAP_PROP_EXPOSURE unit (V4L2_CID_EXPOSURE_ABSOLUTE counts 100 us).
EXPOSURE_UNIT_S = 100e-6
_FOURCC_16 = "Y16 "


def fourcc_code(text: str) -> int:
    """The 32-bit FOURCC code of a 4-character format name (``"YUYV"``)."""
    return sum(ord(c) << (8 * i) for i, c in enumerate(text))


def fourcc_text(code: float) -> str:
    """The 4-character name of a FOURCC code as ``CAP_PROP_FOURCC`` returns it."""
    return int(code).to_bytes(4, "little").decode("ascii", errors="replace")


def _open_cv2_v4l2(path: str) -> Any:
    import cv2

    return cv2.VideoCapture(path, cv2.CAP_V4L2)


class V4l2Camera(GrabStream, Camera):
    """A V4L2 camera driven through OpenCV's V4L2 backend.

    Parameters
    ----------
    device_id : str
        Name of the device.
    device_path : str, optional
        Stable device path: ``/dev/v4l/by-id/...`` or ``/dev/v4l/by-path/...``.
    serial_number : str, optional
        USB serial number, found in the names of ``by_id_dir`` (used when
        ``device_path`` is not given).
    size_px : (int, int), optional
        Frame ``(rows, cols)`` to request at open (read back: the camera's nearest size
        is the sensor shape); default the camera's current size.
    fourcc : str, optional
        8-bit capture format for mono8 (``"GREY"``, ``"YUYV"``, ``"MJPG"``); default the
        camera's current one.
    buffers : int
        Frames the camera may queue (``CAP_PROP_BUFFERSIZE``, 1..10).
    pixel_pitch_um : float
        Sensor pixel pitch in micrometres (required: V4L2 does not report it).
    exposure_range_s : (float, float)
        Exposures the camera takes, from its ``exposure_absolute`` range
        (``v4l2-ctl -L``) times 100 us.
    frame_rate_range_hz : (float, float)
        Frame rates the camera offers (``v4l2-ctl --list-formats-ext``).
    gain_db_per_unit : float, optional
        dB per unit of the camera's gain control; without it gain stays at 0 dB.
    gain_max_units : int
        Largest gain value of the camera (``v4l2-ctl -L``).
    read_timeout_s : float
        Longest wait of a single frame read (OpenCV's V4L2 select timeout).
    by_id_dir : str
        Directory of the udev by-id links (tests point it elsewhere).
    backend : callable, optional
        ``backend(path) -> capture`` with the ``cv2.VideoCapture`` methods; default
        ``cv2.VideoCapture(path, cv2.CAP_V4L2)``. Tests pass a fake.

    Raises
    ------
    DeviceValueError
        A parameter is invalid, e.g. a ``/dev/videoN`` path.
    """

    #: A UVC camera has no trigger input: the kind's trigger modes without "hardware".
    SETTINGS = with_settings(Camera.SETTINGS, Camera.setting("trigger_mode").replace(
        choices=("free_run", "software"), description="free_run or software (trigger())"))

    def __init__(
        self, device_id: str, *, device_path: str | None = None,
        serial_number: str | None = None, size_px: Any = None, fourcc: str | None = None,
        buffers: int = 2, pixel_pitch_um: float,
        exposure_range_s: Any = (1e-4, 1.0), frame_rate_range_hz: Any = (1.0, 120.0),
        gain_db_per_unit: float | None = None, gain_max_units: int = 255,
        read_timeout_s: float = 2.0, by_id_dir: str = BY_ID_DIR,
        backend: Callable[[str], Any] | None = None,
    ) -> None:
        super().__init__(device_id)
        if device_path is None and serial_number is None:
            raise self._error(DeviceValueError, "neither device_path nor serial_number is given",
                              f"set params.device_path to a link in {BY_ID_DIR} "
                              "(ls -l /dev/v4l/by-id) or params.serial_number")
        if device_path is not None and (not isinstance(device_path, str)
                                        or _VIDEO_N.match(device_path)):
            raise self._error(
                DeviceValueError, f"device_path={device_path!r} is not a stable path: "
                "/dev/videoN numbers change with the order devices appear in",
                f"use the camera's link in {BY_ID_DIR} (ls -l {BY_ID_DIR}) or serial_number",
            )
        if serial_number is not None and (not isinstance(serial_number, str)
                                          or not serial_number.strip()):
            raise self._error(DeviceValueError, f"serial_number={serial_number!r} is empty",
                              "give the USB serial number as a string")
        if fourcc is not None and (not isinstance(fourcc, str) or len(fourcc) != 4):
            raise self._error(DeviceValueError, f"fourcc={fourcc!r} is not 4 characters",
                              "use e.g. 'GREY', 'YUYV' or 'MJPG'")
        self._path, self._serial = device_path, serial_number
        self._size = None if size_px is None else self._int_pair("size_px", size_px,
                                                                 high=16384)
        self._fourcc8 = fourcc
        self._buffers = self._int("buffers", buffers, low=1, high=10)
        self._pitch = self._float("pixel_pitch_um", pixel_pitch_um, low=0.0, low_open=True)
        self._exp_range = self._range("exposure_range_s", exposure_range_s)
        self._rate_range = self._range("frame_rate_range_hz", frame_rate_range_hz)
        self._db_per_unit = None if gain_db_per_unit is None else self._float(
            "gain_db_per_unit", gain_db_per_unit, low=0.0, low_open=True)
        self._gain_max = self._int("gain_max_units", gain_max_units, low=0)
        self._read_timeout = self._float("read_timeout_s", read_timeout_s, low=0.0,
                                         low_open=True)
        self._by_id = by_id_dir
        self._backend = backend or _open_cv2_v4l2
        self._cap: Any = None
        self._hw: dict[str, Any] = {}
        self._fresh_after = 0.0
        self._fresh_margin = 0.0
        self._index = 0
        self._trigger_times: list[float] = []
        self._lock = threading.RLock()  # the capture object and the trigger times
        self._state = threading.Lock()  # settings vs. the labels of frames

    def _range(self, name: str, value: Any) -> tuple[float, float]:
        if isinstance(value, str) or not hasattr(value, "__len__") or len(value) != 2:
            raise self._error(DeviceValueError, f"{name}={value!r} is not (min, max)",
                              f"give two numbers, e.g. {name} = [0.0001, 1.0]")
        lo = self._float(f"{name} min", value[0], low=0.0, low_open=True)
        hi = self._float(f"{name} max", value[1], low=lo)
        return lo, hi

    # ------------------------------------------------------------------ open / close
    def resolve_path(self) -> str:
        """The device path: ``device_path`` or the by-id link naming the serial number.

        Raises
        ------
        DeviceDisconnectedError
            No such device (unplugged, or not yet enumerated).
        """
        if self._path is not None:
            if not os.path.exists(self._path):
                raise self._error(DeviceDisconnectedError, f"{self._path} does not exist",
                                  "plug the camera in; ls -l /dev/v4l/by-id lists cameras")
            return self._path
        links = sorted(Path(self._by_id).glob("*")) if os.path.isdir(self._by_id) else []
        named = [p for p in links if self._serial in p.name]
        video = [p for p in named if p.name.endswith("-video-index0")] or named
        if not video:
            raise self._error(
                DeviceDisconnectedError, f"no camera with serial {self._serial!r} in "
                f"{self._by_id} (found: {[p.name for p in links]})",
                "plug the camera in and check its serial (udevadm info /dev/videoN)",
            )
        return str(video[0])

    def _do_open(self, timeout_s: float) -> None:
        try:
            self._connect(timeout_s)
        except BaseException:
            self._do_close()  # release the capture if the open failed half-way
            raise

    def _connect(self, timeout_s: float) -> None:
        os.environ.setdefault("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT",
                              str(max(1, math.ceil(self._read_timeout))))
        path = self.resolve_path()
        try:
            cap = self._backend(path)
        except ImportError as exc:
            raise MissingDependencyError(
                self.device_id, f"OpenCV is not importable ({exc})",
                "pip install opencv-contrib-python-headless (a dependency of diffuserlab)",
            ) from exc
        if cap is None or not cap.isOpened():
            raise self._error(DeviceDisconnectedError, f"OpenCV cannot open {path} as a "
                              "V4L2 camera", "check permissions (group video) and that no "
                              "other program uses the camera")
        self._cap, self._index = cap, 0
        self._resolved = path
        self._set_checked(BUFFERSIZE, self._buffers, "buffers")
        current = fourcc_text(cap.get(FOURCC))
        self._fourcc8 = self._fourcc8 or (current if current != _FOURCC_16 else "YUYV")
        formats = {"mono8": self._fourcc8}
        if self._set_fourcc(_FOURCC_16, strict=False):
            formats.update(mono12=_FOURCC_16, mono16=_FOURCC_16)
        self._formats = formats
        self._set_fourcc(self._fourcc8)
        if self._size is not None:
            rows, cols = self._size
            cap.set(FRAME_WIDTH, cols)
            cap.set(FRAME_HEIGHT, rows)
        shape = (int(cap.get(FRAME_HEIGHT)), int(cap.get(FRAME_WIDTH)))
        if self._size is not None and shape != self._size:
            self._log.warning("%s: asked for %s, the camera took %s", self.device_id,
                              self._size, shape)
        if min(shape) <= 0:
            raise self._error(DeviceError, f"the camera reports a frame size {shape}",
                              "set params.size_px to one of its sizes (v4l2-ctl "
                              "--list-formats-ext)")
        self._shape = shape
        self._set_checked(AUTO_EXPOSURE, EXPOSURE_MANUAL, "manual exposure (auto-exposure 1)")
        exposure = self._read_exposure()
        self._info = self._do_get_info()  # what _validate_setting reads
        self._hw = {
            "pixel_format": "mono8", "roi": (0, 0, shape[1], shape[0]), "binning": 1,
            "exposure_s": min(max(exposure, self._exp_range[0]), self._exp_range[1]),
            "frame_rate_hz": self._read_rate(), "gain": self._read_gain(),
            "trigger_mode": "free_run",
        }
        self._changed(self._hw["exposure_s"])

    def _do_close(self) -> None:
        self._stop_grab()
        # under the lock every read takes: a grab thread still in a read after its join
        # timed out (a stuck camera) finishes it first (OpenCV's release during a read
        # may deadlock), and finds the capture gone after
        with self._lock:
            cap, self._cap = self._cap, None
            if cap is not None:
                try:
                    cap.release()
                except Exception as exc:  # noqa: BLE001 -- a vanished camera must close
                    self._log.warning("%s: release failed: %s", self.device_id, exc)

    def _do_check_connection(self) -> None:
        if not os.path.exists(self._resolved):
            raise self._error(DeviceDisconnectedError, f"{self._resolved} disappeared "
                              "(camera unplugged)", "plug it in and call reconnect()")

    # ------------------------------------------------------------------ controls
    def _set_checked(self, prop: int, value: float, what: str) -> float:
        """Set a property and return what the camera reports afterwards (read back)."""
        with self._lock:
            ok = self._cap.set(prop, value)
            got = self._cap.get(prop)
        if not ok:
            raise self._error(DeviceError, f"the camera refused {what} (set returned False, "
                              f"reads {got})", "check v4l2-ctl -L for the controls it has")
        return float(got)

    def _set_fourcc(self, text: str, strict: bool = True) -> bool:
        with self._lock:
            self._cap.set(FOURCC, fourcc_code(text))
            self._cap.set(CONVERT_RGB, 0 if text == _FOURCC_16 else 1)
            got = fourcc_text(self._cap.get(FOURCC))
        if got != text and strict:
            raise self._error(DeviceError, f"the camera took FOURCC {got!r}, not {text!r}",
                              "set params.fourcc to a format of the camera "
                              "(v4l2-ctl --list-formats-ext)")
        return got == text

    def _read_exposure(self) -> float:
        return float(self._cap.get(EXPOSURE)) * EXPOSURE_UNIT_S

    def _read_rate(self) -> float:
        rate = float(self._cap.get(FPS))
        lo, hi = self._rate_range
        return min(max(rate, lo), hi) if rate > 0 else lo

    def _read_gain(self) -> float:
        if self._db_per_unit is None:
            return 0.0
        return max(float(self._cap.get(GAIN)), 0.0) * self._db_per_unit

    def _do_get_info(self) -> dict[str, Any]:
        gain_max = 0.0 if self._db_per_unit is None else self._gain_max * self._db_per_unit
        return {"sensor_shape": self._shape, "pixel_pitch_um": self._pitch,
                "exposure_range_s": self._exp_range, "frame_rate_range_hz": self._rate_range,
                "gain_range_db": (0.0, gain_max), "pixel_formats": list(self._formats),
                "max_binning": 16, "device_path": self._resolved,
                "fourcc": dict(self._formats)}

    def _do_get_settings(self) -> dict[str, Any]:
        return dict(self._hw)

    def _validate_setting(self, name: str, value: Any, pending: dict[str, Any]) -> Any:
        if name == "gain" and value != 0 and self._db_per_unit is None:
            raise self._error(DeviceValueError, "gain is not mapped to dB for this camera",
                              "set params.gain_db_per_unit (and gain_max_units)")
        if name == "trigger_mode" and value == "hardware":  # named before the choices
            raise self._error(DeviceValueError, "a V4L2 (UVC) camera has no trigger input",
                              "use trigger_mode 'free_run' or 'software'")
        return super()._validate_setting(name, value, pending)

    def _do_apply(self, name: str, value: Any) -> Any:
        with self._state:  # frames are checked for staleness and labelled under it
            old_exposure = self._hw["exposure_s"]
            got = self._apply_one(name, value)
            self._hw[name] = got
            if name in ("exposure_s", "gain", "pixel_format"):
                # a frame in flight may have begun with the longer of the two exposures
                self._changed(max(old_exposure, self._hw["exposure_s"]))
            return got

    def _apply_one(self, name: str, value: Any) -> Any:
        if name == "pixel_format":
            self._set_fourcc(self._formats[value])
            return value
        if name in ("roi", "binning", "trigger_mode"):
            return value  # on the host
        if name == "exposure_s":
            units = max(1, round(value / EXPOSURE_UNIT_S))
            self._set_checked(AUTO_EXPOSURE, EXPOSURE_MANUAL, "manual exposure")
            got = self._set_checked(EXPOSURE, units, f"exposure {units} x 100 us")
            return self._taken(name, value, got * EXPOSURE_UNIT_S)
        if name == "frame_rate_hz":
            got = self._set_checked(FPS, value, f"frame rate {value:g} Hz")
            return self._taken(name, value, got)
        if self._db_per_unit is None:  # gain, unmapped: validated to be 0
            return 0.0
        units = round(value / self._db_per_unit)
        got = self._set_checked(GAIN, units, f"gain {units}")
        return self._taken(name, value, got * self._db_per_unit)

    def _taken(self, name: str, asked: float, got: float) -> float:
        if not math.isclose(asked, got, rel_tol=0.02, abs_tol=1e-12):
            self._log.warning("%s: asked %s=%g, the camera took %g", self.device_id, name,
                              asked, got)
        return got

    def _changed(self, exposure_s: float) -> None:
        """Frames whose exposure began before now are stale; ``exposure_s`` bounds the
        exposure of the frames in flight."""
        self._fresh_after = time.monotonic()
        self._fresh_margin = exposure_s

    # ------------------------------------------------------------------ frames
    def _read(self, deadline: float) -> tuple[np.ndarray, float]:
        """The next frame from the camera and its buffer timestamp (s, CLOCK_MONOTONIC)."""
        while True:
            with self._lock:
                if self._cap is None:  # released by close while this thread waited
                    raise self._error(DeviceStateError, "the capture was released",
                                      "open the camera again")
                ok, image = self._cap.read()
                stamp = float(self._cap.get(POS_MSEC)) * 1e-3
            if ok and image is not None:
                return image, (stamp if stamp > 0 else time.monotonic())
            self._do_check_connection()  # an unplugged camera: DeviceDisconnectedError
            if time.monotonic() >= deadline:
                raise self._timeout(f"no frame from {self._resolved}",
                                    "check the camera and raise timeout_s")

    def _fresh_frame(self, deadline: float, since: float,
                     on_stale: Callable[[float], None] | None = None,
                     on_fresh: Callable[[float], None] | None = None) -> Frame:
        """The first frame whose exposure began after ``since`` and after the last
        setting change (its timestamp minus the longest exposure in flight), labelled
        with the settings it was exposed with: the check and the label happen under the
        lock that setting changes take."""
        while True:
            image, stamp = self._read(deadline)
            with self._state:
                margin = max(self._hw["exposure_s"], self._fresh_margin)
                if stamp - margin >= max(since, self._fresh_after):
                    if on_fresh is not None:
                        on_fresh(stamp)
                    return self._to_frame(image, stamp)
            if on_stale is not None:
                on_stale(stamp)
            if time.monotonic() >= deadline:
                raise self._timeout("only stale frames (exposed before the last setting "
                                    "change) arrived", "raise timeout_s")

    def _to_frame(self, image: np.ndarray, stamp: float) -> Frame:
        hw = self._hw
        if self._formats.get(hw["pixel_format"]) == _FOURCC_16:
            raw, bits = _as_gray16(image, self._shape), 16
        else:
            raw, bits = _as_gray8(image), 8
        x, y, w, h = hw["roi"]
        img, saturated = frame_image(raw, (x, y), (w, h), hw["binning"], bits,
                                     hw["pixel_format"])
        index = self._index
        self._index += 1
        return Frame(image=img, index=index, device_timestamp_s=stamp,
                     host_timestamp_s=time.time(), exposure_s=hw["exposure_s"],
                     gain=hw["gain"], saturated_pixels=saturated)

    def _do_snap(self, timeout_s: float) -> Frame:
        return self._fresh_frame(time.monotonic() + timeout_s, time.monotonic())

    def _do_start_stream(self, ring: FrameRing) -> None:
        self._trigger_times = []
        self._start_grab(ring, lambda stop: self._grab_loop(ring, stop), "v4l2",
                         self._read_timeout + 2.0)

    def _do_stop_stream(self) -> None:
        # a trigger sent before the stop gets its frame (the camera was exposing it):
        # wait for the pending ones, at most two frame periods plus the exposure
        hw = self._hw
        grace = time.monotonic() + min(1.0, 2.0 / hw["frame_rate_hz"] + hw["exposure_s"] + 0.2)
        while self._grab is not None and self._trigger_times and time.monotonic() < grace:
            time.sleep(0.002)
        self._stop_grab()

    def _do_trigger(self) -> None:
        with self._lock:
            self._trigger_times.append(time.monotonic())

    def _grab_loop(self, ring: FrameRing, stop: threading.Event) -> None:
        """Read frames; deliver the fresh ones (every one in free run, the first after
        each trigger in software mode); stale ones after a change count as dropped."""
        def dropped(n: int = 1) -> None:
            self._index += n
            self._count_dropped(n)
            ring.mark_dropped(n)

        last: float | None = None
        started = time.monotonic()  # frames exposed before are nobody's: discarded silently

        def stale(stamp: float) -> None:
            nonlocal last
            if stamp - max(self._hw["exposure_s"], self._fresh_margin) >= started:
                dropped()
                last = stamp

        def gap(stamp: float) -> None:  # free run: frames the camera lost in between
            nonlocal last
            if last is not None:
                missed = round((stamp - last) * self._do_resulting_frame_rate_hz()) - 1
                if missed > 0:
                    dropped(missed)
            last = stamp

        while not stop.is_set():
            software = self._hw["trigger_mode"] == "software"
            with self._lock:
                since = self._trigger_times[0] if software and self._trigger_times \
                    else None
            if software and since is None:
                stop.wait(0.002)
                continue
            try:
                frame = self._fresh_frame(
                    time.monotonic() + self._read_timeout, since or started,
                    None if software else stale, None if software else gap)
            except DeviceDisconnectedError:
                raise
            except DeviceError:  # a read timeout: keep waiting until stopped
                continue
            if stop.is_set():
                return
            if software:
                with self._lock:
                    self._trigger_times.pop(0)
            ring.put(frame)

    def _do_resulting_frame_rate_hz(self) -> float:
        return min(self._hw["frame_rate_hz"], 1.0 / self._hw["exposure_s"])


def _as_gray8(image: np.ndarray) -> np.ndarray:
    """Luma of an OpenCV frame: BGR -> gray (ITU-R BT.601 weights), gray unchanged."""
    if image.ndim == 2:
        return image
    import cv2

    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def _as_gray16(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A ``Y16`` frame as ``(rows, cols)`` uint16: OpenCV returns it either as a 16-bit
    image or, with CONVERT_RGB off, as the raw little-endian bytes."""
    if image.dtype == np.uint16:
        return image.reshape(shape)
    return np.frombuffer(np.ascontiguousarray(image).tobytes(), "<u2",
                         count=shape[0] * shape[1]).reshape(shape)
