"""Motion stage interface: :class:`Stage` with named axes.

Axes are chosen per instance from ``x``, ``y``, ``z`` (millimetres) and ``tip``,
``tilt``, ``rotation`` (degrees); positions, limits, velocities and backlash are
all in the axis unit (velocity in unit per second).

Backlash compensation
---------------------
``backlash[axis] = b`` (0 disables) makes every move *end* travelling in the
direction of ``sign(b)``: when a target lies on the other side of the current
position, the stage first goes to ``target - b`` (overshoot by ``|b|``) and then to
the target. The overshoot point must lie within the limits. With ``wait=False`` the
overshoot leg is still waited for; only the final leg returns immediately.
:attr:`Stage.last_path` lists the commanded legs of the last move.

Settings are ``limits``, ``velocity`` and ``backlash``; the position is state, not
a setting, and :meth:`~drivers.base.Device.reconnect` never replays motion.
"""

from __future__ import annotations

import abc
import contextlib
import time
from collections.abc import Iterable, Mapping
from typing import Any, ClassVar

from drivers.base import Device
from drivers.errors import DeviceError, DeviceValueError, StageLimitError, StageTimeoutError
from drivers.settings import Setting, info

__all__ = ["AXIS_UNITS", "HostTableStage", "Stage", "axes_info"]

#: Allowed axis names and their units.
AXIS_UNITS: dict[str, str] = {
    "x": "mm", "y": "mm", "z": "mm", "tip": "deg", "tilt": "deg", "rotation": "deg",
}


def _check_limits(device: Device, label: str, value: Any, low: float, high: float
                  ) -> tuple[float, float]:
    """One axis's soft limits ``(low, high)`` within its travel ``[low, high]``."""
    if isinstance(value, str | bytes) or not hasattr(value, "__len__") or len(value) != 2:
        raise device._error(
            DeviceValueError, f"{label}={value!r} is not (low, high)",
            f"pass two numbers within the travel [{low}, {high}]",
        )
    a = device._float(f"{label} low", value[0], low=low, high=high)
    b = device._float(f"{label} high", value[1], low=low, high=high)
    if not a < b:
        raise device._error(
            DeviceValueError, f"{label}=({a}, {b}) has low >= high", "give low < high",
        )
    return (a, b)


def _span(travel: Any) -> float:
    return float(travel[1]) - float(travel[0])


class Stage(Device):
    """Abstract multi-axis stage.

    Driver hooks, besides :class:`~drivers.base.Device`'s: ``_do_move(targets)``
    (start an absolute move, do not wait), ``_do_home(axes)`` (start homing),
    ``_do_wait(timeout_s) -> bool`` (True once idle, False on timeout),
    ``_do_is_moving() -> bool``, ``_do_positions() -> dict`` and ``_do_stop()``;
    optionally ``_do_positions_of(axes)`` (positions of some axes only: a move asks
    only the axes it needs, so a silent controller does not block the others).
    ``_do_get_info()`` returns ``{"axes": {name: {"travel": (lo, hi),
    "max_velocity": v}}}``.
    """

    kind: ClassVar[str] = "stage"
    timeout_error = StageTimeoutError
    SETTINGS = (
        Setting("limits", "(float, float)", "{unit}", "soft limits (low, high) per axis, "
                "within the travel; moves outside them are refused", per="axes",
                key_name="axis", key_units=AXIS_UNITS, check=_check_limits,
                low=info("axes.{key}.travel[0]"), high=info("axes.{key}.travel[1]")),
        Setting("velocity", "float", "{unit}/s", "velocity per axis", per="axes",
                key_name="axis", key_units=AXIS_UNITS, low=0.0, low_open=True,
                high=info("axes.{key}.max_velocity")),
        Setting("backlash", "float", "{unit}", "signed backlash overshoot per axis: moves "
                "end travelling in its direction (0: off)", per="axes", key_name="axis",
                key_units=AXIS_UNITS,
                low=info("axes.{key}.travel", transform=lambda t: -_span(t),
                         text="-(travel span)"),
                high=info("axes.{key}.travel", transform=_span, text="travel span")),
    )

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        self._last_path: list[dict[str, float]] = []

    # ----------------------------------------------------------- geometry
    @property
    def axes(self) -> tuple[str, ...]:
        """Names of this stage's axes."""
        self._require_open()
        return tuple(self._info["axes"])

    def units(self, axis: str) -> str:
        """Unit of ``axis``: "mm" or "deg"."""
        return AXIS_UNITS[self._axis(axis)]

    @property
    def travel(self) -> dict[str, tuple[float, float]]:
        """Mechanical range per axis ``{axis: (low, high)}`` (read-only)."""
        self._require_open()
        return {a: tuple(v["travel"]) for a, v in self._info["axes"].items()}

    @property
    def limits(self) -> dict[str, tuple[float, float]]:
        """Soft limits ``{axis: (low, high)}`` within the travel; set with a partial dict."""
        return dict(self._get("limits"))

    @limits.setter
    def limits(self, value: Mapping[str, Any]) -> None:
        self._set("limits", value)

    @property
    def velocity(self) -> dict[str, float]:
        """Velocity per axis in unit/s (0 < v <= max); set with a partial dict."""
        return dict(self._get("velocity"))

    @velocity.setter
    def velocity(self, value: Mapping[str, Any]) -> None:
        self._set("velocity", value)

    @property
    def backlash(self) -> dict[str, float]:
        """Signed backlash overshoot per axis in the axis unit (0 = off); partial dict."""
        return dict(self._get("backlash"))

    @backlash.setter
    def backlash(self, value: Mapping[str, Any]) -> None:
        self._set("backlash", value)

    @property
    def last_path(self) -> list[dict[str, float]]:
        """Commanded legs of the last move: absolute targets, in order."""
        return [dict(leg) for leg in self._last_path]

    # ----------------------------------------------------------- state
    def position(self, axis: str) -> float:
        """Current position of ``axis`` in its unit (interpolated while moving)."""
        axis = self._axis(axis)
        return self._positions_of((axis,))[axis]

    def _positions_of(self, axes: Iterable[str]) -> dict[str, float]:
        """Positions of ``axes`` only (a silent controller of another axis is not asked)."""
        axes = tuple(axes)
        if not axes:
            return {}
        with self._io():
            pos = self._do_positions_of(axes)
        return {a: float(pos[a]) for a in axes}

    def positions(self) -> dict[str, float]:
        """Current positions ``{axis: value}``."""
        self._require_open()
        with self._io():
            pos = self._do_positions()
        return {a: float(pos[a]) for a in self._info["axes"]}

    def is_moving(self) -> bool:
        """True while any axis moves or homes."""
        self._require_open()
        with self._io():
            return bool(self._do_is_moving())

    # ----------------------------------------------------------- motion
    def move_to(
        self, targets: Mapping[str, float], *, wait: bool = True, timeout_s: float = 30.0
    ) -> None:
        """Move axes to absolute positions (all axes start together).

        Parameters
        ----------
        targets : Mapping[str, float]
            ``{axis: position}`` in the axis unit; axes not named do not move.
        wait : bool
            Wait until the motion ends.
        timeout_s : float
            Longest wait, in seconds, for the whole move (both backlash legs).

        Raises
        ------
        StageLimitError
            A target (or its backlash overshoot point) is outside the limits;
            raised before anything moves.
        StageTimeoutError
            The motion did not end in time; the stage is stopped before raising.
        """
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        self._last_path = path = self.path_to(targets)
        targets = path[-1]
        self._log.debug("%s: move_to %s (path %s)", self.device_id, targets, self._last_path)
        start = self._now_s()
        if len(path) > 1:  # backlash: the overshoot point first
            with self._io():
                self._do_move(path[0])
            self._wait(timeout_s, targets)
        with self._io():
            self._do_move(targets)
        if wait:
            self._wait(timeout_s - (self._now_s() - start), targets)

    def path_to(self, targets: Mapping[str, float],
                start: Mapping[str, float] | None = None) -> list[dict[str, float]]:
        """The moves :meth:`move_to` would make to reach ``targets``, checked, nothing moved.

        Parameters
        ----------
        targets : Mapping[str, float]
            ``{axis: position}`` in the axis unit.
        start : Mapping[str, float], optional
            Positions to start from (default: the current ones); a plan's preflight
            passes the end of the previous move to check a whole sequence.

        Returns
        -------
        list of dict
            ``[overshoot, targets]`` when backlash makes the move end travelling in
            its positive direction (the overshoot point holds every target, with the
            backlash-corrected axes replaced), else ``[targets]``.

        Raises
        ------
        StageLimitError
            A target or its backlash overshoot point is outside the limits.
        DeviceValueError
            Unknown axis or a target that is not a finite number.
        """
        self._require_open()
        targets = self._check_targets(targets)
        backlash, limits = self._values["backlash"], self._values["limits"]
        if start is None:  # only the axes whose backlash depends on where they are
            current = self._positions_of(a for a in targets if backlash[a] != 0.0)
        else:
            current = dict(start)
        pre: dict[str, float] = {}
        for axis, t in targets.items():
            b = backlash[axis]
            if b != 0.0 and (t - current[axis]) * b < 0.0:
                pre[axis] = t - b
                lo, hi = limits[axis]
                if not lo <= pre[axis] <= hi:
                    raise self._error(
                        StageLimitError,
                        f"backlash overshoot point {axis}={pre[axis]:g} is outside the limits "
                        f"[{lo:g}, {hi:g}] (target {t:g}, backlash {b:g})",
                        "approach from the other side, reduce the backlash or widen the limits",
                    )
        return ([{**targets, **pre}] if pre else []) + [dict(targets)]

    def move_by(
        self, deltas: Mapping[str, float], *, wait: bool = True, timeout_s: float = 30.0
    ) -> None:
        """Move axes by relative amounts from their current positions (see :meth:`move_to`)."""
        self._require_open()
        if not isinstance(deltas, Mapping):
            raise self._error(
                DeviceValueError, f"deltas={deltas!r} is not a mapping", "pass {axis: delta}"
            )
        named = [self._axis(a) for a in deltas]
        current = self._positions_of(named)
        targets = {}
        for axis, d in deltas.items():
            axis = self._axis(axis)
            targets[axis] = current[axis] + self._float(f"delta[{axis}]", d)
        self.move_to(targets, wait=wait, timeout_s=timeout_s)

    def home(self, axes: Iterable[str] | None = None, *, timeout_s: float = 60.0) -> None:
        """Home ``axes`` (default all) and wait until done.

        Raises
        ------
        StageTimeoutError
            Homing did not finish in time; the stage is stopped before raising.
        """
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        names = tuple(self._info["axes"]) if axes is None else tuple(
            self._axis(a) for a in ([axes] if isinstance(axes, str) else axes)
        )
        self._last_path = []
        self._log.info("%s: homing %s", self.device_id, names)
        with self._io():
            self._do_home(names)
        self._wait(timeout_s, {})

    def wait_until_idle(self, timeout_s: float = 30.0) -> None:
        """Block until no axis moves.

        Raises
        ------
        StageTimeoutError
            Still moving after ``timeout_s`` seconds; the stage is stopped.
        """
        self._require_open()
        self._wait(self._check_timeout(timeout_s), {})

    def stop(self) -> None:
        """Stop all axes now (decelerating)."""
        self._require_open()
        with self._io():
            self._do_stop()

    # ----------------------------------------------------------- helpers
    def _wait(self, timeout_s: float, targets: Mapping[str, float]) -> None:
        with self._io():
            done = timeout_s > 0 and self._do_wait(timeout_s)
        if done:
            return
        with contextlib.suppress(DeviceError), self._io():
            self._do_stop()
        pos = self.positions()
        raise self._timeout(
            f"motion not finished within {timeout_s:g} s (positions {pos}, targets "
            f"{dict(targets)}); the stage was stopped",
            "check for an obstruction or a stalled axis, or raise timeout_s",
        )

    def _axis(self, axis: Any) -> str:
        self._require_open()
        if isinstance(axis, str) and axis in self._info["axes"]:
            return axis
        raise self._error(
            DeviceValueError, f"unknown axis {axis!r}", f"use one of {list(self._info['axes'])}"
        )

    def _check_targets(self, targets: Any) -> dict[str, float]:
        if not isinstance(targets, Mapping) or not targets:
            raise self._error(
                DeviceValueError, f"targets={targets!r} is not a non-empty mapping",
                "pass {axis: position}",
            )
        out = {}
        for axis, t in targets.items():
            axis = self._axis(axis)
            v = self._float(f"target[{axis}]", t)
            lo, hi = self._values["limits"][axis]
            if not lo <= v <= hi:
                raise self._error(
                    StageLimitError,
                    f"target {axis}={v:g} {AXIS_UNITS[axis]} is outside the limits "
                    f"[{lo:g}, {hi:g}]",
                    "choose a target within the limits or widen them (stage.limits)",
                )
            out[axis] = v
        return out

    def _do_status(self) -> dict[str, Any]:
        return {"positions": self.positions(), "moving": self.is_moving()}

    # ----------------------------------------------------------- hooks
    @abc.abstractmethod
    def _do_move(self, targets: dict[str, float]) -> None: ...

    @abc.abstractmethod
    def _do_home(self, axes: tuple[str, ...]) -> None: ...

    @abc.abstractmethod
    def _do_wait(self, timeout_s: float) -> bool: ...

    @abc.abstractmethod
    def _do_is_moving(self) -> bool: ...

    @abc.abstractmethod
    def _do_positions(self) -> dict[str, float]: ...

    def _do_positions_of(self, axes: tuple[str, ...]) -> dict[str, float]:
        """Positions of ``axes``; a driver with one controller per axis overrides it to
        ask only those controllers."""
        return self._do_positions()

    @abc.abstractmethod
    def _do_stop(self) -> None: ...


def axes_info(travel: Mapping[str, tuple[float, float]], max_velocity: float
              ) -> dict[str, Any]:
    """The ``_do_get_info()`` of a stage whose axes share one top speed.

    Parameters
    ----------
    travel : mapping of str to (float, float)
        Each axis's travel ``(low, high)``, in the axis's unit (mm or deg).
    max_velocity : float
        Top speed of every axis, unit/s.

    Returns
    -------
    dict
        ``{"axes": {axis: {"travel": (low, high), "max_velocity": max_velocity}}}``.
    """
    return {"axes": {a: {"travel": t, "max_velocity": max_velocity} for a, t in travel.items()}}


class HostTableStage(Stage):
    """A hardware stage whose travel and settings are kept in host-side tables.

    For drivers of real controllers: the subclass fills ``self._travel`` (``{axis:
    (low, high)}``), ``self._vmax`` and ``self._hw`` (``limits``, ``velocity``,
    ``backlash``) at open and implements ``_send_velocity(axis, velocity)``, which
    sends one axis's velocity to the controller, reads it back and returns the
    velocity the controller took (None: as sent). Limits and backlash are applied by
    this interface (software limits, overshoot moves).
    """

    _travel: dict[str, tuple[float, float]]
    _vmax: float
    _hw: dict[str, Any]

    def _do_get_info(self) -> dict[str, Any]:
        return axes_info(self._travel, self._vmax)

    def _do_get_settings(self) -> dict[str, Any]:
        return {k: dict(v) for k, v in self._hw.items()}

    def _do_apply(self, name: str, value: Any) -> Any:
        if name == "velocity":
            value = dict(value)
            for axis, v in value.items():
                if v != self._hw["velocity"].get(axis):
                    took = self._send_velocity(axis, v)
                    value[axis] = v if took is None else took
            self._hw[name] = value
            return dict(value)
        self._hw[name] = dict(value)
        return None

    @abc.abstractmethod
    def _send_velocity(self, axis: str, velocity: float) -> float | None: ...

    def _wait_homing_at_open(self, home_timeout_s: float) -> None:
        """Wait for the homing a driver started at open (``home_on_open``), up to
        ``home_timeout_s`` seconds or the end of the open's own ``timeout_s`` when the
        caller gave one, whichever comes first; the open's cancel event is checked
        every 0.1 s.

        Raises
        ------
        DeviceTimeoutError
            The kind's timeout error, naming the bound that ended the wait; the axes
            keep homing.
        DeviceCancelledError
            The open was cancelled: the axes are stopped.
        """
        now = time.monotonic()
        deadline, cancel = self._open_bounds
        end, bound = now + home_timeout_s, f"home_timeout_s = {home_timeout_s:g} s"
        fix = "open again once homed, or raise home_timeout_s in the bench file"
        if deadline is not None and deadline < end:
            end, bound = deadline, "the open's timeout_s"
            fix = "open again once homed, or open with a longer timeout"
        while True:
            if cancel is not None and cancel.is_set():
                with contextlib.suppress(DeviceError):
                    self._do_stop()
                self._check_cancel("while homing (the axes were stopped)")
            left = end - time.monotonic()
            if self._do_wait(max(0.0, min(0.1, left))):
                return
            if left <= 0:
                raise self._timeout(f"homing at open did not finish within {bound}; the "
                                    "axes are still homing", fix)
