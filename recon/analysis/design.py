"""Resolution of a microlens mask design from its simulated PSFs (Kuo 2020, Sec. 6.4, Fig. 6.4a).

Sec. 6.4: "we shift (for lateral resolution) or scale (for axial resolution) a
central PSF and calculate the inner product with the original. A low inner
product indicates that neighbouring measurements are sufficiently different to be
distinguished. For the noise levels in our system, we find that a normalized inner
product of 0.8 is a good predictor of the resolution ... This process can be used
for system design by simulating PSFs". :func:`design_resolution` does that for a
mask of :mod:`recon.optics.design_masks` (random or regular microlenses with the
user's lenslet size, focal length and distance): at each depth it ray-traces the
registered PSF at 12 field positions (a 4 x 3 grid over the object field of the
sensor patch, Fig. 6.4a's "12 different lateral locations in the FoV") and
reports per position

* the lateral resolution: the shift at which the PSF's normalised inner product
  with its shifted copy falls to the threshold
  (:func:`~recon.analysis.resolution.lateral_inner_product_resolution_px`), in
  sensor pixels and in object space (``m = d / z``);
* the axial resolution: the scale ``s*`` at which the inner product with its
  scaled copy falls to the threshold
  (:func:`~recon.analysis.resolution.axial_inner_product_scale`; the spots of a
  point at depth ``z`` are the pattern at infinity magnified by ``1 + d / z``), as
  the nearest distinguishable depth towards the mask, ``z - d / (s* (1 + d/z) - 1)``;
* the ghost inner product: the largest normalised inner product of the PSF with
  its copy shifted by more than three lateral resolutions (and at most a third of
  the patch), over the part of the patch both cover. A regular array's PSF shifted by one
  lattice period is a copy of itself (Sec. 6.3), so this is close to 1 and a
  point and its ghost one period away are confused; a random layout keeps it low.

The threshold 0.8 is the chapter's: the level at which the predicted resolution
matched the measured two-point resolution (20 % dip, Sec. 6.4) at its noise level.
"""

from __future__ import annotations

import numpy as np

from ..errors import ReconInputError
from ..optics.design_masks import MaskDesign
from ..validate import float_array
from .resolution import (
    INNER_PRODUCT_THRESHOLD,
    axial_inner_product_scale,
    check_level,
    lateral_inner_product_resolution_px,
)
from .similarity import full_xcorr

__all__ = ["FIELD_GRID", "design_resolution", "field_positions_mm"]

#: Field positions as fractions of the object field (x along columns, y along rows):
#: a 4 x 3 grid, 12 positions.
FIELD_GRID = ((-0.3, -0.1, 0.1, 0.3), (-0.25, 0.0, 0.25))


def field_positions_mm(design: MaskDesign, z_mm: float) -> np.ndarray:
    """The 12 field positions (x, y) in mm at depth ``z_mm``: :data:`FIELD_GRID` times
    the object field of the sensor patch (its size times ``z / d``).

    Returns
    -------
    ndarray, float64, shape (12, 2)
    """
    w, h = design.sensor_size_mm
    scale = z_mm / design.d_mm
    return np.array([(fx * w * scale, fy * h * scale)
                     for fy in FIELD_GRID[1] for fx in FIELD_GRID[0]], np.float64)


def _ghost(psf: np.ndarray, exclude_px: float) -> float:
    """Largest inner product of the PSF with its shifted copy over their overlap, at
    shifts beyond ``exclude_px`` and up to a third of the patch per axis (an overlap
    of at least 4/9 of it).

    ``<h, h(. + t)> / sqrt(sum_overlap h^2 . sum_overlap h(. + t)^2)``: normalised
    over the part of the patch both cover, so a lattice shift of a periodic PSF
    scores 1 however much of it leaves the patch (on an infinite sensor the shifted
    copy is the PSF itself, Sec. 6.3).
    """
    h = np.asarray(psf, np.float64)
    rows, cols = h.shape
    num = full_xcorr(h, h)
    frame = np.ones_like(h)
    sq = h * h
    den = np.sqrt(np.maximum(full_xcorr(sq, frame) * full_xcorr(frame, sq), 1e-300))
    ly = np.arange(num.shape[0])[:, None] - (rows - 1)
    lx = np.arange(num.shape[1])[None, :] - (cols - 1)
    keep = ((ly * ly + lx * lx > exclude_px * exclude_px) & (np.abs(ly) <= rows // 3)
            & (np.abs(lx) <= cols // 3))
    if not np.any(keep):
        return float("nan")
    return float(np.max(num[keep] / den[keep]))


def design_resolution(design: MaskDesign, depths_mm, *,
                      threshold: float = INNER_PRODUCT_THRESHOLD) -> dict:
    """The Sec. 6.4 inner-product predictor of a flat mask design at 12 field positions.

    Parameters
    ----------
    design : MaskDesign
        A flat mask (``"random"``, ``"regular"`` or ``"smooth"``) with its sensor
        patch (shape, pitch), distance, lenslets and wavelength.
    depths_mm : float or sequence of float
        Object depths (mm, > 0, in front of the mask).
    threshold : float
        Normalised inner product below which two points are resolvable, in (0, 1).

    Returns
    -------
    dict
        ``threshold``, ``conjugate_z_mm`` (the plane the lenslets image) and
        ``depths``: one dict per depth with ``z_mm``, ``magnification``,
        ``positions``: per field position ``x_mm``, ``y_mm``,
        ``lateral_px`` (x, y), ``lateral_um`` (x, y, object space), ``scale``
        (``s*``), ``axial_um`` and ``ghost_inner_product``; and ``summary``: the
        mean, min and max over the positions of ``lateral_um`` (mean of x and y),
        ``axial_um`` and ``ghost_inner_product``.

    Raises
    ------
    ReconInputError
        The objective (not a flat mask), bad depths or threshold, or a PSF whose
        inner product never falls to the threshold on the patch (e.g. a mask that
        focuses no light onto it).
    """
    if design.kind == "objective":
        raise ReconInputError("design_resolution analyses a flat mask (random, regular or "
                              "smooth); the objective has no mask PSF to shift")
    thr = check_level(threshold, "threshold")
    zs = np.atleast_1d(float_array(depths_mm, "depths_mm", ndims=(0, 1)))
    if zs.size == 0 or np.any(zs <= 0):
        raise ReconInputError("give depths > 0 mm in front of the mask, e.g. 2.0,2.5,3.0")
    pitch_mm = design.pitch_um * 1e-3
    d = design.d_mm
    out = []
    for z in (float(v) for v in zs):
        m = d / z
        positions = []
        for x, y in field_positions_mm(design, z):
            psf = design.psf((float(x), float(y), z), 1, registered=True)
            if not np.any(psf):
                raise ReconInputError(
                    f"no light of a point at ({x:.3f}, {y:.3f}, {z:g}) mm reaches the sensor "
                    "patch; check the distance, focal length and sensor size")
            lat = lateral_inner_product_resolution_px(psf, thr)
            s_star = axial_inner_product_scale(psf, thr)
            u = 1.0 + m
            axial_mm = z - d / (s_star * u - 1.0)
            positions.append({
                "x_mm": float(x), "y_mm": float(y),
                "lateral_px": {"x": lat.x_px, "y": lat.y_px},
                "lateral_um": {"x": lat.x_px * pitch_mm / m * 1e3,
                               "y": lat.y_px * pitch_mm / m * 1e3},
                "scale": s_star, "axial_um": axial_mm * 1e3,
                "ghost_inner_product": _ghost(psf, 3.0 * max(lat.x_px, lat.y_px))})
        summary = {}
        for key, values in (
                ("lateral_um", [(p["lateral_um"]["x"] + p["lateral_um"]["y"]) / 2
                                for p in positions]),
                ("axial_um", [p["axial_um"] for p in positions]),
                ("ghost_inner_product", [p["ghost_inner_product"] for p in positions])):
            summary[key] = {"mean": float(np.mean(values)), "min": float(np.min(values)),
                            "max": float(np.max(values))}
        out.append({"z_mm": z, "magnification": m, "positions": positions,
                    "summary": summary})
    return {"threshold": thr, "conjugate_z_mm": design.conjugate_z_mm, "depths": out}
