"""Simulated time shared by the simulated devices: :class:`SimClock`."""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections.abc import Callable

__all__ = ["SimClock"]


class SimClock:
    """Simulated time in seconds, advanced by device operations, never by itself.

    Devices sharing a clock see one consistent time: a stage move that takes 2 s
    advances the clock by 2 s, and a streaming camera produces the frames that fall
    due in those 2 s (each frame rendered at its own time, so it sees the stage
    where it was then).

    Parameters
    ----------
    start_s : float
        Initial time in seconds.
    realtime : bool
        If True, advancing the clock also sleeps the same wall-clock time (for demos
        with a GUI); tests keep the default False and never sleep.

    Notes
    -----
    Timers registered with :meth:`subscribe` fire in time order while the clock
    advances; a timer must not advance the clock itself (RuntimeError).
    """

    def __init__(self, start_s: float = 0.0, *, realtime: bool = False) -> None:
        if not math.isfinite(start_s):
            raise ValueError(f"SimClock: start_s={start_s!r} must be finite")
        self._now = float(start_s)
        self.realtime = bool(realtime)
        self._timers: dict[int, tuple[Callable[[], float | None], Callable[[float], None]]] = {}
        self._tokens = itertools.count()
        self._lock = threading.RLock()
        self._firing = False

    @property
    def now_s(self) -> float:
        """Current simulated time in seconds."""
        return self._now

    def advance(self, dt_s: float) -> None:
        """Advance by ``dt_s`` >= 0 seconds, firing due timers in order."""
        if not dt_s >= 0 or not math.isfinite(dt_s):
            raise ValueError(f"SimClock: cannot advance by {dt_s!r} s; use a finite dt_s >= 0")
        self.advance_to(self._now + dt_s)

    def advance_to(self, t_s: float) -> None:
        """Advance to time ``t_s`` (>= now), firing due timers in order."""
        with self._lock:
            if self._firing:
                raise RuntimeError(
                    "SimClock: a timer callback tried to advance the clock; "
                    "callbacks (e.g. a camera's irradiance function) must only read state"
                )
            if t_s < self._now:
                raise ValueError(f"SimClock: cannot go back from {self._now} to {t_s} s")
            while True:
                due = []
                for token, (next_event, _) in list(self._timers.items()):
                    t = next_event()
                    if t is not None and t <= t_s:
                        due.append((t, token))
                if not due:
                    break
                t, token = min(due)
                self._step(max(t, self._now))
                self._firing = True
                try:
                    self._timers[token][1](self._now)
                finally:
                    self._firing = False
            self._step(t_s)

    def subscribe(
        self, next_event: Callable[[], float | None], fire: Callable[[float], None]
    ) -> int:
        """Register a timer; returns a token for :meth:`unsubscribe`.

        ``next_event()`` returns the time of the timer's next event (None: none
        pending); ``fire(t)`` handles it and must move ``next_event()`` later.
        """
        with self._lock:
            token = next(self._tokens)
            self._timers[token] = (next_event, fire)
            return token

    def unsubscribe(self, token: int) -> None:
        """Remove a timer (unknown tokens are ignored)."""
        with self._lock:
            self._timers.pop(token, None)

    def _step(self, t: float) -> None:
        if self.realtime and t > self._now:
            time.sleep(t - self._now)
        self._now = t
