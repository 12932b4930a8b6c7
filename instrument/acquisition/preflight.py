"""Preflight: a plan's steps checked against the bench before the first move.

Every stage target (backlash overshoot included, followed along the sequence from
the stages' current positions), fixed exposure and LED step of the points a run or
resume will execute is checked with the devices' own validation
(:meth:`drivers.stage.Stage.path_to`, :meth:`drivers.base.Device.check_settings`),
so a plan that cannot finish is refused naming its point before anything moves,
rather than failing at its last point.
"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.errors import DeviceError

from ..devices.bench import Bench
from .plan import Expose, Light, Move, Plan, PlanError

__all__ = ["preflight"]


def preflight(bench: Bench, plan: Plan, points: Sequence, indices: Sequence[int]) -> None:
    """Check the steps of ``points[indices]`` (and of setup and teardown) against the
    devices of ``bench`` (:meth:`~instrument.acquisition.plan.Plan.checked_steps`): stage targets
    against the stage limits, fixed exposures against the camera, LED indices and
    brightness against the LED array.

    Raises
    ------
    PlanError
        A step the device would refuse (a target or overshoot point outside a
        stage's limits, an exposure out of range, an LED the array lacks, an unknown
        device or axis): the point, its coordinates and the device's message.
    """
    positions: dict[str, dict[str, float]] = {}
    for index, step in plan.checked_steps(points, indices):
        try:
            if isinstance(step, Move):
                stage = bench.device(step.stage)
                start = positions.get(stage.device_id) or stage.positions()
                path = stage.path_to(dict(step.targets), start)
                positions[stage.device_id] = {**start, **path[-1]}
            elif isinstance(step, Expose) and step.exposure_s is not None:
                bench.camera.check_settings({"exposure_s": step.exposure_s})
            elif isinstance(step, Light):
                _check_light(bench, step)
        except (DeviceError, LookupError, PlanError) as exc:
            where = ("setup/teardown" if index is None else
                     f"point {index + 1} of {len(points)} {dict(points[index].coords)}")
            raise PlanError(f"plan {plan.name!r} cannot run: {where}: {exc}; nothing moved - "
                            "change the plan's parameters or the device limits") from None


def _check_light(bench: Bench, step: Light) -> None:
    leds = bench.device(step.device)
    if not 0 <= step.brightness <= 1:
        raise PlanError(f"{leds.device_id}: brightness {step.brightness} is outside [0, 1]")
    if isinstance(step.leds, str):
        return  # "all" (anything else is refused by the step itself)
    bad = [i for i in step.leds if not 0 <= i < leds.n_leds]
    if bad:
        raise PlanError(f"{leds.device_id}: LED(s) {bad} outside 0-{leds.n_leds - 1}")
