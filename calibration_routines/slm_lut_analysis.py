"""Numerics of the SLM phase-LUT calibration: diffraction orders on the camera, the
zero-order fraction of a binary grating, phase from it, unfolding, the LUT fit.

A binary phase grating of levels ``(a, b)`` (50 % duty) sends the fraction
``C = cos^2(dphi / 2)`` of the light into the zero order, ``dphi = phi(b) - phi(a)``;
the rest goes into the odd (ideally) diffraction orders. On the camera the energies
are measured in windows around the orders (local background from a ring, so the
dark offset and stray light cancel), and the fraction

    c = E_0 / (E_0 + E_d),   E_d = sum of the windows of orders 1 <= |m| <= M

needs no laser power and no exposure (both cancel within one frame). The windows
catch only the share ``beta`` of the diffracted light (``8 / pi^2`` for the two
first orders of an ideal grating, less with pixel crosstalk; orders off the camera
are lost), so ``c = C / (C + beta (1 - C))`` and

    C = beta c / (1 - c + beta c),   m = 2 arccos(sqrt(C)) in [0, pi].

``beta`` is one number for the whole run, fitted from the exposure-normalised
energies against the uniform pattern's zero order (:func:`diffracted_share`).
``m`` is ``dphi`` folded into [0, pi]; the monotone response unfolds it
(:func:`unfold_monotone`). Sensitivity ``d(dphi)/dC = -2 / sin(dphi)`` is poor near
0 and pi, hence weights ``sin^2 m`` and a second grating pass against a reference
level near pi/2 (:func:`combine_passes`). Source: docs/hardware.md, "Phase SLMs"
(binary gratings, Opt. Express 20, 22334 (2012)); Kuo 2020 Sec. 7.4 pre-calibrates
the SLM phase the same way.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import isotonic_regression

from instrument.acquisition.plan import PlanError
from recon.optics.holo_display import efficiency

__all__ = ["WEIGHT_FLOOR", "binary_grating", "branch_values", "combine_passes",
           "diffracted_share", "find_order_offset", "fit_lut", "folded_phase",
           "nearest_branch", "order_energies", "spot_centroid", "unfold_monotone",
           "visible_orders"]

#: Added to ``sin^2 m`` in the weights: the inversion is biased, not just noisy, where
#: ``cos^2`` is flat, and one pass must never dominate by orders of magnitude.
WEIGHT_FLOOR = 0.05
#: Most phase branches the unfolding considers (a response up to 6 pi).
MAX_BRANCHES = 6


def binary_grating(shape: tuple[int, int], period_px: int, low: int, high: int) -> np.ndarray:
    """A binary grating along the SLM columns: gray ``low`` where ``col mod period <
    period / 2``, ``high`` elsewhere.

    Returns
    -------
    numpy.ndarray
        uint8 ``shape``.
    """
    rows, cols = shape
    row = np.where(np.arange(cols) % period_px < period_px // 2, low, high).astype(np.uint8)
    return np.broadcast_to(row, (rows, cols)).copy()


def spot_centroid(frame: np.ndarray, window_px: int) -> tuple[tuple[float, float], float]:
    """Sub-pixel centroid of the brightest spot and its peak-to-noise ratio.

    The frame's median is the background; the centroid is taken over the
    ``window_px`` square around the brightest pixel (background-subtracted values,
    negatives clipped).

    Parameters
    ----------
    frame : numpy.ndarray
        2-D, e.g. DN or DN/s.
    window_px : int
        Odd window side, pixels.

    Returns
    -------
    (x, y) : (float, float)
        Column and row of the centroid, pixels.
    peak_to_noise : float
        (peak - median) / robust noise (1.4826 MAD, at least 1e-12 of the peak).
    """
    f = np.asarray(frame, np.float64)
    bg = float(np.median(f))
    noise = 1.4826 * float(np.median(np.abs(f - bg)))
    r, c = np.unravel_index(int(np.argmax(f)), f.shape)
    peak = float(f[r, c]) - bg
    h = window_px // 2
    r0, c0 = max(r - h, 0), max(c - h, 0)
    patch = np.clip(f[r0:r + h + 1, c0:c + h + 1] - bg, 0.0, None)
    yy, xx = np.mgrid[r0:r0 + patch.shape[0], c0:c0 + patch.shape[1]]
    total = float(patch.sum())
    xy = (float((xx * patch).sum() / total), float((yy * patch).sum() / total)) if total > 0 \
        else (float(c), float(r))
    return xy, peak / max(noise, 1e-12 * max(abs(peak), 1.0))


def order_energies(frame: np.ndarray, zero_xy, offset_xy, orders, window_px: int,
                   ring_px: int) -> np.ndarray:
    """Background-corrected energy in the window of each diffraction order.

    Order ``m`` sits at ``zero_xy + m * offset_xy``; its energy is the sum over the
    ``window_px`` square minus the window's area times the mean of the surrounding
    ring of width ``ring_px`` (:func:`recon.optics.holo_display.efficiency`).

    Parameters
    ----------
    frame : numpy.ndarray
        2-D raw frame (e.g. mean DN, dark offset included; positive total).
    zero_xy, offset_xy : (float, float)
        Zero order and order spacing, camera pixels (x = column, y = row).
    orders : sequence of int
    window_px, ring_px : int

    Returns
    -------
    numpy.ndarray
        float64 ``(len(orders),)`` in the frame's unit.
    """
    f = np.asarray(frame, np.float64)
    total = float(f.sum())
    z, d = np.asarray(zero_xy, float), np.asarray(offset_xy, float)
    return np.array([efficiency(f, tuple(z + m * d), window_px, ring_px) * total
                     for m in orders])


def visible_orders(shape: tuple[int, int], zero_xy, offset_xy, max_order: int,
                   reach_px: int) -> list[int]:
    """Orders ``m`` (``1 <= |m| <= max_order``) whose window and ring (``reach_px``
    from the centre) lie inside a frame of ``shape`` (rows, cols)."""
    rows, cols = shape
    out = []
    for m in range(-max_order, max_order + 1):
        x, y = np.asarray(zero_xy, float) + m * np.asarray(offset_xy, float)
        cx, cy = round(x), round(y)
        if m and reach_px <= cx < cols - reach_px and reach_px <= cy < rows - reach_px:
            out.append(m)
    return out


def find_order_offset(diffraction_map: np.ndarray, zero_xy, window_px: int,
                      ring_px: int) -> tuple[float, float]:
    """The first-order spacing on the camera from a map of diffracted light.

    The brightest spot outside the zero order's window and ring is taken as one
    first order; its centroid minus the zero order is the spacing. The order on the
    other side must carry at least a quarter of its energy.

    Parameters
    ----------
    diffraction_map : numpy.ndarray
        2-D, e.g. the sum of background-subtracted grating frames, each divided by
        its own maximum.
    zero_xy : (float, float)
    window_px, ring_px : int

    Returns
    -------
    (dx, dy) : (float, float)
        Camera pixels.

    Raises
    ------
    PlanError
        No symmetric pair of first orders, or orders too close to be separated.
    """
    f = np.asarray(diffraction_map, np.float64) - float(np.median(diffraction_map))
    rows, cols = f.shape
    reach = window_px // 2 + ring_px + 1
    yy, xx = np.mgrid[0:rows, 0:cols]
    near = np.hypot(xx - zero_xy[0], yy - zero_xy[1]) <= reach
    (x1, y1), _ = spot_centroid(np.where(near, float(f.min()), f), window_px)
    d = (x1 - zero_xy[0], y1 - zero_xy[1])
    if math.hypot(*d) < window_px + 2 * ring_px:
        raise PlanError(f"the grating's first orders are only {math.hypot(*d):.1f} px from "
                        f"the zero order, closer than a window plus its ring "
                        f"({window_px + 2 * ring_px} px); use a smaller period_px or window_px")
    shape = f.shape
    if visible_orders(shape, zero_xy, d, 1, reach) != [-1, 1]:
        raise PlanError("the grating's -1 order falls off the camera (the +1 order is at "
                        f"{x1:.0f}, {y1:.0f} px, the zero order at {zero_xy[0]:.0f}, "
                        f"{zero_xy[1]:.0f} px); centre the zero order or use a larger period_px")
    minus, plus = order_energies(f + 1.0 - f.min(), zero_xy, d, (-1, 1), window_px, ring_px)
    if not minus > 0.25 * plus:
        raise PlanError("found no pair of first diffraction orders symmetric about the zero "
                        f"order (energies {minus:.3g} and {plus:.3g}); check that the camera "
                        "sees the SLM's far field without the mask and without stray spots")
    return float(d[0]), float(d[1])


def diffracted_share(e0: np.ndarray, ed: np.ndarray, e0_uniform: np.ndarray) -> float:
    """``beta``: share of the diffracted light the order windows catch.

    Least squares through the origin of ``ed = beta (e0_uniform - e0)`` over grating
    measurements (all energies per second; ``e0_uniform`` the uniform pattern's zero
    order at the time of each measurement).

    Raises
    ------
    PlanError
        No diffraction at all, or ``beta`` outside [0.2, 1.5] (the windows miss the
        orders or the light level changed during the run).
    """
    lost = np.asarray(e0_uniform, float) - np.asarray(e0, float)
    den = float(np.sum(lost * lost))
    if not den > 0:
        raise PlanError("no grating diffracted any light (zero order as bright as with the "
                        "uniform pattern at every level); check that the SLM modulates")
    beta = float(np.sum(np.asarray(ed, float) * lost) / den)
    if not 0.2 <= beta <= 1.5:
        raise PlanError(f"the order windows catch {beta:.2f} of the light the zero order "
                        "loses (expected about 0.8-1); check window_px and the order "
                        "positions, and that the laser power is stable")
    return beta


def folded_phase(fraction: np.ndarray, beta: float) -> np.ndarray:
    """``m = 2 arccos(sqrt(C))`` in [0, pi] from zero-order fractions ``c`` (module
    docstring), ``C`` clipped to [0, 1]. float64, shape of ``fraction``."""
    c = np.asarray(fraction, np.float64)
    big_c = np.clip(beta * c / np.maximum(1.0 - c + beta * c, 1e-12), 0.0, 1.0)
    return 2.0 * np.arccos(np.sqrt(big_c))


def branch_values(m: np.ndarray) -> np.ndarray:
    """Candidates ``x`` with ``fold(x) = m``: ``k pi + m`` (k even) and ``(k + 1) pi - m``
    (k odd) for ``k = 0 .. MAX_BRANCHES - 1``; float64 ``(len(m), MAX_BRANCHES)``."""
    m = np.asarray(m, np.float64)[:, None]
    k = np.arange(MAX_BRANCHES)[None, :]
    return np.where(k % 2 == 0, k * np.pi + m, (k + 1) * np.pi - m)


def unfold_monotone(gray: np.ndarray, m: np.ndarray, decrease_penalty: float = 10.0
                    ) -> np.ndarray:
    """Unfold folded phases ``m`` (in [0, pi], gray levels ascending, the first at
    phase 0) into a non-decreasing phase.

    Dynamic programming over the branch of each level (non-decreasing branch index)
    minimising the squared change of slope (``dx/dg``) plus ``decrease_penalty``
    times the squared decrease of any step: the smoothest monotone unfolding.

    Returns
    -------
    numpy.ndarray
        float64 ``(len(m),)``, radians.
    """
    g = np.asarray(gray, np.float64)
    cand = branch_values(m)
    n, nb = cand.shape
    if n < 3:
        return cand[:, 0]
    h = np.diff(g)
    inf = np.inf
    # cost[kp, k]: best cost with branch kp at level i-1 and k at level i (here i = 1)
    step = cand[1][None, :] - cand[0][:, None]
    cost = np.full((nb, nb), inf)
    cost[0, :] = decrease_penalty * np.minimum(step[0], 0.0) ** 2
    back = []
    upper = np.triu(np.ones((nb, nb), bool))  # allowed (kp <= k)
    for i in range(2, n):
        s_prev = (cand[i - 1][:, None] - cand[i - 2][None, :]) / h[i - 2]  # [kp, kpp]
        s_new = (cand[i][None, :] - cand[i - 1][:, None]) / h[i - 1]       # [kp, k]
        # total[kpp, kp, k]
        curv = (s_new[None, :, :] - s_prev.T[:, :, None]) * (0.5 * (h[i - 1] + h[i - 2]))
        dec = decrease_penalty * np.minimum(s_new * h[i - 1], 0.0) ** 2
        total = cost[:, :, None] + curv ** 2 + dec[None, :, :]
        total = np.where(upper[None, :, :], total, inf)
        arg = np.argmin(total, axis=0)              # best kpp for each (kp, k)
        cost = np.take_along_axis(total, arg[None], axis=0)[0]
        back.append(arg)
    kp, k = np.unravel_index(int(np.argmin(cost)), cost.shape)
    branches = [k, kp]
    for arg in reversed(back):
        kpp = arg[kp, k]
        k, kp = kp, kpp
        branches.append(kp)
    branches = np.array(branches[::-1])
    return cand[np.arange(n), branches]


def nearest_branch(m: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """The candidate (:func:`branch_values`, extended to negative phases) nearest to
    ``guess`` for each folded ``m``; float64."""
    m = np.asarray(m, np.float64)
    k = np.arange(-MAX_BRANCHES, MAX_BRANCHES + 1)
    cand = np.concatenate([2 * np.pi * k[None, :] + m[:, None],
                           2 * np.pi * k[None, :] - m[:, None]], axis=1)
    pick = np.argmin(np.abs(cand - np.asarray(guess, float)[:, None]), axis=1)
    return cand[np.arange(m.size), pick]


def combine_passes(gray: np.ndarray, m1: np.ndarray, m2: np.ndarray | None = None,
                   ref_index: int | None = None, refinements: int = 3
                   ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Phase of each gray level from pass 1 (``phi(g) - phi(0)``, folded ``m1``) and
    optionally pass 2 (``phi(g) - phi(g_ref)``, folded ``m2``, ``g_ref = gray[ref_index]``).

    Pass 1 is unfolded by :func:`unfold_monotone`; then, ``refinements`` times, each
    pass's branch is re-picked nearest to the current estimate and the weighted least
    squares problem ``phi_i ~ x1_i`` (weights ``sin^2 m1 + floor``), ``phi_i -
    phi_ref ~ x2_i`` (weights ``sin^2 m2 + floor``), ``phi_0 = 0`` is solved.

    Parameters
    ----------
    gray : numpy.ndarray
        Ascending levels, ``gray[0]`` the reference of pass 1 (phase 0 by definition).
    m1, m2 : numpy.ndarray
        Folded phases per level, radians in [0, pi] (``m1[0]`` is ignored).
    ref_index : int, optional
        Index of pass 2's reference level in ``gray``.
    refinements : int
        How many times the branches are re-picked and the least squares solved again
        (default 3).

    Returns
    -------
    phase : numpy.ndarray
        float64 (n,), radians, ``phase[0] = 0``.
    weight : numpy.ndarray
        float64 (n,), summed weights of the observations of each level.
    detail : dict
        ``x1``, ``x2`` (unfolded observations; ``x2`` already offset by the reference's
        phase), ``w1``, ``w2`` and ``rms_rad`` (weighted RMS disagreement).
    """
    gray = np.asarray(gray, np.float64)
    n = gray.size
    w1 = np.sin(np.asarray(m1, float)) ** 2 + WEIGHT_FLOOR
    w1[0] = 0.0
    x1 = unfold_monotone(gray, m1)
    x1[0] = 0.0
    phase = x1.copy()
    if m2 is None:
        return phase, w1, {"x1": x1, "x2": None, "w1": w1, "w2": None, "rms_rad": 0.0}
    m2 = np.asarray(m2, float)
    w2 = np.sin(m2) ** 2 + WEIGHT_FLOOR
    w2[ref_index] = 0.0  # phi_ref - phi_ref = 0 says nothing
    for _ in range(refinements):
        x1 = nearest_branch(m1, phase)
        x1[0] = 0.0
        x2 = nearest_branch(m2, phase - phase[ref_index])
        # unknowns phi_1..phi_{n-1}; rows: pass 1 (i >= 1), pass 2 (all i)
        a = np.zeros((2 * n, n))
        b = np.zeros(2 * n)
        a[np.arange(n), np.arange(n)] = 1.0
        b[:n] = x1
        a[n + np.arange(n), np.arange(n)] += 1.0
        a[n + np.arange(n), ref_index] -= 1.0
        b[n:] = x2
        sw = np.sqrt(np.concatenate([w1, w2]))
        sol, *_ = np.linalg.lstsq(a[:, 1:] * sw[:, None], b * sw, rcond=None)
        phase = np.concatenate([[0.0], sol])
    resid = np.concatenate([phase - x1, phase - phase[ref_index] - x2])
    wts = np.concatenate([w1, w2])
    rms = float(np.sqrt(np.sum(wts * resid**2) / np.sum(wts)))
    detail = {"x1": x1, "x2": x2 + phase[ref_index], "w1": w1, "w2": w2, "rms_rad": rms}
    return phase, w1 + w2, detail


def fit_lut(gray: np.ndarray, phase: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """A monotone LUT over all 256 gray levels from phases measured at ``gray``.

    Weighted isotonic regression (non-decreasing) at the measured levels, then the
    shape-preserving PCHIP interpolant through them, evaluated at 0..255 (the levels
    must include 0 and 255).

    Returns
    -------
    numpy.ndarray
        float64 (256,), radians, non-decreasing.

    Raises
    ------
    PlanError
        The levels do not span 0..255, or the phase does not rise.
    """
    gray = np.asarray(gray, np.float64)
    if gray[0] != 0 or gray[-1] != 255 or np.any(np.diff(gray) <= 0):
        raise PlanError("the measured levels must ascend from 0 to 255")
    iso = isotonic_regression(np.asarray(phase, float),
                              weights=np.maximum(np.asarray(weight, float), 1e-6)).x
    if not iso[-1] > iso[0]:
        raise PlanError("the measured phase does not rise with the gray level; check that "
                        "the SLM is lit and modulates (polarisation along its LC axis)")
    return PchipInterpolator(gray, iso)(np.arange(256.0))
