"""Simulated multi-axis stage moving on simulated time."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.errors import DeviceValueError
from drivers.simulated._common import SimulatedMixin
from drivers.simulated.clock import SimClock
from drivers.simulated.faults import StageFaults
from drivers.stage import AXIS_UNITS, Stage, axes_info

__all__ = ["DEFAULT_TRAVEL", "SimulatedStage"]

#: Travel of an axis given by name only: mm for x, y, z; degrees for the rotations.
DEFAULT_TRAVEL: dict[str, tuple[float, float]] = {
    "x": (-25.0, 25.0), "y": (-25.0, 25.0), "z": (0.0, 50.0),
    "tip": (-10.0, 10.0), "tilt": (-10.0, 10.0), "rotation": (-180.0, 180.0),
}


class SimulatedStage(SimulatedMixin, Stage):
    """A stage whose axes move at constant velocity on a :class:`SimClock`.

    A move of ``d`` at velocity ``v`` takes ``|d| / v`` simulated seconds (all axes
    start together); positions are interpolated in between, :meth:`is_moving`
    follows the clock and waits advance it. Homing moves each axis to its home
    position the same way. Each completed leg lands at ``target + N(0,
    repeatability_sigma)``. The position survives close/open (it is mechanical);
    closing stops any motion.

    Parameters
    ----------
    device_id : str
        Name of the stage.
    axes : Mapping[str, (float, float)] or sequence of str
        Axis names (from x, y, z, tip, tilt, rotation) and their travel ``(low, high)``;
        a list of names takes :data:`instrument.config.DEFAULT_TRAVEL`. Default x, y
        +-25 mm, z 0..50 mm.
    velocity : float or Mapping[str, float]
        Initial velocity per axis, unit/s.
    max_velocity : float
        Largest velocity allowed on every axis, unit/s.
    home_positions : Mapping[str, float], optional
        Home position per axis; default 0 clipped into the travel. Axes start there.
    repeatability_sigma : float
        Standard deviation of the landing error, in the axis unit.
    seed : int
        Seeds the landing error and the faults.
    clock : SimClock, optional
        Shared simulated time.
    """

    def __init__(
        self, device_id: str, *,
        axes: Mapping[str, tuple[float, float]] | list[str] | tuple[str, ...] | None = None,
        velocity: float | Mapping[str, float] = 5.0, max_velocity: float = 50.0,
        home_positions: Mapping[str, float] | None = None,
        repeatability_sigma: float = 0.0, seed: int = 0, clock: SimClock | None = None,
    ) -> None:
        super().__init__(device_id)
        self.faults: StageFaults
        self._sim_setup(clock, StageFaults(self, seed))
        axes = {"x": (-25.0, 25.0), "y": (-25.0, 25.0), "z": (0.0, 50.0)} if axes is None else axes
        if isinstance(axes, list | tuple):  # names only: default travel per axis
            axes = {a: DEFAULT_TRAVEL.get(a, (0.0, 0.0)) for a in axes}
        if not isinstance(axes, Mapping) or not axes:
            raise self._error(DeviceValueError, f"axes={axes!r} is invalid",
                              "pass {name: (low, high)} with names from " + str(list(AXIS_UNITS)))
        self._travel: dict[str, tuple[float, float]] = {}
        for name, rng in axes.items():
            if name not in AXIS_UNITS:
                raise self._error(DeviceValueError, f"axis name {name!r} is not supported",
                                  f"use names from {list(AXIS_UNITS)}")
            lo, hi = self._float(f"{name} low", rng[0]), self._float(f"{name} high", rng[1])
            if not lo < hi:
                raise self._error(DeviceValueError, f"travel of {name} ({lo}, {hi}) is empty",
                                  "give low < high")
            self._travel[name] = (lo, hi)
        self._vmax = self._float("max_velocity", max_velocity, low=0.0, low_open=True)
        vel = velocity if isinstance(velocity, Mapping) else dict.fromkeys(self._travel, velocity)
        self._v0 = {a: self._float(f"velocity[{a}]", vel[a], low=0.0, low_open=True,
                                   high=self._vmax) for a in self._travel}
        home = dict(home_positions or {})
        self._home = {a: float(np.clip(self._float(f"home[{a}]", home.get(a, 0.0)), *t))
                      for a, t in self._travel.items()}
        self.repeatability_sigma = self._float("repeatability_sigma", repeatability_sigma,
                                               low=0.0)
        self._rng = np.random.default_rng([self._int("seed", seed, low=0), 3])
        self._pos = dict(self._home)
        # per axis: (t0, p0, p1, t1); a stuck axis has t1 = inf and p1 = p0
        self._motion: dict[str, tuple[float, float, float, float]] = {}
        self._homed = dict.fromkeys(self._travel, False)
        self._hw: dict[str, Any] = {}

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        self.faults._try_connect()
        self._hw = {
            "limits": dict(self._travel), "velocity": dict(self._v0),
            "backlash": dict.fromkeys(self._travel, 0.0),
        }

    def _do_close(self) -> None:
        self._freeze(list(self._motion))

    def _do_get_info(self) -> dict[str, Any]:
        return axes_info(self._travel, self._vmax)

    # ----------------------------------------------------------- motion hooks
    def _do_move(self, targets: dict[str, float]) -> None:
        self.faults._check_connected()
        self._start(targets)

    def _do_home(self, axes: tuple[str, ...]) -> None:
        self.faults._check_connected()
        self._start({a: self._home[a] for a in axes})
        for a in axes:
            self._homed[a] = a not in self.faults.stuck

    def _do_wait(self, timeout_s: float) -> bool:
        if self._fault_timeout(timeout_s):
            return False
        now = self.clock.now_s
        remaining = max((m[3] - now for m in self._motion.values()), default=0.0)
        if remaining > timeout_s:
            self.clock.advance(timeout_s)
            return False
        self.clock.advance(max(remaining, 0.0))
        self._settle()
        return True

    def _do_is_moving(self) -> bool:
        self.faults._check_connected()
        self._settle()
        return bool(self._motion)

    def _do_positions(self) -> dict[str, float]:
        self.faults._check_connected()
        self._settle()
        return {a: self._interp(a) for a in self._travel}

    def _do_stop(self) -> None:
        self.faults._check_connected()
        self._freeze(list(self._motion))

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "homed": dict(self._homed), "time_s": self.clock.now_s}

    # ----------------------------------------------------------- kinematics
    def _start(self, targets: Mapping[str, float]) -> None:
        now = self.clock.now_s
        self._settle()
        for axis, target in targets.items():
            p0 = self._interp(axis)
            if axis in self.faults.stuck:
                self._motion[axis] = (now, p0, p0, math.inf)
                continue
            if self.repeatability_sigma > 0:
                target = target + self._rng.normal(0.0, self.repeatability_sigma)
            duration = abs(target - p0) / self._hw["velocity"][axis]
            self._motion[axis] = (now, p0, target, now + duration)
        self._settle()

    def _interp(self, axis: str) -> float:
        if axis not in self._motion:
            return self._pos[axis]
        t0, p0, p1, t1 = self._motion[axis]
        if not math.isfinite(t1) or t1 <= t0:
            return p0 if not math.isfinite(t1) else p1
        frac = min(max((self.clock.now_s - t0) / (t1 - t0), 0.0), 1.0)
        return p0 + (p1 - p0) * frac

    def _settle(self) -> None:
        """Retire finished motions."""
        now = self.clock.now_s
        for axis, (_, _, p1, t1) in list(self._motion.items()):
            if t1 <= now:
                self._pos[axis] = p1
                del self._motion[axis]

    def _freeze(self, axes: list[str]) -> None:
        for axis in axes:
            self._pos[axis] = self._interp(axis)
            self._motion.pop(axis, None)
