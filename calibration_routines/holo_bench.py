"""Holography-bench set-ups shared by the SLM and mask routines.

* :func:`retracted_mask`: the scattering mask out of the beam (moved by its 6-axis
  stage until the SLM footprint sees clear substrate) for the duration of a ``with``
  block, and back at the pose it had on entry afterwards, whatever happens inside.
* :func:`holography_branch`: on the virtual bench, route the camera to the
  holography path (a real bench's camera simply looks where it looks).
* :func:`far_field_setup`: both, plus an ND filter in front of the camera (asked of
  the operator): without the mask, the zero order or a grating order carries most of
  the beam on a few camera pixels.

Geometry of the retraction: the SLM footprint on the mask plane is ``resolution x
pixel_pitch_um`` (the relay images the SLM 1:1 onto the mask, as the mask model
assumes); the mask pattern overhangs the footprint by ``overhang_mm`` on each side,
so a shift of ``footprint + overhang_mm + clearance_mm`` along ``axis`` leaves the
footprint on clear substrate (on the virtual bench the pattern's margin is 16 mask
pixels = 0.032 mm). The shift goes towards +``axis`` when the stage limits allow it,
otherwise towards -``axis``.

Example
-------
>>> from calibration_routines.holo_bench import retracted_mask
>>> with retracted_mask(bench) as out:          # doctest: +SKIP
...     ...                                     # the SLM's far field, no scattering
>>> out.home_pose == bench.mask_stage.positions()   # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass

from drivers.errors import DeviceError
from instrument.acquisition.plan import PlanError
from instrument.devices.bench import BenchRoleError, PromptRefused
from instrument.devices.virtual_bench import VirtualBench

__all__ = ["Retraction", "far_field_setup", "holography_branch", "retract_distance_mm",
           "retracted_mask"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Retraction:
    """Where :func:`retracted_mask` took the mask.

    Attributes
    ----------
    stage_id : str
        Device id of the mask stage.
    axis : str
        Axis moved (``"x"`` or ``"y"``).
    shift_mm : float
        Signed shift along ``axis``, mm.
    home_pose : dict[str, float]
        Every axis's position on entry (mm or deg), restored on exit.
    retracted_pose : dict[str, float]
        The commanded pose while retracted.
    """

    stage_id: str
    axis: str
    shift_mm: float
    home_pose: dict
    retracted_pose: dict


def retract_distance_mm(bench, axis: str = "x", *, overhang_mm: float = 0.1,
                        clearance_mm: float = 0.25) -> float:
    """Shift (mm) that takes the mask pattern off the SLM footprint along ``axis``.

    ``footprint + overhang_mm + clearance_mm`` with the footprint ``cols x pitch``
    (``axis="x"``) or ``rows x pitch`` (``"y"``) of ``bench.slm``.

    Raises
    ------
    PlanError
        ``axis`` not x or y, or a negative overhang or clearance.
    """
    if axis not in ("x", "y"):
        raise PlanError(f"axis={axis!r}: retract the mask along 'x' or 'y'")
    if not (overhang_mm >= 0 and clearance_mm >= 0):
        raise PlanError(f"overhang_mm={overhang_mm!r}, clearance_mm={clearance_mm!r}: "
                        "give non-negative distances in mm")
    slm = bench.slm
    rows, cols = slm.resolution
    footprint_mm = (cols if axis == "x" else rows) * slm.pixel_pitch_um * 1e-3
    return footprint_mm + float(overhang_mm) + float(clearance_mm)


@contextlib.contextmanager
def retracted_mask(bench, *, axis: str = "x", distance_mm: float | None = None,
                   stage: str = "mask_stage", overhang_mm: float = 0.1,
                   clearance_mm: float = 0.25, timeout_s: float = 60.0) -> Iterator[Retraction]:
    """Context manager: the mask out of the beam inside the block, back on exit.

    On entry the mask stage's pose is recorded and the stage moves by ``distance_mm``
    (default :func:`retract_distance_mm`) along ``axis``. On exit, normal or by any
    exception (including Ctrl-C and errors of the retraction itself), the stage moves
    back to the recorded pose (every axis). If that return fails while an exception
    is propagating, the original exception propagates with a note saying where the
    mask is and where it belongs; after a clean block the stage error is raised.

    Parameters
    ----------
    bench : instrument.devices.bench.Bench
        Open bench with an SLM and a mask stage.
    axis : {"x", "y"}
        Lateral axis to retract along.
    distance_mm : float, optional
        Shift in mm (> 0); the sign is chosen to stay within the stage limits.
    stage : str
        Device id or role of the mask stage.
    overhang_mm, clearance_mm : float
        Mask pattern beyond the SLM footprint and extra margin, mm (default shift).
    timeout_s : float
        Longest wait for each stage move, s.

    Yields
    ------
    Retraction

    Raises
    ------
    PlanError
        No such stage, bad ``axis`` or ``distance_mm``, or no shift of that size fits
        the stage limits on either side (the message says how far the stage reaches).
    drivers.errors.DeviceError
        A stage move failed or timed out.
    """
    try:
        dev = bench.device(stage)
    except BenchRoleError as exc:
        raise PlanError(f"cannot retract the mask: {exc}") from exc
    if axis not in dev.axes:
        raise PlanError(f"the mask stage {dev.device_id!r} has no axis {axis!r} "
                        f"(axes {list(dev.axes)}); retract along 'x' or 'y'")
    if distance_mm is None:
        distance_mm = retract_distance_mm(bench, axis, overhang_mm=overhang_mm,
                                          clearance_mm=clearance_mm)
    if not (math.isfinite(distance_mm) and distance_mm > 0):
        raise PlanError(f"distance_mm={distance_mm!r}: give a retraction distance > 0 mm")
    home = dev.positions()
    lo, hi = dev.limits[axis]
    if home[axis] + distance_mm <= hi:
        shift = float(distance_mm)
    elif home[axis] - distance_mm >= lo:
        shift = -float(distance_mm)
    else:
        raise PlanError(
            f"the mask stage cannot retract {distance_mm:.3g} mm along {axis} from "
            f"{home[axis]:.3g} mm within its limits [{lo:g}, {hi:g}] mm; retract along the "
            "other axis, bring the stage nearer one end, or give a smaller distance_mm")
    target = {axis: home[axis] + shift}
    log.info("retracting the mask: %s %s %+.3f mm (from %s)", dev.device_id, axis, shift, home)
    try:
        dev.move_to(target, timeout_s=timeout_s)
        yield Retraction(dev.device_id, axis, shift, dict(home), {**home, **target})
    except BaseException as exc:
        try:
            dev.move_to(home, timeout_s=timeout_s)
        except DeviceError as again:
            text = (f"the mask stage {dev.device_id!r} could not return to {home} "
                    f"({again}); move it back by hand")
            log.error(text)
            exc.add_note(text)
        raise
    dev.move_to(home, timeout_s=timeout_s)
    log.info("mask back at %s", home)


@contextlib.contextmanager
def holography_branch(bench) -> Iterator[None]:
    """Context manager: on a :class:`~instrument.devices.virtual_bench.VirtualBench`, the
    camera sees the holography path inside the block and the previous branch
    afterwards; on a real bench it does nothing (the camera looks where it is set up
    to look)."""
    if not isinstance(bench, VirtualBench):
        yield
        return
    before = bench.branch
    bench.set_branch("holography")
    try:
        yield
    finally:
        bench.set_branch(before)


@contextlib.contextmanager
def far_field_setup(bench, *, attenuate: bool = True, **retract) -> Iterator[Retraction]:
    """Context manager for measuring the SLM's own far field: the holography branch,
    an ND filter in front of the camera (``attenuate``; the operator is asked, the
    virtual bench inserts its own) and the mask retracted (``retract``: keyword
    arguments of :func:`retracted_mask`). Left in reverse order; the request to remove
    the ND filter on exit is best effort (a refusal is logged, not raised).

    Yields
    ------
    Retraction

    Raises
    ------
    instrument.devices.bench.PromptRefused
        The operator did not insert the ND filter.
    PlanError, drivers.errors.DeviceError
        As :func:`retracted_mask`.
    """
    with contextlib.ExitStack() as stack:
        stack.enter_context(holography_branch(bench))
        if attenuate:
            bench.prompt("insert_nd_filter", "Put an ND filter (about OD 2) in front of the "
                         "camera: without the mask the SLM's zero order concentrates the beam "
                         "on a few pixels")
            stack.callback(_remove_nd_filter, bench)
        yield stack.enter_context(retracted_mask(bench, **retract))


def _remove_nd_filter(bench) -> None:
    try:
        bench.prompt("remove_nd_filter", "Remove the ND filter from in front of the camera")
    except PromptRefused as exc:
        log.warning("the ND filter may still be in front of the camera: %s", exc)
