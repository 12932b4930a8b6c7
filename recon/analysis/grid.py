"""Reconstruction-grid recommendation: depth planes and lateral binning from a PSF stack.

Following G. Kuo, *Exploiting Randomness in Computational Cameras and Displays*
(PhD dissertation, UC Berkeley, 2020), Sec. 4.4 ("we set the voxel spacing in our
grid to Nyquist sample the 3D two-point resolution", Fig. 4.3d; Eq. 4.7) with the
inner-product predictor of Sec. 6.4 (threshold 0.8) as the measured resolution.

:func:`recommend_grid` is the first place the project "models no more than a scene
needs": the planes Nyquist-sample the measured axial resolution only over the depths
the scene occupies, and the binning is as coarse as the measured lateral resolution
allows. The returned :class:`GridRecommendation` says what it chose and why.

Depths ``z`` are object-to-diffuser distances, ``d`` the diffuser-to-sensor
distance, in mm. Every refusal raises :class:`recon.errors.ReconInputError` whose
message says what is wrong and how to fix it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recon.analysis.resolution import (
    INNER_PRODUCT_THRESHOLD,
    RESOLUTION_LEVEL,
    check_level,
    crossing_lag,
)
from recon.analysis.sampling import inverse_depth_step_per_mm, inverse_depths
from recon.analysis.similarity import check_stack
from recon.errors import ReconInputError
from recon.validate import float_array, positive

__all__ = ["GridRecommendation", "recommend_grid"]

#: Samples per resolution width (Nyquist), laterally and axially.
SAMPLES_PER_RESOLUTION = 2


@dataclass(frozen=True)
class GridRecommendation:
    """Result of :func:`recommend_grid`.

    Attributes
    ----------
    depths_mm : numpy.ndarray
        float64 (n_planes,), ascending: the recommended reconstruction planes, mm,
        with a constant 1/z step (the last step may be shorter, to end on the range).
    inverse_depth_step_per_mm : float
        The 1/z spacing of the planes, 1/mm: half of `resolvable_step_per_mm`.
    resolvable_step_per_mm : float
        ``c`` of Eq. 4.7, 1/mm: the finest 1/z step at which a calibrated PSF becomes
        distinguishable (inner product with its scaled copy at the threshold).
    step_per_psf_per_mm : numpy.ndarray
        float64 (n_psfs,): that step for each calibrated PSF, in the order of the
        sorted calibration depths.
    lateral_bin : int
        Sensor pixels per reconstruction pixel along each axis (>= 1).
    lateral_resolution_px : float
        The finest measured lateral resolution on the sensor (px): the shift at
        which a PSF's inner product with its shifted copy falls to the threshold,
        minimum over x, y and all PSFs.
    lateral_resolution_70_px : float
        The Sec. 3.2 figure for comparison: finest autocorrelation half width at
        70 % of the peak (px).
    voxel_size_mm : numpy.ndarray
        float64 (n_planes,): object-space size of one binned pixel at each plane,
        ``lateral_bin * pitch * z / d`` (mm).
    psf_indices : numpy.ndarray
        int (n_planes,): index into the caller's stack of the calibrated PSF
        nearest to each plane in 1/z.
    calibrated_range_mm : tuple of float
        Nearest and farthest calibrated depth, mm.
    span_mm : tuple of float
        The depth span the planes cover, mm (the calibrated range, or the scene
        range clipped to it).
    reasons : tuple of str
        What was chosen and why, with the numbers, one line each.
    """

    depths_mm: np.ndarray
    inverse_depth_step_per_mm: float
    resolvable_step_per_mm: float
    step_per_psf_per_mm: np.ndarray
    lateral_bin: int
    lateral_resolution_px: float
    lateral_resolution_70_px: float
    voxel_size_mm: np.ndarray
    psf_indices: np.ndarray
    calibrated_range_mm: tuple[float, float]
    span_mm: tuple[float, float]
    reasons: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (arrays as lists of float / int)."""
        return {
            "depths_mm": [float(v) for v in self.depths_mm],
            "inverse_depth_step_per_mm": self.inverse_depth_step_per_mm,
            "resolvable_step_per_mm": self.resolvable_step_per_mm,
            "step_per_psf_per_mm": [float(v) for v in self.step_per_psf_per_mm],
            "lateral_bin": self.lateral_bin,
            "lateral_resolution_px": self.lateral_resolution_px,
            "lateral_resolution_70_px": self.lateral_resolution_70_px,
            "voxel_size_mm": [float(v) for v in self.voxel_size_mm],
            "psf_indices": [int(v) for v in self.psf_indices],
            "calibrated_range_mm": list(self.calibrated_range_mm),
            "span_mm": list(self.span_mm),
            "reasons": list(self.reasons),
        }


def _scene_span(scene: Any, z_lo: float, z_hi: float, reasons: list[str]) -> tuple[float, float]:
    rng = float_array(scene, "scene_depth_range_mm", ndims=(1,))
    if rng.size != 2 or not 0 < rng[0] <= rng[1]:
        raise ReconInputError(
            f"scene_depth_range_mm must be (z_near, z_far) in mm with 0 < z_near <= z_far, "
            f"got {scene!r}"
        )
    a, b = float(rng[0]), float(rng[1])
    if b < z_lo or a > z_hi:
        raise ReconInputError(
            f"the scene ({a:g}-{b:g} mm) lies outside the calibrated range "
            f"({z_lo:g}-{z_hi:g} mm); calibrate PSFs over the scene's depths"
        )
    lo, hi = max(a, z_lo), min(b, z_hi)
    if (lo, hi) != (a, b):
        reasons.append(
            f"the scene ({a:g}-{b:g} mm) extends beyond the calibrated range "
            f"({z_lo:g}-{z_hi:g} mm); planes cover only {lo:g}-{hi:g} mm -- calibrate further "
            "to reconstruct the rest"
        )
    return lo, hi


def recommend_grid(
    psf_stack: Any,
    depths_mm: Any,
    *,
    pitch_mm: float,
    d_mm: float,
    threshold: float = INNER_PRODUCT_THRESHOLD,
    scene_depth_range_mm: Any | None = None,
) -> GridRecommendation:
    """Depth planes and lateral binning that Nyquist-sample the measured resolution.

    Parameters
    ----------
    psf_stack : array_like
        Shape (n, rows, cols), n >= 1, on-axis PSFs (background removed, centred on
        the array), one per calibrated depth; real, finite, none all zero.
    depths_mm : array_like
        Shape (n,): the object-to-diffuser distance of each PSF in mm (> 0, distinct;
        any order).
    pitch_mm : float
        Sensor pixel pitch in mm (> 0), unbinned.
    d_mm : float
        Diffuser-to-sensor distance in mm (> 0).
    threshold : float, optional
        Normalised inner product below which two points are distinguishable, in
        (0, 1). Default 0.8 (Sec. 6.4).
    scene_depth_range_mm : (float, float), optional
        ``(z_near, z_far)`` in mm the scene occupies. Only planes in that span
        (clipped to the calibrated range) are kept; default the calibrated range.

    Returns
    -------
    GridRecommendation
        The planes, the binning, the measurements behind them and the reasons.

    Raises
    ------
    ReconInputError
        If the stack or depths are invalid, `pitch_mm` / `d_mm` are not positive,
        `threshold` is not in (0, 1), a PSF's similarity never falls to the
        threshold (under scaling up to 2x or under shifts inside the frame), or the
        scene range lies outside the calibrated range.

    Notes
    -----
    Axial: for each PSF ``c_k`` =
    :func:`~recon.analysis.sampling.inverse_depth_step_per_mm` (the 1/z step of
    Eq. 4.7 at which the PSF's inner product with its scaled copy falls to
    `threshold`); two-point axial resolution is the finest, ``c = min_k c_k``, and
    Nyquist sampling puts planes ``c / 2`` apart in 1/z
    (:func:`~recon.analysis.sampling.inverse_depths` with ``c_per_mm = c / 2``)
    from the near to the far end of the span. A span thinner than that gives its
    two ends (one plane if ``z_near == z_far``).

    Lateral: for each PSF the shift at which its inner product with its shifted
    copy falls to `threshold`
    (:func:`~recon.analysis.resolution.lateral_inner_product_resolution_px`) along
    x and y; with ``r`` the finest, the bin is the largest integer ``b`` with
    ``b <= r / 2`` (2 binned pixels per resolution width), at least 1. The lateral
    resolution in object space, ``r pitch z / d``, grows with depth; the sensor-plane
    value sets one bin for all planes. All measurements use every calibrated PSF,
    so the spacing does not depend on the scene; the scene only selects the span.
    """
    stack = check_stack(psf_stack, "psf_stack")
    n = stack.shape[0]
    z = float_array(depths_mm, "depths_mm", ndims=(1,))
    if z.size != n:
        raise ReconInputError(
            f"depths_mm has {z.size} values but psf_stack holds {n} PSFs; pass one depth per PSF"
        )
    if np.any(z <= 0) or np.unique(z).size != n:
        raise ReconInputError(
            "depths_mm must be positive and distinct (object-to-diffuser distances in mm)"
        )
    pitch = positive(pitch_mm, "pitch_mm", unit=" mm")
    d = positive(d_mm, "d_mm", unit=" mm")
    thr = check_level(threshold, "threshold")

    order = np.argsort(z)
    zs = z[order]
    z_lo, z_hi = float(zs[0]), float(zs[-1])
    reasons = [
        f"calibrated range {z_lo:g}-{z_hi:g} mm ({n} PSF(s)); d = {d:g} mm, "
        f"pixel pitch {pitch * 1e3:g} um; distinguishable when the normalised inner product "
        f"falls to {thr:g} (Sec. 6.4)"
    ]

    # ----------------------------------------------------------------- axial
    steps = np.array(
        [inverse_depth_step_per_mm(stack[i], d, float(z[i]), thr) for i in order],
        dtype=np.float64,
    )
    k_min = int(np.argmin(steps))
    c = float(steps[k_min])
    spacing = c / SAMPLES_PER_RESOLUTION
    reasons.append(
        f"axial: a PSF becomes distinguishable from its scaled copy after a 1/z step of "
        f"{steps.min():.4g}-{steps.max():.4g} 1/mm across the stack (Eq. 4.7); the finest, "
        f"c = {c:.4g} 1/mm at z = {zs[k_min]:g} mm, sets the planes {spacing:.4g} 1/mm apart "
        f"in 1/z ({SAMPLES_PER_RESOLUTION} planes per resolvable step, Nyquist)"
    )

    if scene_depth_range_mm is None:
        lo, hi = z_lo, z_hi
    else:
        lo, hi = _scene_span(scene_depth_range_mm, z_lo, z_hi, reasons)
    full = 1 if z_lo == z_hi else inverse_depths(z_lo, z_hi, c_per_mm=spacing).size
    planes = np.array([lo]) if lo == hi else inverse_depths(lo, hi, c_per_mm=spacing)
    if scene_depth_range_mm is None:
        reasons.append(
            f"{planes.size} plane(s) from {lo:g} to {hi:g} mm (the calibrated range; pass "
            "scene_depth_range_mm to keep only the depths a scene occupies)"
        )
    else:
        reasons.append(
            f"the scene spans {lo:g}-{hi:g} mm: {planes.size} plane(s) kept of the {full} the "
            "calibrated range would need (model no more than the scene needs)"
        )

    # ----------------------------------------------------------------- calibration
    inv_cal = 1.0 / zs
    psf_sorted = np.argmin(np.abs(inv_cal[None, :] - 1.0 / planes[:, None]), axis=1)
    psf_indices = order[psf_sorted]
    if n > 1:
        cal_step = float(np.max(-np.diff(inv_cal)))
        if cal_step > spacing * (1.0 + 1e-9):
            reasons.append(
                f"calibration: the stack's largest 1/z gap ({cal_step:.4g} 1/mm) is wider "
                f"than the plane spacing; planes between calibrated depths need PSFs "
                "interpolated (scaled) from their neighbours, or calibrate more densely"
            )
        else:
            reasons.append(
                f"calibration: the stack's largest 1/z gap ({cal_step:.4g} 1/mm) is within "
                "the plane spacing; each plane can use its nearest calibrated PSF "
                "(psf_indices)"
            )

    # ----------------------------------------------------------------- lateral
    res = np.array([[crossing_lag(stack[i], axis, thr) for axis in (1, 0)] for i in order])
    res70 = np.array([[crossing_lag(stack[i], axis, RESOLUTION_LEVEL) for axis in (1, 0)]
                      for i in order])
    k_res, ax = np.unravel_index(int(np.argmin(res)), res.shape)
    r = float(res[k_res, ax])
    bin_factor = max(1, math.floor(r / SAMPLES_PER_RESOLUTION + 1e-9))
    reasons.append(
        f"lateral: the finest resolution is {r:.3g} px on the sensor (shift at which the inner "
        f"product with the shifted PSF falls to {thr:g}, along {'xy'[ax]} at z = "
        f"{zs[k_res]:g} mm; the 70 % autocorrelation half width is {float(res70.min()):.3g} px); "
        + (
            f"{SAMPLES_PER_RESOLUTION} samples per resolution width allow a bin of {bin_factor} "
            f"({bin_factor} px <= {r / SAMPLES_PER_RESOLUTION:.3g} px)"
            if r >= SAMPLES_PER_RESOLUTION
            else f"even unbinned pixels give fewer than {SAMPLES_PER_RESOLUTION} samples per "
            "resolution width, so no binning (bin 1); the sensor, not the grid, limits the "
            "lateral sampling"
        )
    )
    voxel = bin_factor * pitch * planes / d
    reasons.append(
        f"binned pixel in object space: {voxel[0] * 1e3:.3g} um at {planes[0]:g} mm to "
        f"{voxel[-1] * 1e3:.3g} um at {planes[-1]:g} mm (bin * pitch * z / d)"
    )
    return GridRecommendation(
        depths_mm=planes,
        inverse_depth_step_per_mm=spacing,
        resolvable_step_per_mm=c,
        step_per_psf_per_mm=steps,
        lateral_bin=int(bin_factor),
        lateral_resolution_px=r,
        lateral_resolution_70_px=float(res70.min()),
        voxel_size_mm=voxel,
        psf_indices=psf_indices,
        calibrated_range_mm=(z_lo, z_hi),
        span_mm=(lo, hi),
        reasons=tuple(reasons),
    )
