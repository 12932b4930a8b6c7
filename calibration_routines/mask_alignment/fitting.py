"""Model fits of the mask-alignment procedure (holography-evaluation.md 8(c)).

Plain functions on arrays, no bench access:

* :func:`fit_triangle` -- the spot amplitude under a mask shift is a triangle of
  half-width ``k`` mask px (one SLM pixel), so ``sqrt(eta(s)) = A tri((s - d)/k) + B``
  locates the true offset ``d`` to a fraction of a mask pixel from a few samples;
* :func:`fit_similarity` -- per-patch offsets ``d_j`` at patch centres ``(x_j, y_j)``
  to ``t + theta (-y, x) + (m - 1) (x, y)`` (translation, rotation, scale);
* :func:`best_subpixel_offset` -- the common sub-pixel stage move that best serves
  every patch once each is rounded to its integer shift.

Each returns its standard errors, because the stopping rules compare a correction
with its own uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from instrument.plan import PlanError

__all__ = ["SimilarityFit", "TriangleFit", "best_subpixel_offset",
           "fit_similarity", "fit_triangle", "triangle"]


def triangle(x: np.ndarray) -> np.ndarray:
    """``tri(x) = max(0, 1 - |x|)`` (float64, same shape as ``x``)."""
    return np.maximum(0.0, 1.0 - np.abs(np.asarray(x, np.float64)))


def _samples(s, v, name: str) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(s, np.float64).ravel()
    v = np.asarray(v, np.float64).ravel()
    if s.size != v.size:
        raise PlanError(f"{name}: {s.size} positions but {v.size} values")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(v))):
        raise PlanError(f"{name}: positions and values must be finite")
    return s, v


@dataclass(frozen=True)
class TriangleFit:
    """Result of :func:`fit_triangle`.

    Attributes
    ----------
    offset : float
        ``d``: where the triangle peaks (same unit as the shifts, mask px).
    offset_sigma : float
        Standard error of ``d`` (inf when the fit is degenerate).
    amplitude, background : float
        ``A`` and ``B`` (units of ``sqrt(eta)``).
    rms : float
        Root-mean-square residual.
    """

    offset: float
    offset_sigma: float
    amplitude: float
    background: float
    rms: float


def fit_triangle(shifts, eta, k: float) -> TriangleFit:
    """Fit ``sqrt(eta(s)) = A tri((s - d) / k) + B`` to spot efficiencies.

    Under a true mask offset ``d`` the spot amplitude of a pattern computed for the
    model shifted by ``s`` falls off as ``tri((s - d) / k)`` per axis (the overlap of
    the shifted binary mask with itself within one SLM pixel of ``k`` mask pixels;
    holography-evaluation.md 8(c), checked against the bench model in the tests).

    Parameters
    ----------
    shifts : array_like, float (n,)
        Software shifts ``s`` (mask px), at least 4 distinct values.
    eta : array_like, float (n,)
        Spot efficiencies (negative values, from background subtraction, count as 0).
    k : float
        Mask pixels per SLM pixel (triangle half-width).

    Returns
    -------
    TriangleFit

    Raises
    ------
    instrument.plan.PlanError
        Mismatched, non-finite or too few samples, or ``k <= 0``.
    """
    s, e = _samples(shifts, eta, "fit_triangle")
    if k <= 0:
        raise PlanError(f"fit_triangle: k must be > 0, got {k}")
    if np.unique(s).size < 4:
        raise PlanError("fit_triangle needs at least 4 distinct shifts")
    a = np.sqrt(np.maximum(e, 0.0))

    def linear(d):
        basis = np.stack([triangle((s - d) / k), np.ones_like(s)], axis=1)
        coef, *_ = np.linalg.lstsq(basis, a, rcond=None)
        return coef, float(np.sum((basis @ coef - a) ** 2))

    grid = np.arange(s.min() - k / 2, s.max() + k / 2, k / 40.0)
    costs = [linear(d)[1] for d in grid]
    d0 = float(grid[int(np.argmin(costs))])
    (a0, b0), _ = linear(d0)

    def resid(p):
        return p[1] * triangle((s - p[0]) / k) + p[2] - a

    sol = least_squares(resid, [d0, max(a0, 1e-12), b0], method="lm")
    d, amp, bg = (float(v) for v in sol.x)
    r = sol.fun
    dof = max(s.size - 3, 1)
    var = float(r @ r) / dof
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * var
        sig = float(np.sqrt(max(cov[0, 0], 0.0)))
    except np.linalg.LinAlgError:
        sig = float("inf")
    if amp <= 0 or not np.isfinite(sig):
        sig = float("inf")
    return TriangleFit(d, sig, amp, bg, float(np.sqrt(np.mean(r**2))))


@dataclass(frozen=True)
class SimilarityFit:
    """Result of :func:`fit_similarity` (units of the inputs; ``theta`` in rad).

    Attributes
    ----------
    translation : (float, float)
    theta : float
    scale_error : float
        ``m - 1``.
    sigmas : (float, float, float, float)
        Standard errors of ``tx, ty, theta, m - 1``.
    residual_rms : float
        RMS of the per-patch residual displacement (x and y pooled).
    residuals : numpy.ndarray
        float64 (n, 2): what the similarity does not explain (distortion).
    """

    translation: tuple[float, float]
    theta: float
    scale_error: float
    sigmas: tuple[float, float, float, float]
    residual_rms: float
    residuals: np.ndarray


def fit_similarity(centres, offsets, offset_sigma: float | None = None) -> SimilarityFit:
    """Least-squares ``d_j = t + theta (-y_j, x_j) + (m - 1) (x_j, y_j)``.

    Parameters
    ----------
    centres : array_like, float (n, 2)
        Patch centres ``(x, y)`` in mask px from the optical axis.
    offsets : array_like, float (n, 2)
        Measured offsets ``(dx, dy)`` (mask px), n >= 3.
    offset_sigma : float, optional
        Measurement noise of one offset. Given, the standard errors are the noise
        propagated through the fit (what a stopping rule compares a correction with);
        otherwise they come from the residuals, which also hold any distortion the
        similarity cannot describe.

    Returns
    -------
    SimilarityFit

    Raises
    ------
    instrument.plan.PlanError
        Shapes differ, fewer than 3 patches, or the centres coincide.
    """
    c = np.asarray(centres, np.float64)
    d = np.asarray(offsets, np.float64)
    if c.shape != d.shape or c.ndim != 2 or c.shape[1] != 2:
        raise PlanError(f"fit_similarity: centres {c.shape} and offsets {d.shape} must both "
                        "be (n, 2)")
    n = c.shape[0]
    if n < 3:
        raise PlanError("fit_similarity needs at least 3 patches")
    x, y = c[:, 0], c[:, 1]
    one, zero = np.ones(n), np.zeros(n)
    a = np.concatenate([np.stack([one, zero, -y, x], 1), np.stack([zero, one, x, y], 1)])
    b = np.concatenate([d[:, 0], d[:, 1]])
    if np.linalg.matrix_rank(a) < 4:
        raise PlanError("fit_similarity: the patch centres coincide; use patches at "
                        "different positions")
    p, *_ = np.linalg.lstsq(a, b, rcond=None)
    r = b - a @ p
    var = float(r @ r) / max(2 * n - 4, 1) if offset_sigma is None else float(offset_sigma) ** 2
    sig = np.sqrt(np.maximum(np.diag(np.linalg.inv(a.T @ a)) * var, 0.0))
    res = np.stack([r[:n], r[n:]], axis=1)
    return SimilarityFit((float(p[0]), float(p[1])), float(p[2]), float(p[3]),
                         tuple(float(v) for v in sig), float(np.sqrt(np.mean(r**2))), res)


def best_subpixel_offset(offsets, k: float, step: float = 0.02) -> tuple[np.ndarray, float]:
    """Common sub-pixel move that best serves every patch once each is rounded.

    After a common move ``phi``, patch ``j`` uses the integer shift nearest
    ``d_j + phi`` and keeps ``f_j = d_j + phi - round(d_j + phi)``; by the triangle
    law its spot keeps ``(1 - |f_jx|/k)^2 (1 - |f_jy|/k)^2``. ``phi`` maximises the
    sum over patches (grid search over ``[-0.5, 0.5)^2``). Without distortion this is
    minus the common fractional part; with distortion it balances the patches.

    Parameters
    ----------
    offsets : array_like, float (n, 2)
        Per-patch offsets ``(dx, dy)``, mask px.
    k : float
        Mask pixels per SLM pixel.
    step : float
        Grid step of the search, mask px.

    Returns
    -------
    phi : numpy.ndarray
        float64 (2,), the move (mask px).
    gain : float
        Predicted mean spot with ``phi`` over the mean with no move (>= 1).
    """
    d = np.asarray(offsets, np.float64).reshape(-1, 2)
    grid = np.arange(-0.5, 0.5, step)

    def keep(v):  # (n, g): per patch, per candidate move, one axis
        f = v[:, None] + grid[None, :]
        return (1.0 - np.abs(f - np.round(f)) / k) ** 2

    score = keep(d[:, 0])[:, None, :] * keep(d[:, 1])[:, :, None]  # (n, gy, gx)
    total = score.mean(axis=0)
    iy, ix = np.unravel_index(int(np.argmax(total)), total.shape)
    i0 = int(np.argmin(np.abs(grid)))
    return np.array([grid[ix], grid[iy]]), float(total[iy, ix] / total[i0, i0])
