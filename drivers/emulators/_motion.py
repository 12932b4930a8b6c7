"""One axis of emulated motion: a trapezoidal velocity profile on model time."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Motion"]


@dataclass
class Motion:
    """A move from ``p0`` to ``p1`` starting at model time ``t0``.

    Accelerates at ``accel`` up to ``velocity`` (both positive, position units per
    second and per second squared), cruises, decelerates; a short move never reaches
    ``velocity`` (triangular profile). ``accel = inf`` gives a constant velocity.
    ``kind`` is free for the emulator ("move", "home", ...).
    """

    t0: float
    p0: float
    p1: float
    velocity: float
    accel: float
    kind: str = "move"

    def __post_init__(self) -> None:
        if not (self.velocity > 0 and self.accel > 0):
            raise ValueError("velocity and accel must be > 0")
        d = abs(self.p1 - self.p0)
        a, v = self.accel, self.velocity
        t_acc = 0.0 if math.isinf(a) else v / a
        d_acc = 0.5 * v * t_acc
        if 2 * d_acc >= d:  # triangle
            t_acc = 0.0 if math.isinf(a) else math.sqrt(d / a)
            self._vpeak = a * t_acc if t_acc else v
            self._cruise = 0.0
        else:
            self._vpeak = v
            self._cruise = (d - 2 * d_acc) / v
        self._t_acc = t_acc
        self.duration = 2 * t_acc + self._cruise

    @property
    def direction(self) -> int:
        """+1 forward, -1 reverse, 0 for no travel."""
        return (self.p1 > self.p0) - (self.p1 < self.p0)

    def position(self, t: float) -> float:
        """Position at model time ``t`` (``p1`` once done)."""
        dt = t - self.t0
        if dt >= self.duration:
            return self.p1
        if dt <= 0:
            return self.p0
        ta, vp, a = self._t_acc, self._vpeak, self.accel
        if dt < ta:
            s = 0.5 * a * dt * dt
        elif dt < ta + self._cruise:
            s = 0.5 * vp * ta + vp * (dt - ta)
        else:
            rem = self.duration - dt
            s = abs(self.p1 - self.p0) - (0.5 * a * rem * rem if ta else 0.0)
        return self.p0 + self.direction * s

    def done(self, t: float) -> bool:
        """True once the move has ended at model time ``t``."""
        return t - self.t0 >= self.duration
