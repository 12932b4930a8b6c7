"""The acquisition thread of a streaming camera driver: :class:`GrabThread`."""

from __future__ import annotations

import threading
from collections.abc import Callable

__all__ = ["GrabThread"]


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
    """

    def __init__(self, target: Callable[[threading.Event], None], name: str,
                 join_timeout_s: float) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=target, args=(self._stop,), daemon=True,
                                        name=name)
        self._join_timeout_s = join_timeout_s

    def start(self) -> GrabThread:
        """Start the thread; returns self."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Ask the thread to end and wait for it (not when called from the thread itself)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=self._join_timeout_s)
