"""How often a live view shows new images: as often as the GUI thread keeps up with.

The Live panel's timer fires every 50 ms; each image shown costs the GUI thread its
lookup, its ``QImage`` and a paint (a few ms a view). On a computer whose cores other
programs fill, the timer comes late, and a GUI thread that still wants to paint 20
times a second asks for more than its share of a core: its stalls grow. The
:class:`DisplayPacer` halves the rate of images shown whenever a tick comes a whole
period late (down to :data:`SLOWEST_S` between images) and doubles it back after
:data:`RECOVER_S` seconds on time. The images not shown are counted by the panel and
said in its counters; the camera, the recording and the live reconstruction take
every frame whatever the view shows.
"""

from __future__ import annotations

__all__ = ["RECOVER_S", "SLOWEST_S", "DisplayPacer"]

#: The longest interval between two images shown, s (5 a second).
SLOWEST_S = 0.2
#: Seconds of ticks on time before the rate of images shown doubles back.
RECOVER_S = 2.0
#: A pause this long (s: the panel hidden, the machine suspended) starts afresh.
RESTART_S = 1.0


class DisplayPacer:
    """Decides at each tick of a view's timer whether new images are shown.

    Parameters
    ----------
    tick_s : float
        The timer's interval, s: the shortest interval between images shown.
    slowest_s : float
        The longest, s.
    recover_s : float
        Seconds of ticks on time before the interval halves back.

    Attributes
    ----------
    period_s : float
        The interval between images shown now, s.
    ticks_skipped : int
        Ticks that showed nothing new, since the pacer was made.
    """

    def __init__(self, tick_s: float = 0.05, slowest_s: float = SLOWEST_S,
                 recover_s: float = RECOVER_S) -> None:
        self.tick_s = float(tick_s)
        self.slowest_s = max(float(slowest_s), self.tick_s)
        self.recover_s = float(recover_s)
        self.period_s = self.tick_s
        self.ticks_skipped = 0
        self._last_tick: float | None = None
        self._last_shown = -1e18
        self._on_time_since = 0.0

    @property
    def rate_hz(self) -> float:
        """Images shown per second at most, now."""
        return 1.0 / self.period_s

    def tick(self, now_s: float) -> bool:
        """The timer fired at ``now_s`` (a monotonic clock, s): True when this tick
        shows new images."""
        interval = None if self._last_tick is None else now_s - self._last_tick
        self._last_tick = now_s
        if interval is None or interval > RESTART_S:
            self.period_s, self._on_time_since = self.tick_s, now_s
        elif interval >= 2.0 * self.tick_s:  # a whole tick late: the thread is behind
            self.period_s = min(2.0 * self.period_s, self.slowest_s)
            self._on_time_since = now_s
        elif now_s - self._on_time_since >= self.recover_s and self.period_s > self.tick_s:
            self.period_s = max(self.period_s / 2.0, self.tick_s)
            self._on_time_since = now_s
        if now_s - self._last_shown >= self.period_s - 0.5 * self.tick_s:
            self._last_shown = now_s
            return True
        self.ticks_skipped += 1
        return False
