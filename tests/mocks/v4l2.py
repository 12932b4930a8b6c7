"""A UVC camera on OpenCV's V4L2 backend, as the ``cv2.VideoCapture`` surface the
:class:`~drivers.v4l2_camera.V4l2Camera` driver uses (``isOpened``, ``read``, ``get``,
``set``, ``release``), written from the V4L2/UVC control semantics (docs/drivers/v4l2.md):

- frames come from a recorded image sequence or video read through OpenCV (a real
  ``cv2.VideoCapture`` on the file, looped), scaled by exposure and gain;
- the camera exposes frame k from ``t0 + k * period`` for one exposure, with the
  settings in effect when its exposure began; ``period = max(1 / fps, exposure)``;
- a queue of ``BUFFERSIZE`` buffers: ``read()`` returns the *oldest* queued frame (stale
  after a setting change); frames finished while every buffer is full are lost;
- ``CAP_PROP_POS_MSEC`` is the returned frame's timestamp (end of its exposure, ms of
  CLOCK_MONOTONIC); ``read()`` waits for the next frame up to ``read_timeout_s`` and
  returns ``(False, None)`` on a timeout or once unplugged;
- controls: auto-exposure menu {1 manual, 3 aperture priority} (other values refused;
  exposure refused while auto), exposure in 100 us units clamped to its range, gain in
  raw units (the fake's unit is 1 dB) clamped, FPS snapped to the offered rates,
  FOURCC among YUYV/GREY/"Y16 " (others refused), frame size snapped to the offered
  sizes (width and height as a pair); FOURCC, size and buffer count restart the stream;
- the property ids are OpenCV's (``cv2.CAP_PROP_*``), and :meth:`FakeV4l2Capture.control`
  reads exposure, auto-exposure and gain by the kernel's V4L2 control ids, through the
  property each maps to in OpenCV's V4L2 backend (:data:`V4L2_CONTROL`);
- ``release()`` while another thread is inside ``read()`` (undefined in OpenCV: a
  possible deadlock or a use after free) is recorded (``released_during_read``) and
  raises; ``gate`` (a ``threading.Event``, set) holds every ``read()`` while cleared,
  ``reading`` is set once one is held; :meth:`stall` (``math.inf``: until
  :meth:`resume`) stops the frames.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Any

import cv2
import numpy as np

__all__ = ["V4L2_CID_EXPOSURE_ABSOLUTE", "V4L2_CID_EXPOSURE_AUTO", "V4L2_CID_GAIN",
           "V4L2_CONTROL", "FakeV4l2Capture"]

# The property ids as OpenCV defines them, taken from cv2 itself and never from the
# driver under test: a driver that swapped two ids would set one control for another.
POS_MSEC, FOURCC, FPS = cv2.CAP_PROP_POS_MSEC, cv2.CAP_PROP_FOURCC, cv2.CAP_PROP_FPS
FRAME_WIDTH, FRAME_HEIGHT = cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT
GAIN, EXPOSURE, AUTO_EXPOSURE = cv2.CAP_PROP_GAIN, cv2.CAP_PROP_EXPOSURE, cv2.CAP_PROP_AUTO_EXPOSURE
CONVERT_RGB, BUFFERSIZE = cv2.CAP_PROP_CONVERT_RGB, cv2.CAP_PROP_BUFFERSIZE

# The kernel's V4L2 control ids (include/uapi/linux/v4l2-controls.h): V4L2_CID_BASE =
# V4L2_CTRL_CLASS_USER (0x00980000) | 0x900, V4L2_CID_GAIN = V4L2_CID_BASE + 19;
# V4L2_CID_CAMERA_CLASS_BASE = V4L2_CTRL_CLASS_CAMERA (0x009a0000) | 0x900,
# V4L2_CID_EXPOSURE_AUTO = that + 1, V4L2_CID_EXPOSURE_ABSOLUTE = that + 2.
V4L2_CID_GAIN = 0x00980913
V4L2_CID_EXPOSURE_AUTO = 0x009A0901
V4L2_CID_EXPOSURE_ABSOLUTE = 0x009A0902
#: The V4L2 control each OpenCV property sets on a camera (OpenCV's V4L2 backend,
#: ``capPropertyToV4L2`` in modules/videoio/src/cap_v4l.cpp).
V4L2_CONTROL: dict[int, int] = {AUTO_EXPOSURE: V4L2_CID_EXPOSURE_AUTO,
                                EXPOSURE: V4L2_CID_EXPOSURE_ABSOLUTE, GAIN: V4L2_CID_GAIN}


def fourcc_code(text: str) -> int:
    """OpenCV's FOURCC code of a 4-character format name."""
    return cv2.VideoWriter_fourcc(*text)


def fourcc_text(code: float) -> str:
    """The format name of a FOURCC code (its 4 bytes, least significant first)."""
    return int(code).to_bytes(4, "little").decode("ascii", errors="replace")


class FakeV4l2Capture:
    """See the module docstring. ``sizes`` are ``(width, height)``, the first the default."""

    FOURCCS = ("YUYV", "GREY", "Y16 ")

    def __init__(self, source: str, *, sizes=((160, 120), (80, 60)),
                 fps_choices=(5, 10, 15, 20, 25, 30, 50, 60, 100),
                 exposure_units=(1, 5000), gain_units=(0, 100), read_timeout_s: float = 2.0):
        self._source_path = source
        self._source = cv2.VideoCapture(source, cv2.CAP_ANY)
        if not self._source.isOpened():
            raise FileNotFoundError(f"OpenCV cannot read {source}")
        self.sizes, self.fps_choices = tuple(sizes), tuple(fps_choices)
        self.exposure_units, self.gain_units = exposure_units, gain_units
        self.read_timeout_s = read_timeout_s
        self.opened, self.unplugged = True, False
        self.props: dict[int, float] = {
            FOURCC: fourcc_code("YUYV"), FRAME_WIDTH: sizes[0][0], FRAME_HEIGHT: sizes[0][1],
            AUTO_EXPOSURE: 3, EXPOSURE: 100, GAIN: 0, FPS: 30, BUFFERSIZE: 4, CONVERT_RGB: 1,
            POS_MSEC: 0.0,
        }
        self.set_log: list[tuple[int, float]] = []
        self.lost = 0
        #: every frame exposed: (start, end, exposure in 100 us units), lost ones too
        self.produced: list[tuple[float, float, int]] = []
        self._lock = threading.RLock()  # the test thread may look while the driver reads
        self.gate, self.reading = threading.Event(), threading.Event()
        self.gate.set()
        self._readers = 0
        self.released_during_read = False
        self._stall_until = 0.0
        self._history: list[tuple[float, dict[int, float]]] = []
        self._queue: collections.deque[tuple[float, np.ndarray]] = collections.deque()
        self._restart(time.monotonic())

    # ------------------------------------------------------------------ timing
    def _period(self, props: dict[int, float]) -> float:
        return max(1.0 / props[FPS], props[EXPOSURE] * 1e-4)

    def _restart(self, now: float) -> None:
        self._queue.clear()
        self._history = [(now, dict(self.props))]
        self._next_start = now

    def _settings_at(self, t: float) -> dict[int, float]:
        current = self._history[0][1]
        for since, props in self._history:
            if since <= t:
                current = props
        return current

    def _produce(self, now: float) -> None:
        """Expose every frame whose exposure ended by ``now``."""
        if now < self._stall_until:
            return
        self._next_start = max(self._next_start, self._stall_until)
        while True:
            props = self._settings_at(self._next_start)
            end = self._next_start + props[EXPOSURE] * 1e-4
            if end > now:
                return
            self.produced.append((self._next_start, end, int(props[EXPOSURE])))
            if len(self._queue) < int(self.props[BUFFERSIZE]):
                self._queue.append((end, self._render(props)))
            else:
                self.lost += 1
            self._next_start += self._period(props)

    def _next_frame_source(self) -> np.ndarray:
        ok, frame = self._source.read()
        if not ok:  # loop the recording
            self._source.release()
            self._source = cv2.VideoCapture(self._source_path, cv2.CAP_ANY)
            ok, frame = self._source.read()
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame

    def _render(self, props: dict[int, float]) -> np.ndarray:
        gray = self._next_frame_source().astype(np.float64)
        size = (int(props[FRAME_WIDTH]), int(props[FRAME_HEIGHT]))
        if gray.shape[::-1] != size:
            gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        scale = props[EXPOSURE] / 100.0 * 10 ** (props[GAIN] / 20.0)
        if fourcc_text(props[FOURCC]) == "Y16 ":
            y16 = np.clip(np.rint(gray * scale * 256.0), 0, 65535).astype(np.uint16)
            return y16 if props[CONVERT_RGB] == 0 else cv2.cvtColor(
                (y16 >> 8).astype(np.uint8), cv2.COLOR_GRAY2BGR)
        y8 = np.clip(np.rint(gray * scale), 0, 255).astype(np.uint8)
        return cv2.cvtColor(y8, cv2.COLOR_GRAY2BGR)

    # ------------------------------------------------------------------ cv2 surface
    def isOpened(self) -> bool:  # noqa: N802 (cv2's name)
        return self.opened

    def read(self) -> tuple[bool, Any]:
        with self._lock:
            self._readers += 1
        try:
            if not self.gate.is_set():
                self.reading.set()
                self.gate.wait(60.0)  # a hang guard only
            return self._read()
        finally:
            with self._lock:
                self._readers -= 1

    def _read(self) -> tuple[bool, Any]:
        deadline = time.monotonic() + self.read_timeout_s
        while self.opened and not self.unplugged:
            now = time.monotonic()
            with self._lock:
                self._produce(now)
                if self._queue:
                    stamp, image = self._queue.popleft()
                    self.props[POS_MSEC] = stamp * 1e3
                    return True, image
            if now >= deadline:
                break
            time.sleep(min(0.002, deadline - now))
        return False, None

    def get(self, prop: int) -> float:
        if not self.opened:
            return 0.0
        return float(self.props.get(prop, -1.0))

    def set(self, prop: int, value: float) -> bool:
        with self._lock:
            return self._set(prop, value)

    def _set(self, prop: int, value: float) -> bool:
        if not self.opened or self.unplugged:
            return False
        now = time.monotonic()
        self._produce(now)  # frames exposed so far keep the old settings
        self.set_log.append((prop, value))
        p = self.props
        restart = False
        if prop == AUTO_EXPOSURE:
            if int(value) not in (1, 3):
                return False
            p[prop] = int(value)
        elif prop == EXPOSURE:
            if p[AUTO_EXPOSURE] != 1:
                return False  # the driver refuses a manual exposure in auto mode
            lo, hi = self.exposure_units
            p[prop] = int(min(max(round(value), lo), hi))
        elif prop == GAIN:
            lo, hi = self.gain_units
            p[prop] = int(min(max(round(value), lo), hi))
        elif prop == FPS:
            p[prop] = float(min(self.fps_choices, key=lambda f: abs(f - value)))
        elif prop == FOURCC:
            if fourcc_text(value) not in self.FOURCCS:
                return False
            p[prop], restart = float(value), True
        elif prop in (FRAME_WIDTH, FRAME_HEIGHT):
            want = (value, p[FRAME_HEIGHT]) if prop == FRAME_WIDTH else (p[FRAME_WIDTH], value)
            w, h = min(self.sizes, key=lambda s: abs(s[0] - want[0]) + abs(s[1] - want[1]))
            p[FRAME_WIDTH], p[FRAME_HEIGHT], restart = w, h, True
        elif prop == BUFFERSIZE:
            if not 1 <= int(value) <= 10:
                return False
            p[prop], restart = int(value), True
        elif prop == CONVERT_RGB:
            p[prop] = 1 if value else 0
        else:
            return False
        if restart:
            self._restart(now)
        else:
            self._history.append((now, dict(p)))
        return True

    def control(self, cid: int) -> int:
        """The value of the camera's V4L2 control ``cid`` (a kernel id such as
        :data:`V4L2_CID_GAIN`), set through the OpenCV property that maps to it."""
        prop = {c: p for p, c in V4L2_CONTROL.items()}[cid]
        return int(self.props[prop])

    def release(self) -> None:
        with self._lock:
            if self._readers:
                self.released_during_read = True
                raise RuntimeError("release() while another thread reads (OpenCV: "
                                   "undefined, a possible deadlock)")
            self.opened = False
        self._source.release()

    def stall(self, seconds: float) -> None:
        """The camera stops sending for ``seconds`` (e.g. a USB bandwidth stall;
        ``math.inf``: until :meth:`resume`)."""
        with self._lock:
            now = time.monotonic()
            self._produce(now)
            self._stall_until = now + seconds

    def resume(self) -> None:
        """End a stall now: frames are exposed again from now on."""
        with self._lock:
            self._stall_until = min(self._stall_until, time.monotonic())

    def unplug(self) -> None:
        """The camera disappears: reads fail from now on."""
        self.unplugged = True
