"""Behaviour shared by the simulated drivers (clock, faults, simulated waits)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.simulated.clock import SimClock
from drivers.simulated.faults import DeviceFaults


class SimulatedMixin:
    """Runs a device's time on a :class:`SimClock` and routes calls through its faults.

    Put it first in the bases (``class SimulatedX(SimulatedMixin, X)``) so its
    ``_now_s``/``_sleep_s``/``_do_check_connection`` override the interface defaults.
    """

    clock: SimClock
    faults: DeviceFaults
    #: The device's settings as set (``_do_open`` fills it); a dict value (a stage's
    #: per-axis limits, a DMD's currents per colour) is kept and returned as a copy.
    _hw: dict[str, Any]

    def _sim_setup(self, clock: SimClock | None, faults: DeviceFaults) -> None:
        if clock is not None and not isinstance(clock, SimClock):
            raise TypeError(f"clock must be a SimClock or None, got {type(clock).__name__}")
        self.clock = clock if clock is not None else SimClock()
        self.faults = faults

    def _do_check_connection(self) -> None:
        self.faults._check_connected()

    def _do_get_settings(self) -> dict[str, Any]:
        return {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in self._hw.items()}

    def _do_apply(self, name: str, value: Any) -> Any:
        self.faults._check_connected()
        self._hw[name] = dict(value) if isinstance(value, Mapping) else value
        return None

    def _now_s(self) -> float:
        return self.clock.now_s

    def _sleep_s(self, seconds: float) -> None:
        if seconds > 0:
            self.clock.advance(seconds)

    def _fault_timeout(self, timeout_s: float) -> bool:
        """Check the connection; if a timeout fault is pending, spend ``timeout_s`` of
        simulated time and return True (the caller then raises or reports failure)."""
        self.faults._check_connected()
        if self.faults._take_timeout():
            self.clock.advance(timeout_s)
            return True
        return False

    def _raise_fault_timeout(self, what: str, timeout_s: float) -> None:
        if self._fault_timeout(timeout_s):
            raise self._timeout(  # type: ignore[attr-defined]
                f"{what} got no answer within {timeout_s:g} s (simulated fault)",
                "check the connection and retry; in tests, faults.timeout_next() caused this",
            )
