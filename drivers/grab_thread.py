"""The acquisition thread of a streaming camera driver: :class:`GrabThread`, and
:class:`GrabStream`, the start and stop of it that the drivers share."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from drivers.errors import DeviceDisconnectedError

__all__ = ["GrabStream", "GrabThread", "report_stream_error"]


def report_stream_error(device: Any, ring: Any, exc: BaseException) -> None:
    """End a stream on an error: a lost camera marks ``device`` disconnected; the error
    is logged and handed to the reader through ``ring.fail`` (never lost).

    Parameters
    ----------
    device : drivers.camera.Camera
        The streaming camera.
    ring : drivers.camera.FrameRing
        Its ring; the next ``get`` after the buffered frames raises ``exc``.
    exc : BaseException
        What ended the stream.
    """
    if isinstance(exc, DeviceDisconnectedError):
        device._disconnected = True
        device._log.error("%s: stream ended: %s", device.device_id, exc)
    else:
        device._log.error("%s: grab thread failed: %s", device.device_id, exc, exc_info=exc)
    ring.fail(exc)


class GrabThread:
    """A daemon thread running ``target(stop)`` until ``stop`` (a threading.Event) is set.

    Parameters
    ----------
    target : callable
        ``target(stop)``; it must return soon after ``stop.is_set()`` (every wait in it
        has a timeout).
    name : str
        Thread name (shown in logs and debuggers).
    join_timeout_s : float
        Longest wait for the thread to end in :meth:`stop`, in seconds.
    on_error : callable
        Called with any exception ``target`` raises (the thread then ends).
    """

    def __init__(self, target: Callable[[threading.Event], None], name: str,
                 join_timeout_s: float, on_error: Callable[[BaseException], None]) -> None:
        self._stop = threading.Event()
        self._target, self._on_error = target, on_error
        self._thread = threading.Thread(target=self._run, daemon=True, name=name)
        self._join_timeout_s = join_timeout_s

    def _run(self) -> None:
        try:
            self._target(self._stop)
        except Exception as exc:  # noqa: BLE001 -- handed to on_error, not lost
            self._on_error(exc)

    def start(self) -> GrabThread:
        """Start the thread; returns self."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Ask the thread to end and wait for it (not when called from the thread itself),
        at most ``join_timeout_s``; a thread still running then is logged at warning
        level."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=self._join_timeout_s)
            if self._thread.is_alive():  # a driver call stuck in the thread
                logging.getLogger("drivers").warning(
                    "%s: the grab thread did not end within %g s of its stop; a frame "
                    "it holds may still reach the ring", self._thread.name,
                    self._join_timeout_s)


class GrabStream:
    """Mixin of a camera driver whose stream a :class:`GrabThread` reads: it holds the
    thread in ``_grab`` (None while not streaming) and starts and stops it.

    The class it is mixed into is a :class:`drivers.camera.Camera` (``device_id`` and
    the logger :func:`report_stream_error` uses).
    """

    _grab: GrabThread | None = None

    def _start_grab(self, ring: Any, loop: Callable[[threading.Event], None], name: str,
                    join_timeout_s: float) -> None:
        """Start ``loop(stop)`` on a thread named ``<device_id>-<name>``; an error it
        raises ends the stream through :func:`report_stream_error` on ``ring``."""
        self._grab = GrabThread(loop, f"{self.device_id}-{name}", join_timeout_s,
                                lambda exc: report_stream_error(self, ring, exc)).start()

    def _stop_grab(self) -> None:
        """Stop the thread and wait for it (see :meth:`GrabThread.stop`); no-op when none
        runs."""
        grab, self._grab = self._grab, None
        if grab is not None:
            grab.stop()
