"""The SLM phase-LUT run's analysis and products, loading a LUT onto an SLM, and a
check of a LUT on the bench (a blazed grating's first-order efficiency).

This module owns the run's reduction (:func:`analyze`, :func:`reference_level`,
:func:`reduce_run`); the plan, :mod:`calibration_routines.slm_lut`, imports it from
here and this module never imports the plan.

Load and apply a calibrated LUT in a later session::

    from calibration_routines.slm_lut_io import apply_lut, load_lut
    lut = apply_lut(bench.slm, "out/runs/slm-lut.zarr")   # checks the wavelength
    lut.lut_rad, lut.wavelength_nm, lut.attrs["reference_gray"]
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from diffuserlab.errors import InputError
from instrument.acquisition.exposure import autoexpose, average_frames
from instrument.acquisition.plan import CheckFailed, PlanError
from instrument.runs.runstore import RunStore

from . import slm_lut_analysis as ana

__all__ = ["SlmLut", "analyze", "apply_lut", "blazed_efficiency", "load_lut", "reduce_run",
           "reference_level"]

log = logging.getLogger(__name__)

#: Columns of the ``slm_phase_measured`` product.
MEASURED_COLUMNS = ["gray", "phase_rad", "weight", "phase_pass1_rad", "phase_pass2_rad",
                    "fraction_pass1", "fraction_pass2", "lut_rad"]
#: Relative change of the uniform pattern's zero order over the run that is warned of.
DRIFT_WARNING = 0.05


def _point_mean(store, index: int, tag: str) -> tuple[np.ndarray, float]:
    frames, coords = store.point_frames(index, tag)
    sat = [c["saturated_pixels"] for c in coords]
    exposures = {c["exposure_s"] for c in coords}
    if any(sat):
        raise PlanError(f"point {index} ({tag}) has {int(max(sat))} saturated pixels at "
                        f"{coords[0]['exposure_s']:.3g} s; lower the light (ND filter) or the "
                        "exposure bounds' minimum, then rerun")
    if len(exposures) != 1:
        raise PlanError(f"point {index}: frames with exposures {sorted(exposures)}; rerun it")
    return frames.astype(np.float64).mean(axis=0), exposures.pop()


def analyze(plan, store, passes: int = 2) -> dict:
    """Phases of the measured levels from a run's frames (pass 1 only, or both).

    Parameters
    ----------
    plan : calibration_routines.slm_lut.SlmLutPlan
    store : instrument.runs.runstore.RunStore
        Holding at least the points the passes need.
    passes : {1, 2}

    Returns
    -------
    dict
        ``gray`` (n,), ``phase`` (n, rad), ``weight`` (n,), ``detail`` (see
        :func:`~calibration_routines.slm_lut_analysis.combine_passes`),
        ``fraction`` (n, 2; NaN where not measured), ``beta``, ``drift``,
        ``zero_order_px``, ``order_offset_px``, ``orders``, ``reference_gray``.

    Raises
    ------
    PlanError
        Saturated frames, orders not found, no diffraction.
    """
    p = plan.params
    n = plan.n
    window, ring = p["window_px"], p["ring_px"]
    uniform = plan.uniform_points()[:passes + 1]
    gratings = {1: list(range(1, n)), 2: list(range(n + 1, 2 * n + 1))}
    used = sorted(uniform + gratings[1] + (gratings[2] if passes == 2 else []))
    means, exposure = {}, {}
    for i in used:
        means[i], exposure[i] = _point_mean(store, i, "uniform" if i in uniform else "grating")
    zero, _ = ana.spot_centroid(means[0], window)
    diff_map = np.zeros_like(means[0])
    for i in gratings[1]:
        f = means[i] - np.median(means[i])
        diff_map += f / max(float(f.max()), 1e-12)
    offset = ana.find_order_offset(diff_map, zero, window, ring)
    orders = ana.visible_orders(means[0].shape, zero, offset, p["max_order"],
                                window // 2 + ring)
    energy = {i: ana.order_energies(means[i], zero, offset, [0, *orders], window, ring)
              / exposure[i] for i in used}
    e0 = np.array([energy[i][0] for i in used])
    ed = np.array([energy[i][1:].sum() for i in used])
    e0u = np.interp(used, uniform, [energy[i][0] for i in uniform])
    is_grating = np.array([i not in uniform for i in used])
    beta = ana.diffracted_share(e0[is_grating], ed[is_grating], e0u[is_grating])
    frac = dict(zip(used, e0 / np.maximum(e0 + ed, 1e-300), strict=True))
    fraction = np.full((n, 2), np.nan)
    fraction[0, 0] = frac[0]
    fraction[1:, 0] = [frac[i] for i in gratings[1]]
    m1 = ana.folded_phase(fraction[:, 0], beta)
    m1[0] = 0.0
    ref = None
    if passes == 1:
        phase, weight, detail = ana.combine_passes(plan.levels, m1)
    else:
        ref = store.attrs.get("slm_lut_reference_gray")
        if ref is None:
            ref = reference_level(plan, store)
        fraction[:, 1] = [frac[i] for i in gratings[2]]
        m2 = ana.folded_phase(fraction[:, 1], beta)
        ref_index = int(np.flatnonzero(plan.levels == ref)[0])
        phase, weight, detail = ana.combine_passes(plan.levels, m1, m2, ref_index)
    e_uni = [energy[i][0] for i in uniform]
    return {"gray": plan.levels.copy(), "phase": phase, "weight": weight, "detail": detail,
            "fraction": fraction, "beta": beta, "drift": max(e_uni) / min(e_uni) - 1.0,
            "zero_order_px": list(zero), "order_offset_px": list(offset), "orders": orders,
            "reference_gray": None if ref is None else int(ref)}


def reference_level(plan, store) -> int:
    """Pass 2's reference gray: the measured level whose pass-1 phase is nearest pi/2.

    Parameters
    ----------
    plan : calibration_routines.slm_lut.SlmLutPlan
    store : instrument.runs.runstore.RunStore
        Holding at least the pass-1 points.

    Returns
    -------
    int
        A gray level of ``plan.levels``.

    Raises
    ------
    instrument.acquisition.plan.CheckFailed
        The response never reaches pi/2 (or the pass-1 data cannot be analysed).
    """
    try:
        res = analyze(plan, store, passes=1)
    except PlanError as exc:
        raise CheckFailed(f"pass 1 cannot be analysed: {exc}",
                          "fix the cause, then resume the run") from exc
    phase = res["phase"]
    if phase.max() < 0.5 * np.pi:
        raise CheckFailed(
            f"the SLM's phase reaches only {phase.max():.2f} rad at gray 255 "
            f"({plan.params['wavelength_nm']:g} nm), below pi/2",
            "check the polarisation (along the liquid-crystal axis) and the wavelength")
    i = 1 + int(np.argmin(np.abs(phase[1:] - 0.5 * np.pi)))
    return int(plan.levels[i])


def reduce_run(plan, store) -> dict:
    """Analyse a complete run, write the ``slm_lut`` and ``slm_phase_measured``
    products and return the summary (see
    :meth:`SlmLutPlan.reduce <calibration_routines.slm_lut.SlmLutPlan.reduce>`)."""
    p = plan.params
    res = analyze(plan, store, passes=2)
    gray, detail = res["gray"], res["detail"]
    lut = ana.fit_lut(gray, res["phase"], res["weight"])
    fit_rms = float(np.sqrt(np.average((lut[gray] - res["phase"]) ** 2, weights=res["weight"]
                                       + 1e-12)))
    above = np.flatnonzero(lut >= 2 * np.pi)
    summary = {
        "wavelength_nm": p["wavelength_nm"], "slm_id": p["slm_id"], "n_levels": plan.n,
        "reference_gray": res["reference_gray"], "beta": res["beta"],
        "drift": float(res["drift"]),
        "stroke_rad": float(lut[-1]), "gray_at_2pi": int(above[0]) if above.size else None,
        "passes_rms_rad": detail["rms_rad"], "fit_rms_rad": fit_rms,
        "zero_order_px": res["zero_order_px"], "order_offset_px": res["order_offset_px"],
        "orders": res["orders"], "period_px": p["period_px"], "window_px": p["window_px"],
        "ring_px": p["ring_px"], "exposure_bounds_s": p["exposure_bounds_s"]}
    table = np.column_stack([gray, res["phase"], res["weight"], detail["x1"], detail["x2"],
                             res["fraction"][:, 0], res["fraction"][:, 1], lut[gray]])
    store.write_product("slm_phase_measured", table.astype(np.float64),
                        columns=MEASURED_COLUMNS, units="rad (phases), 1 (fractions)",
                        processing="zero-order fraction of binary gratings (0|g) and "
                        "(g_ref|g), folded phase 2 arccos(sqrt(C)), pass 1 unfolded by "
                        "monotonicity, passes combined by weighted least squares",
                        **summary)
    store.write_product("slm_lut", lut.astype(np.float64), units="rad",
                        meaning="phase delay of gray levels 0..255 relative to gray 0 at "
                        "wavelength_nm; set as the SLM's lut_rad (apply_lut)", **summary)
    if summary["drift"] > DRIFT_WARNING:
        store.add_warning(f"the uniform pattern's zero order changed by "
                          f"{summary['drift']:.1%} during the run (laser drift?)")
    return summary


@dataclass(frozen=True)
class SlmLut:
    """A calibrated LUT: ``lut_rad`` (float64 (256,), rad), the ``wavelength_nm`` it
    holds for, the ``slm_id`` it was measured on, its ``source`` (run store path) and
    the product's ``attrs``."""

    lut_rad: np.ndarray = field(repr=False)
    wavelength_nm: float
    slm_id: str
    source: str
    attrs: dict = field(repr=False)


def load_lut(source) -> SlmLut:
    """The ``slm_lut`` product of an SLM phase-LUT run.

    Parameters
    ----------
    source : str, pathlib.Path or instrument.runs.runstore.RunStore
        The run store (``RUN.zarr``).

    Raises
    ------
    instrument.runs.runstore.RunStoreError
        No run there, or the run has no ``slm_lut`` product (incomplete: resume it).
    """
    store = source if isinstance(source, RunStore) else RunStore.open(Path(source))
    lut, attrs = store.product("slm_lut")
    return SlmLut(np.asarray(lut, np.float64), float(attrs["wavelength_nm"]),
                  str(attrs["slm_id"]), str(store.path), attrs)


def apply_lut(slm, source, *, tolerance_nm: float = 1.0) -> SlmLut:
    """Set ``slm.lut_rad`` to a calibrated LUT (from :func:`load_lut` or a run store).

    Raises
    ------
    diffuserlab.errors.InputError
        The LUT was measured at a wavelength more than ``tolerance_nm`` from the SLM's
        ``wavelength_nm`` (calibrate at that wavelength, or pass a larger tolerance).
    drivers.errors.DeviceValueError
        The SLM refuses the LUT.
    """
    lut = source if isinstance(source, SlmLut) else load_lut(source)
    if abs(lut.wavelength_nm - slm.wavelength_nm) > tolerance_nm:
        raise InputError(f"the LUT in {lut.source} is for {lut.wavelength_nm:g} nm but the SLM "
                         f"{slm.device_id!r} runs at {slm.wavelength_nm:g} nm; calibrate at "
                         "that wavelength (diffuserlab calibrate slm-lut) or raise tolerance_nm")
    slm.lut_rad = lut.lut_rad
    log.info("%s: LUT from %s applied (%g nm, stroke %.2f rad)", slm.device_id, lut.source,
             lut.wavelength_nm, float(lut.lut_rad[-1]))
    return lut


def blazed_efficiency(bench, lut: SlmLut, *, frames: int = 4, timeout_s: float = 10.0) -> float:
    """First-order efficiency of a blazed grating shown through the SLM's current LUT.

    The phase ramp ``2 pi (col mod P) / P`` (``P`` the calibration's grating period)
    is shown with :meth:`drivers.slm.Slm.show_phase`; the frame is auto-exposed
    (half of full scale for a small spot) and averaged over ``frames``; the result
    is the larger first order's window energy over the energy of all orders
    ``|m| <= max(orders)`` at the calibration's order positions. Run it inside
    :func:`~calibration_routines.holo_bench.far_field_setup` (mask out of the beam).

    Returns
    -------
    float
        Efficiency in [0, 1] (about 0.95 for an ideal 8-level ramp).
    """
    a = lut.attrs
    slm = bench.slm
    rows, cols = slm.resolution
    period = int(a["period_px"])
    ramp = 2 * math.pi * (np.arange(cols) % period) / period
    slm.show_phase(np.broadcast_to(ramp, (rows, cols)), timeout_s=timeout_s)
    cam = bench.camera
    lo, hi = a["exposure_bounds_s"]
    autoexpose(cam, target=0.6, tolerance=0.2, bounds_s=(lo, hi), timeout_s=timeout_s)
    cam.exposure_s = max(cam.exposure_s * 0.5, lo)
    mean, _ = average_frames(cam, frames, timeout_s=timeout_s)
    orders = sorted({0, *(int(m) for m in a["orders"])})
    e = np.clip(ana.order_energies(mean, a["zero_order_px"], a["order_offset_px"], orders,
                                   int(a["window_px"]), int(a["ring_px"])), 0.0, None)
    return float(max(e[orders.index(-1)], e[orders.index(1)]) / e.sum())
