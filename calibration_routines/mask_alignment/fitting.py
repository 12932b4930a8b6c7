"""Model fits of the mask-alignment procedure (docs/protocols.md, "Mask alignment").

Plain functions on arrays, no bench access:

* :func:`fit_triangle` -- the spot amplitude under a mask shift is a triangle of
  half-width ``k`` mask px (one SLM pixel), apex rounded by the relay's blur, so
  ``sqrt(eta(s)) = A tri_r((s - d)/k) + B`` locates the true offset ``d`` to a
  fraction of a mask pixel from a few samples;
* :func:`fit_similarity` -- per-patch offsets ``d_j`` at patch centres ``(x_j, y_j)``
  to ``t + theta (-y, x) + (m - 1) (x, y)`` (translation, rotation, scale);
* :func:`best_subpixel_offset` -- the common sub-pixel stage move that best serves
  every patch once each is rounded to its integer shift;
* :func:`fit_parabola` -- the vertex of the spot's response to a focus sweep;
* :func:`fit_plane` -- per-patch best-focus positions to ``z0 + b_x x + b_y y``
  (focus and tip/tilt).

Each returns its standard errors, because the stopping rules compare a correction
with its own uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr

from instrument.acquisition.plan import PlanError

__all__ = ["ParabolaFit", "PlaneFit", "SimilarityFit", "TriangleFit", "best_subpixel_offset",
           "fit_parabola", "fit_plane", "fit_similarity", "fit_triangle", "smoothed_triangle",
           "triangle"]


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


def smoothed_triangle(x, rounding: float) -> np.ndarray:
    """``tri`` convolved with a Gaussian of standard deviation ``rounding`` (float64).

    Closed form with the smoothed ramp ``R(x) = x Phi(x / r) + r phi(x / r)``:
    ``R(x + 1) - 2 R(x) + R(x - 1)``; ``rounding = 0`` is :func:`triangle`.
    """
    x = np.asarray(x, np.float64)
    r = float(rounding)
    if r <= 0.0:
        return triangle(x)

    def ramp(v):
        return v * ndtr(v / r) + r * np.exp(-0.5 * (v / r) ** 2) / math.sqrt(2.0 * math.pi)

    return ramp(x + 1.0) - 2.0 * ramp(x) + ramp(x - 1.0)


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
    rounding : float
        Fitted rounding of the apex (Gaussian sigma in units of ``k``; 0 = sharp).
    """

    offset: float
    offset_sigma: float
    amplitude: float
    background: float
    rms: float
    rounding: float = 0.0


def fit_triangle(shifts, eta, k: float, rounded: bool = True) -> TriangleFit:
    """Fit ``sqrt(eta(s)) = A tri_r((s - d) / k) + B`` to spot efficiencies.

    Under a true mask offset ``d`` the spot amplitude of a pattern computed for the
    model shifted by ``s`` falls off as ``tri((s - d) / k)`` per axis (the overlap of
    the shifted binary mask with itself within one SLM pixel of ``k`` mask pixels;
    docs/protocols.md, checked against the bench model in the tests).
    A relay pupil or defocus blurs the SLM pixels on the mask and rounds the apex;
    ``tri_r`` is the triangle convolved with a Gaussian of fitted width ``r``
    (``smoothed_triangle``). Fitting a sharp triangle to a rounded apex sampled at
    integer shifts pushes ``d`` away from the nearest integer (measured on the virtual
    bench, NA 0.05 and 0.05 mm defocus: a 0.1 px stage move read as 0.18 px, which
    made the rigid loop oscillate; 0.12 px with the rounded model).

    Parameters
    ----------
    shifts : array_like, float (n,)
        Software shifts ``s`` (mask px), at least 4 distinct values (5 when rounded).
    eta : array_like, float (n,)
        Spot efficiencies (negative values, from background subtraction, count as 0).
    k : float
        Mask pixels per SLM pixel (triangle half-width).
    rounded : bool
        Fit the apex rounding ``r`` (in [0, 1]) too; False: the sharp triangle.

    Returns
    -------
    TriangleFit

    Raises
    ------
    instrument.acquisition.plan.PlanError
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
    rounded = rounded and np.unique(s).size >= 5

    def resid(p):
        shape = smoothed_triangle((s - p[0]) / k, p[3]) if rounded else triangle((s - p[0]) / k)
        return p[1] * shape + p[2] - a

    start = [d0, max(a0, 1e-12), b0] + ([0.05] if rounded else [])
    if rounded:
        lo = [-np.inf, -np.inf, -np.inf, 0.0]
        hi = [np.inf, np.inf, np.inf, 1.0]
        sol = least_squares(resid, start, bounds=(lo, hi), method="trf", x_scale="jac")
    else:
        sol = least_squares(lambda p: resid(list(p) + [0.0]), start, method="lm")
    d, amp, bg = (float(v) for v in sol.x[:3])
    rnd = float(sol.x[3]) if rounded else 0.0
    r = sol.fun
    n_par = 4 if rounded else 3
    dof = max(s.size - n_par, 1)
    var = float(r @ r) / dof
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * var
        sig = float(np.sqrt(max(cov[0, 0], 0.0)))
    except np.linalg.LinAlgError:
        sig = float("inf")
    if amp <= 0 or not np.isfinite(sig):
        sig = float("inf")
    return TriangleFit(d, sig, amp, bg, float(np.sqrt(np.mean(r**2))), rnd)


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
    instrument.acquisition.plan.PlanError
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


@dataclass(frozen=True)
class ParabolaFit:
    """Result of :func:`fit_parabola` (units of the inputs).

    Attributes
    ----------
    vertex : float
        Position of the extremum ``-b / (2 a)`` (nan when ``a == 0``).
    vertex_sigma : float
        Its standard error (inf when undetermined).
    curvature : float
        ``a`` of ``a z^2 + b z + c`` (negative for a maximum).
    peak : float
        The parabola's value at the vertex.
    width_80 : float
        Full width over which the parabola stays above 0.8 of its peak
        (``2 sqrt(0.2 peak / -a)``; inf unless a maximum with a positive peak): the
        depth of field the sweep measured.
    accepted : bool
        A maximum (``a < 0``, at least twice its standard error) whose vertex lies
        inside the sampled range.
    reason : str
        Why it was not accepted ("" when accepted).
    used : int
        Samples that entered the fit.
    """

    vertex: float
    vertex_sigma: float
    curvature: float
    peak: float
    width_80: float
    accepted: bool
    reason: str
    used: int


def fit_parabola(z, values, floor: float = 0.5) -> ParabolaFit:
    """Fit ``a z^2 + b z + c`` around the maximum of a sweep (focus of the spot).

    Only the samples around the largest value that stay above ``floor`` times it
    enter the fit (a bell-shaped response is a parabola near its top only); at least
    the 5 samples nearest the maximum are used (fewer if the sweep is shorter).

    Parameters
    ----------
    z : array_like, float (n,)
        Sweep positions (e.g. stage z, mm), n >= 3 distinct.
    values : array_like, float (n,)
        The metric at each position (e.g. the spot efficiency eta).
    floor : float
        Fraction of the maximum below which samples are left out, in [0, 1).

    Returns
    -------
    ParabolaFit

    Raises
    ------
    instrument.acquisition.plan.PlanError
        Mismatched or non-finite samples, fewer than 3 distinct positions, or
        ``floor`` outside [0, 1).
    """
    z, v = _samples(z, values, "fit_parabola")
    if np.unique(z).size < 3:
        raise PlanError("fit_parabola needs at least 3 distinct positions")
    if not 0.0 <= floor < 1.0:
        raise PlanError(f"fit_parabola: floor must be in [0, 1), got {floor}")
    order = np.argsort(z)
    z, v = z[order], v[order]
    i = int(np.argmax(v))
    lo, hi = i, i
    while lo > 0 and v[lo - 1] >= floor * v[i]:
        lo -= 1
    while hi < z.size - 1 and v[hi + 1] >= floor * v[i]:
        hi += 1
    while hi - lo + 1 < min(5, z.size):  # widen towards the side with more samples
        if lo > 0 and (hi == z.size - 1 or i - lo <= hi - i):
            lo -= 1
        else:
            hi += 1
    zs, vs = z[lo:hi + 1], v[lo:hi + 1]
    centre, scale = float(zs.mean()), float(np.ptp(zs)) or 1.0
    t = (zs - centre) / scale  # conditioned abscissa
    basis = np.stack([t**2, t, np.ones_like(t)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, vs, rcond=None)
    a_t, b_t, c_t = (float(c) for c in coef)
    r = vs - basis @ coef
    dof = zs.size - 3
    if dof > 0:
        cov = np.linalg.pinv(basis.T @ basis) * float(r @ r) / dof
    else:
        cov = np.full((3, 3), np.inf)
    a = a_t / scale**2
    if a_t == 0.0:
        return ParabolaFit(float("nan"), float("inf"), 0.0, float(vs.max()), float("inf"),
                           False, "flat response (no curvature)", int(zs.size))
    vt = -b_t / (2 * a_t)
    grad = np.array([b_t / (2 * a_t**2), -1.0 / (2 * a_t), 0.0])
    var = float(grad @ cov @ grad)
    sigma = float(np.sqrt(var)) * scale if np.isfinite(var) and var >= 0 else float("inf")
    vertex = centre + vt * scale
    peak = c_t - b_t**2 / (4 * a_t)
    width = 2.0 * float(np.sqrt(0.2 * peak / -a)) if a < 0 and peak > 0 else float("inf")
    reason = ""
    sig_a = float(np.sqrt(cov[0, 0])) if np.isfinite(cov[0, 0]) else float("inf")
    if a >= 0:
        reason = "no maximum (curvature >= 0)"
    elif -a_t < max(2.0 * sig_a, 1e-9 * abs(peak)):
        reason = "no significant curvature (flat response)"
    elif not z[0] <= vertex <= z[-1]:
        reason = f"vertex {vertex:.4g} outside the sweep [{z[0]:.4g}, {z[-1]:.4g}]"
    return ParabolaFit(float(vertex), sigma, float(a), float(peak), width, reason == "",
                       reason, int(zs.size))


@dataclass(frozen=True)
class PlaneFit:
    """Result of :func:`fit_plane`: ``z = z0 + slope_x x + slope_y y``.

    Attributes
    ----------
    z0, slope_x, slope_y : float
        Value at the origin and the two slopes (units of z per unit of x, y).
    sigmas : (float, float, float)
        Standard errors of ``z0, slope_x, slope_y``.
    residual_rms : float
    """

    z0: float
    slope_x: float
    slope_y: float
    sigmas: tuple[float, float, float]
    residual_rms: float


def fit_plane(xy, z, sigma=None) -> PlaneFit:
    """Weighted least-squares plane through points (per-patch best focus -> tip/tilt).

    Parameters
    ----------
    xy : array_like, float (n, 2)
        Point positions ``(x, y)``, n >= 3, not all on one line.
    z : array_like, float (n,)
        Values at the points.
    sigma : array_like, float (n,), optional
        Standard errors of ``z`` (weights ``1 / sigma^2``). The parameter errors are
        scaled up by the reduced chi-square when the scatter exceeds them (a patch's
        optimum also scatters because the metric of a finite random mask is itself
        random); without ``sigma`` they come from the residuals.

    Returns
    -------
    PlaneFit

    Raises
    ------
    instrument.acquisition.plan.PlanError
        Shapes differ, fewer than 3 points, the points are collinear, or a sigma is
        not positive.
    """
    p = np.asarray(xy, np.float64)
    zz = np.asarray(z, np.float64).ravel()
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] != zz.size:
        raise PlanError(f"fit_plane: xy {p.shape} must be (n, 2) with n = {zz.size} values")
    if zz.size < 3:
        raise PlanError("fit_plane needs at least 3 points")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(zz))):
        raise PlanError("fit_plane: positions and values must be finite")
    if sigma is None:
        w = np.ones_like(zz)
    else:
        s = np.asarray(sigma, np.float64).ravel()
        if s.size != zz.size or not np.all(s > 0):
            raise PlanError("fit_plane: sigma must hold one positive value per point")
        w = 1.0 / s**2
    a = np.stack([np.ones_like(zz), p[:, 0], p[:, 1]], axis=1)
    if np.linalg.matrix_rank(a) < 3:
        raise PlanError("fit_plane: the points lie on a line; a plane needs points spread "
                        "in both x and y")
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(a * sw[:, None], zz * sw, rcond=None)
    r = zz - a @ coef
    dof = max(zz.size - 3, 1)
    chi2 = float(np.sum(w * r**2)) / dof
    scale = chi2 if sigma is None else max(chi2, 1.0)
    cov = np.linalg.inv(a.T @ (a * w[:, None])) * scale
    sig = tuple(float(np.sqrt(max(c, 0.0))) for c in np.diag(cov))
    return PlaneFit(float(coef[0]), float(coef[1]), float(coef[2]), sig,
                    float(np.sqrt(np.mean(r**2))))
