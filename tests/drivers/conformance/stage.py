"""Conformance suite of stages."""

from __future__ import annotations

import math
import time

import pytest

from drivers.errors import (
    DeviceDisconnectedError,
    DeviceValueError,
    StageLimitError,
    StageTimeoutError,
)

from .base import DeviceConformance


def unplug_mid_move(stage, emulator, axis: str, target: float, velocity: float) -> None:
    """Start a slow move of ``axis`` and unplug ``emulator`` (a yanked USB cable).

    Checks that waiting for the move raises DeviceDisconnectedError at once (never
    hangs) and so does every later call, until the test calls ``reconnect()``.
    """
    stage.velocity = {axis: velocity}
    stage.move_to({axis: target}, wait=False)
    emulator.unplug()
    t0 = time.monotonic()
    with pytest.raises(DeviceDisconnectedError, match="reconnect"):
        stage.wait_until_idle(timeout_s=120.0)
    # a hang guard, not a speed check (a loaded host runs late): a wait that ran out its
    # 120 s, or the move's end, fails it
    assert time.monotonic() - t0 < 30.0
    with pytest.raises(DeviceDisconnectedError):
        stage.positions()


class StageConformance(DeviceConformance):
    """Stage behaviour: moves, homing, limits and backlash."""

    kind = "stage"
    timeout_error = StageTimeoutError
    position_tolerance = 1e-6

    def _axis(self, device) -> tuple[str, float, float]:
        axis = device.axes[0]
        lo, hi = device.limits[axis]
        return axis, lo, hi

    def use(self, device):
        return device.positions()

    def blocking_call(self, device):
        axis, lo, hi = self._axis(device)
        target = lo + 0.25 * (hi - lo) if device.position(axis) > (lo + hi) / 2 else hi - 0.25 * (
            hi - lo)
        device.move_to({axis: target}, timeout_s=60.0)

    def changed_settings(self, device):
        axis, lo, hi = self._axis(device)
        span = hi - lo
        return {
            "limits": {axis: [lo + 0.05 * span, hi - 0.05 * span]},
            "velocity": {axis: device.velocity[axis] / 2},
            "backlash": {axis: 0.01 * span},
        }

    def invalid_settings(self, device):
        axis, _, _ = self._axis(device)
        tlo, thi = device.travel[axis]
        return [
            {"velocity": {axis: 0}}, {"velocity": {axis: -1.0}}, {"velocity": {axis: 1e12}},
            {"velocity": 2.0}, {"velocity": {"w": 1.0}},
            {"limits": {axis: [tlo - 1, thi]}}, {"limits": {axis: [thi, tlo]}},
            {"limits": {axis: [tlo]}}, {"backlash": {axis: math.nan}},
        ]

    def assert_settings_in_effect(self, device, settings):
        axis = next(iter(settings["limits"]))
        lo, hi = settings["limits"][axis]
        with pytest.raises(StageLimitError):
            device.move_to({axis: hi + 1e-3 * (hi - lo)})

    def test_axes_units_and_positions(self, device):
        assert device.axes and set(device.positions()) == set(device.axes)
        for a in device.axes:
            assert device.units(a) in ("mm", "deg")
            tlo, thi = device.travel[a]
            lo, hi = device.limits[a]
            assert tlo <= lo < hi <= thi
        with pytest.raises(DeviceValueError, match="unknown axis"):
            device.position("w")

    def test_move_to_and_move_by(self, device):
        axis, lo, hi = self._axis(device)
        target = lo + 0.3 * (hi - lo)
        device.move_to({axis: target})
        assert not device.is_moving()
        assert device.position(axis) == pytest.approx(target, abs=self.position_tolerance)
        device.move_by({axis: 0.1 * (hi - lo)})
        assert device.position(axis) == pytest.approx(target + 0.1 * (hi - lo),
                                                      abs=self.position_tolerance)
        with pytest.raises(DeviceValueError):
            device.move_by([(axis, 1.0)])
        with pytest.raises(DeviceValueError):
            device.move_to({})

    def test_move_without_wait(self, device):
        axis, lo, hi = self._axis(device)
        start = device.position(axis)
        target = hi - 0.1 * (hi - lo) if start < (lo + hi) / 2 else lo + 0.1 * (hi - lo)
        device.move_to({axis: target}, wait=False)
        assert device.is_moving()
        device.wait_until_idle(timeout_s=60.0)
        assert not device.is_moving()
        assert device.position(axis) == pytest.approx(target, abs=self.position_tolerance)

    def test_home(self, device):
        axis, lo, hi = self._axis(device)
        device.move_to({axis: lo + 0.9 * (hi - lo)})
        device.home(timeout_s=120.0)
        assert not device.is_moving()
        device.home([axis], timeout_s=120.0)
        with pytest.raises(DeviceValueError):
            device.home(["w"])

    def test_limits_checked_before_anything_moves(self, device):
        before = device.positions()
        axes = device.axes
        lo, hi = device.limits[axes[-1]]
        targets = {a: sum(device.limits[a]) / 2 for a in axes[:-1]}
        targets[axes[-1]] = hi + 0.01 * (hi - lo)
        with pytest.raises(StageLimitError, match="outside the limits") as info:
            device.move_to(targets)
        assert isinstance(info.value, ValueError) and "Fix:" in str(info.value)
        assert not device.is_moving()
        assert device.positions() == before
        with pytest.raises(DeviceValueError):
            device.move_to({axes[0]: math.nan})
        with pytest.raises(DeviceValueError, match="unknown axis"):
            device.move_to({"w": 0.0})

    def test_narrowed_limits_apply(self, device):
        axis, lo, hi = self._axis(device)
        mid = (lo + hi) / 2
        device.limits = {axis: (lo, mid)}
        assert device.limits[axis] == (lo, mid)
        with pytest.raises(StageLimitError):
            device.move_to({axis: mid + 0.01 * (hi - lo)})
        device.move_to({axis: mid})

    def test_backlash_approaches_from_one_side(self, device):
        axis, lo, hi = self._axis(device)
        b = 0.02 * (hi - lo)
        device.backlash = {axis: b}
        low_t, high_t = lo + 0.3 * (hi - lo), lo + 0.6 * (hi - lo)
        device.move_to({axis: high_t})  # moving up: same direction as b > 0, direct
        assert len(device.last_path) == 1
        device.move_to({axis: low_t})  # moving down: overshoot to low_t - b, then up
        path = device.last_path
        assert [leg[axis] for leg in path] == pytest.approx([low_t - b, low_t])
        assert device.position(axis) == pytest.approx(low_t, abs=self.position_tolerance)
        device.backlash = {axis: 0.0}
        device.move_to({axis: lo + 0.1 * (hi - lo)})
        assert len(device.last_path) == 1

    def test_backlash_overshoot_must_be_within_limits(self, device):
        axis, lo, hi = self._axis(device)
        device.move_to({axis: lo + 0.5 * (hi - lo)})
        device.backlash = {axis: 0.1 * (hi - lo)}
        before = device.positions()
        with pytest.raises(StageLimitError, match="overshoot"):
            device.move_to({axis: lo + 0.05 * (hi - lo)})
        assert device.positions() == before and not device.is_moving()
