"""Simulated time shared by the simulated devices: :class:`SimClock`."""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections.abc import Callable

__all__ = ["SimClock"]


#: Real-time mode: the longest simulated step an advance sleeps through before it
#: looks again for timers (one subscribed meanwhile by another thread), s.
REALTIME_STEP_S = 0.02


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
        If True, advancing the clock also waits on the wall clock (for demos, live
        capture and a GUI); tests keep the default False and never sleep.
    max_lag_s : float
        Real-time mode only: how far simulated time may lag behind the wall clock
        before the clock stops catching up (see Notes).

    Notes
    -----
    Timers registered with :meth:`subscribe` fire in time order while the clock
    advances; a timer must not advance the clock itself (RuntimeError).

    Real-time pacing: simulated time ``t`` is due at wall time
    ``wall_0 + (t - sim_0)`` for an anchor ``(wall_0, sim_0)``; advancing to ``t``
    sleeps until then, so work done between advances (rendering a frame) does not
    add up as drift. When the clock is behind its anchor by more than
    ``max_lag_s`` (it sat idle, or the work is slower than real time) the anchor
    moves to now: simulated time never races to catch up, and each such slip is
    counted in :attr:`slips` / :attr:`slipped_s` (idle periods count too). A
    shorter lag is caught up (an idle gap under ``max_lag_s`` counts as elapsed
    time); :meth:`resync` starts a paced sequence afresh (a camera's stream does).
    """

    def __init__(self, start_s: float = 0.0, *, realtime: bool = False,
                 max_lag_s: float = 0.1) -> None:
        if not math.isfinite(start_s):
            raise ValueError(f"SimClock: start_s={start_s!r} must be finite")
        if not 0 < max_lag_s < math.inf:
            raise ValueError(f"SimClock: max_lag_s={max_lag_s!r}; use a finite number > 0")
        self._now = float(start_s)
        self.realtime = bool(realtime)
        self.max_lag_s = float(max_lag_s)
        self._anchor = (time.monotonic(), self._now)
        #: Real-time mode: times the clock fell more than ``max_lag_s`` behind.
        self.slips = 0
        #: Real-time mode: wall-clock seconds given up by those slips.
        self.slipped_s = 0.0
        self._timers: dict[int, tuple[Callable[[], float | None], Callable[[float], None]]] = {}
        self._tokens = itertools.count()
        self._lock = threading.RLock()
        #: Guards ``_timers`` alone: a timer is added or removed while another thread
        #: advances the clock (which, in real time, holds ``_lock`` for as long as the
        #: advance lasts: a stage's 70 s move once kept a stream that started meanwhile
        #: from subscribing its camera's timer, and so from any frame, until it ended).
        self._timers_lock = threading.Lock()
        self._firing = False

    @property
    def now_s(self) -> float:
        """Current simulated time in seconds."""
        return self._now

    def advance(self, dt_s: float) -> None:
        """Advance by ``dt_s`` >= 0 seconds from now, firing due timers in order (safe
        from several threads: "now" is read under the lock that advancing holds)."""
        if not dt_s >= 0 or not math.isfinite(dt_s):
            raise ValueError(f"SimClock: cannot advance by {dt_s!r} s; use a finite dt_s >= 0")
        with self._lock:
            self.advance_to(self._now + dt_s)

    def advance_to(self, t_s: float) -> None:
        """Advance to time ``t_s`` (>= now), firing due timers in order."""
        with self._lock:
            self._sync()
            if self._firing:
                raise RuntimeError(
                    "SimClock: a timer callback tried to advance the clock; "
                    "callbacks (e.g. a camera's irradiance function) must only read state"
                )
            if t_s < self._now:
                raise ValueError(f"SimClock: cannot go back from {self._now} to {t_s} s")
            while True:
                due = []
                with self._timers_lock:
                    timers = list(self._timers.items())
                for token, (next_event, _) in timers:
                    t = next_event()
                    if t is not None and t <= t_s:
                        due.append((t, token))
                if not due:
                    if self.realtime and t_s - self._now > REALTIME_STEP_S:
                        # in steps: a timer subscribed meanwhile fires in time
                        self._step(self._now + REALTIME_STEP_S)
                        continue
                    break
                t, token = min(due)
                self._step(max(t, self._now))
                with self._timers_lock:
                    timer = self._timers.get(token)
                if timer is None:  # unsubscribed meanwhile
                    continue
                self._firing = True
                try:
                    timer[1](self._now)
                finally:
                    self._firing = False
            self._step(t_s)

    def run_until(self, t_s: float) -> None:
        """Advance to ``t_s`` if it is later than now, else do nothing (a thread
        pacing the clock uses it: another thread may have advanced it meanwhile)."""
        with self._lock:
            if t_s > self._now:
                self.advance_to(t_s)

    def resync(self) -> None:
        """Real-time mode: take the current simulated time as due now (forget any lag).

        Not under the lock an advance holds (a camera's stream resyncs as it starts,
        perhaps while a stage's move advances the clock): the anchor is one tuple,
        replaced at once, and an advance under way paces its next step from it."""
        self._anchor = (time.monotonic(), self._now)

    def wall_time_until(self, t_s: float) -> float:
        """Wall-clock seconds until simulated time ``t_s`` is due (0 when not
        real-time or already due)."""
        if not self.realtime:
            return 0.0
        with self._lock:
            self._sync()
            wall0, sim0 = self._anchor
            return max(0.0, wall0 + (t_s - sim0) - time.monotonic())

    def subscribe(
        self, next_event: Callable[[], float | None], fire: Callable[[float], None]
    ) -> int:
        """Register a timer; returns a token for :meth:`unsubscribe`.

        ``next_event()`` returns the time of the timer's next event (None: none
        pending); ``fire(t)`` handles it and must move ``next_event()`` later.
        """
        with self._timers_lock:  # not ``_lock``: another thread may be advancing
            token = next(self._tokens)
            self._timers[token] = (next_event, fire)
            return token

    def unsubscribe(self, token: int) -> None:
        """Remove a timer (unknown tokens are ignored)."""
        with self._timers_lock:
            self._timers.pop(token, None)

    def _sync(self) -> None:
        """Move the real-time anchor to now when the clock lags more than max_lag_s."""
        if not self.realtime:
            return
        wall0, sim0 = self._anchor
        wall = time.monotonic()
        lag = wall - (wall0 + (self._now - sim0))
        if lag > self.max_lag_s:
            self.slips += 1
            self.slipped_s += lag
            self._anchor = (wall, self._now)

    def _step(self, t: float) -> None:
        if self.realtime and t > self._now:
            wall0, sim0 = self._anchor
            wait = wall0 + (t - sim0) - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        self._now = t
