"""Two-point and 16-point distinguishability by reconstruction (Sec. 4.4, Fig. 4.3-4.4).

As in the dissertation: the measurement of several point sources is the sum of
images of one point source at the different positions (here the PSF shifted on
the sensor by the sources' separation, sub-pixel by cubic interpolation), the
scene is reconstructed with the regulariser off (non-negativity kept), and two
sources count as resolved when the reconstruction dips by at least 20 % between
them (the Rayleigh-like criterion of Sec. 4.4). Lateral only: separations are in
sensor pixels; convert to object space with m = d/z
(:func:`recon.analysis.lateral_resolution_object_mm`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import ReconInputError

__all__ = ["DIP_CRITERION", "TwoPointResult", "dip_between", "distinguishability_limit",
           "points_resolved"]

#: Two sources are resolved when the reconstruction dips by at least this fraction
#: of the weaker peak between them (Sec. 4.4).
DIP_CRITERION = 0.2


@dataclass(frozen=True)
class TwoPointResult:
    """Outcome at one separation: ``dip`` is the smallest dip over the neighbouring
    pairs (1 = fully separated, 0 = no dip), ``resolved`` whether it reaches
    :data:`DIP_CRITERION`."""

    separation_px: float
    n_points: int
    dip: float
    resolved: bool


def dip_between(image: np.ndarray, p0, p1, *, samples_per_px: int = 4) -> float:
    """Relative dip of ``image`` between points ``p0`` and ``p1`` ((row, col), px).

    The peaks are the maxima within 1 px of each point; the valley is the minimum of
    the bilinear profile along the segment between them (excluding 1 px at either
    end). Returns ``1 - valley / min(peak0, peak1)`` (0 if a peak is not positive).
    """
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    length = float(np.hypot(*(p1 - p0)))
    if length < 2:
        return 0.0

    def peak(p):
        r, c = (int(round(v)) for v in p)
        return float(image[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2].max())

    top = min(peak(p0), peak(p1))
    if top <= 0:
        return 0.0
    t = np.linspace(1.0 / length, 1.0 - 1.0 / length, max(int(length * samples_per_px), 3))
    line = p0[:, None] + (p1 - p0)[:, None] * t[None, :]
    valley = float(ndimage.map_coordinates(image, line, order=1).min())
    return float(np.clip(1.0 - valley / top, 0.0, 1.0))


def _grid(n_points: int, separation_px: float, axis: str) -> np.ndarray:
    """Offsets (row, col) of the sources about the centre: 2 on a line, 16 on 4x4."""
    if n_points == 2:
        half = separation_px / 2
        return np.array([[0.0, -half], [0.0, half]] if axis == "x" else
                        [[-half, 0.0], [half, 0.0]])
    if n_points == 16:
        k = (np.arange(4) - 1.5) * separation_px
        return np.array([(r, c) for r in k for c in k])
    raise ReconInputError(f"n_points={n_points}: use 2 (two-point) or 16 (4 x 4 grid)")


def points_resolved(psf: np.ndarray, separation_px: float, *, n_points: int = 2,
                    axis: str = "x", iterations: int = 300, method: str = "fista",
                    noise_std: float = 0.0, seed: int = 0) -> TwoPointResult:
    """Reconstruct ``n_points`` sources ``separation_px`` apart and test the 20 % dip.

    Parameters
    ----------
    psf : ndarray, (rows, cols)
        Measured PSF (non-negative, background removed).
    separation_px : float
        Distance between neighbouring sources on the sensor, px (> 0).
    n_points : {2, 16}
        Two sources on a line along ``axis``, or a 4 x 4 grid (every horizontal and
        vertical neighbour pair must dip).
    axis : {"x", "y"}
    iterations : int
        Solver iterations (regulariser off).
    method : {"fista", "gd", "admm"}
    noise_std : float
        Gaussian noise added to the summed measurement, as a fraction of its peak.
    seed : int

    Returns
    -------
    TwoPointResult

    Raises
    ------
    ReconInputError
        Bad PSF, separation, axis or point count.
    """
    from ..planar import scaled_problem, solve

    psf = np.asarray(psf, np.float64)
    if psf.ndim != 2 or not np.all(np.isfinite(psf)) or psf.sum() <= 0:
        raise ReconInputError("psf must be a finite 2D array with positive sum")
    if not separation_px > 0:
        raise ReconInputError(f"separation_px={separation_px!r}: use a positive distance")
    if axis not in ("x", "y"):
        raise ReconInputError(f"axis={axis!r}: use 'x' or 'y'")
    offsets = _grid(n_points, float(separation_px), axis)
    b = sum(ndimage.shift(psf, off, order=3, mode="constant") for off in offsets)
    b = np.clip(b, 0.0, None)
    if noise_std > 0:
        rng = np.random.default_rng(seed)
        b = b + noise_std * b.max() * rng.standard_normal(b.shape)
    op, bs = scaled_problem(psf, b)
    # where a source at the sensor-centred offset 0 reconstructs: the adjoint of the
    # PSF peaks there (its autocorrelation peak)
    centre = np.array(np.unravel_index(np.argmax(op.adjoint(scaled_problem(psf, psf)[1])),
                                       op.padded_shape), float)
    x = np.asarray(solve(op, bs, method, iterations=iterations, tv=0.0).x, np.float64)
    pos = centre[None, :] + offsets
    pairs = [(i, j) for i in range(len(pos)) for j in range(i + 1, len(pos))
             if abs(np.hypot(*(pos[i] - pos[j])) - separation_px) < 1e-6]
    dip = min(dip_between(x, pos[i], pos[j]) for i, j in pairs)
    return TwoPointResult(float(separation_px), n_points, dip, dip >= DIP_CRITERION)


def distinguishability_limit(psf: np.ndarray, separations_px, **options) -> tuple[
        float | None, list[TwoPointResult]]:
    """Smallest tested separation from which on every larger one is resolved.

    ``options`` go to :func:`points_resolved` (``n_points=2`` for the two-point
    limit, 16 for the 16-point one). Returns ``(limit_px or None, results)``.
    """
    seps = sorted(float(s) for s in separations_px)
    results = [points_resolved(psf, s, **options) for s in seps]
    limit = None
    for r in reversed(results):
        if not r.resolved:
            break
        limit = r.separation_px
    return limit, results
