"""Fused numba passes of the isotropic-TV and TGV priors (2D planes, float32, circular).

Conventions of :mod:`recon._kernels`: C-contiguous float32 arrays, neighbours wrap
circularly (the padded grid of the circular convolution). Axis 1 is x (columns),
axis 0 is y (rows); D+ is the forward difference, D- the backward one, and with
circular boundaries (D+)^T = -D-.

TGV of second order (Bredies, Kunisch & Pock 2010, "Total generalized variation",
SIAM J. Imaging Sci. 3(3)) in its discrete form of that paper's Sec. 4:

    TGV(x) = min_w  a1 ||D+ x - w||_{2,1} + a0 ||E w||_{F,1},
    E w = [[D-_x w1, (D-_y w1 + D-_x w2) / 2], [same, D-_y w2]],

the Frobenius norm of the symmetric 2 x 2 matrix counting its off-diagonal entry
twice. K(x, w) = (D+ x - w, E w) is the operator of the primal-dual iteration
(Chambolle & Pock 2011, Algorithm 1) with duals p (2 components) and q (q11, q22,
q12; <E w, q> = e11 q11 + e22 q22 + 2 e12 q12).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import PARALLEL_FAST, njit, prange

__all__ = ["TGV_NORM_SQ", "group_shrink_2", "tgv_dual_step", "tgv_primal_step",
           "tgv_upper_value"]

#: Bound on ||K||^2 of the TGV operator above (Bredies et al. 2010 give 12 for it;
#: the tests check it by power iteration), for the steps tau sigma ||K||^2 <= 1.
TGV_NORM_SQ = 12.0


@njit(inline="always")
def _around(i, n):
    """The circular neighbours (i - 1, i + 1) of index ``i`` of ``n``."""
    return (i - 1 if i > 0 else n - 1), (i + 1 if i < n - 1 else 0)


@njit(**PARALLEL_FAST)
def group_shrink_2(a, b, thr, out_a, out_b):
    """Group soft threshold of the 2-vectors (a, b) per pixel at ``thr`` (the prox of
    ``thr ||.||_{2,1}``): (a, b) max(1 - thr / |(a, b)|, 0) into (out_a, out_b);
    returns sum |(a, b)| of the input (float64)."""
    n0, n1 = a.shape
    rows = np.zeros(n0)
    for i in prange(n0):
        acc = 0.0
        for j in range(n1):
            u = a[i, j]
            v = b[i, j]
            n = math.sqrt(u * u + v * v)
            acc += n
            s = max(np.float32(1.0) - thr / n, np.float32(0.0)) if n > 0 else np.float32(0.0)
            out_a[i, j] = u * s
            out_b[i, j] = v * s
        rows[i] = acc
    return rows.sum()


@njit(**PARALLEL_FAST)
def tgv_dual_step(xb, w1b, w2b, p1, p2, q11, q22, q12, sigma, r1, r0):
    """Dual ascent of one primal-dual iteration, in place: p <- proj_{|p| <= r1}(p +
    sigma (D+ xb - wb)), q <- proj_{|q|_F <= r0}(q + sigma E wb)."""
    n0, n1 = xb.shape
    for i in prange(n0):
        im, ip = _around(i, n0)
        for j in range(n1):
            jm, jp = _around(j, n1)
            c = xb[i, j]
            a = p1[i, j] + sigma * (xb[i, jp] - c - w1b[i, j])
            b = p2[i, j] + sigma * (xb[ip, j] - c - w2b[i, j])
            n = math.sqrt(a * a + b * b)
            s = r1 / n if n > r1 else np.float32(1.0)
            p1[i, j] = a * s
            p2[i, j] = b * s
            e11 = w1b[i, j] - w1b[i, jm]
            e22 = w2b[i, j] - w2b[im, j]
            e12 = np.float32(0.5) * (w1b[i, j] - w1b[im, j] + w2b[i, j] - w2b[i, jm])
            a = q11[i, j] + sigma * e11
            b = q22[i, j] + sigma * e22
            d = q12[i, j] + sigma * e12
            n = math.sqrt(a * a + b * b + 2 * d * d)
            s = r0 / n if n > r0 else np.float32(1.0)
            q11[i, j] = a * s
            q22[i, j] = b * s
            q12[i, j] = d * s


@njit(**PARALLEL_FAST)
def tgv_primal_step(x, w1, w2, xb, w1b, w2b, p1, p2, q11, q22, q12, t, tau):
    """Primal descent of one primal-dual iteration of min 0.5 ||x - t||^2 + <K(x, w),
    (p, q)>, in place, with the extrapolation: x <- (x - tau D+^T p + tau t) / (1 +
    tau), w <- w + tau (p - E^T q); xb = 2 x_new - x_old, wb likewise."""
    n0, n1 = x.shape
    inv = np.float32(1.0) / (np.float32(1.0) + tau)
    for i in prange(n0):
        im, ip = _around(i, n0)
        for j in range(n1):
            jm, jp = _around(j, n1)
            div_p = p1[i, j] - p1[i, jm] + p2[i, j] - p2[im, j]  # -D+^T p
            xo = x[i, j]
            xn = (xo + tau * (div_p + t[i, j])) * inv
            x[i, j] = xn
            xb[i, j] = 2 * xn - xo
            # -E^T q: D+_x q11 + D+_y q12 and D+_y q22 + D+_x q12
            g1 = q11[i, jp] - q11[i, j] + q12[ip, j] - q12[i, j]
            g2 = q22[ip, j] - q22[i, j] + q12[i, jp] - q12[i, j]
            wo = w1[i, j]
            wn = wo + tau * (p1[i, j] + g1)
            w1[i, j] = wn
            w1b[i, j] = 2 * wn - wo
            wo = w2[i, j]
            wn = wo + tau * (p2[i, j] + g2)
            w2[i, j] = wn
            w2b[i, j] = 2 * wn - wo


@njit(**PARALLEL_FAST)
def tgv_upper_value(x, w1, w2, a1, a0):
    """a1 ||D+ x - w||_{2,1} + a0 ||E w||_{F,1} at the given w (float64): TGV(x)
    itself at the minimising w, an upper bound on it at any other."""
    n0, n1 = x.shape
    rows = np.zeros(n0)
    for i in prange(n0):
        im, ip = _around(i, n0)
        acc = 0.0
        for j in range(n1):
            jm, jp = _around(j, n1)
            c = x[i, j]
            a = x[i, jp] - c - w1[i, j]
            b = x[ip, j] - c - w2[i, j]
            e11 = w1[i, j] - w1[i, jm]
            e22 = w2[i, j] - w2[im, j]
            e12 = 0.5 * (w1[i, j] - w1[im, j] + w2[i, j] - w2[i, jm])
            acc += (a1 * math.sqrt(a * a + b * b)
                    + a0 * math.sqrt(e11 * e11 + e22 * e22 + 2 * e12 * e12))
        rows[i] = acc
    return rows.sum()
