"""Fused numba kernels for the 3D (volume) forward model and FISTA (Kuo 2020, Ch. 4).

The 3D counterparts of :mod:`recon._kernels`, with the same conventions: one pass
over the arrays, C-contiguous float32 / complex64, parallel over rows. Lateral
neighbours wrap circularly (the padded grid of the circular convolution, Eq. 3.4);
depth planes do **not** wrap (the front and back of the volume are not neighbours),
so the Haar pairs along z stop at the first and last plane.
"""

from __future__ import annotations

import numpy as np

from ..jit import PARALLEL_FAST, clip, njit, prange


@njit(**PARALLEL_FAST)
def accumulate_products(acc, spec, h, zero_first):
    """In place: ``acc[i, j] (+)= sum_z h[z, i, j] * spec[z, i, j]`` (Eq. 4.4 in Fourier space).

    ``acc`` (F0, F1) complex64 is set to the sum when ``zero_first``, otherwise the
    sum is added to it (for chunked stacks); ``spec`` and ``h`` are (k, F0, F1).
    """
    k, n0, n1 = spec.shape
    for i in prange(n0):
        for j in range(n1):
            s = np.complex64(0.0) if zero_first else acc[i, j]
            for z in range(k):
                s += h[z, i, j] * spec[z, i, j]
            acc[i, j] = s


@njit(**PARALLEL_FAST)
def conj_products(out, r, h):
    """``out[z, i, j] = conj(h[z, i, j]) * r[i, j]`` for every plane (the adjoint, Eq. 3.8)."""
    k, n0, n1 = out.shape
    for i in prange(n0):
        for z in range(k):
            for j in range(n1):
                out[z, i, j] = h[z, i, j].conjugate() * r[i, j]


@njit(inline="always")
def _zval(y, grad, step, z, i, j):
    return y[z, i, j] - step * grad[z, i, j]


@njit(inline="always")
def _prox_vox(y, grad, x, y_next, z, i, j, im, ip, jm, jp, nz, step, thr, l1thr, beta, lo):
    yc = y[z, i, j]
    zc = yc - step * grad[z, i, j]
    corr = (clip(0.5 * (_zval(y, grad, step, z, ip, j) - zc), thr)
            - clip(0.5 * (zc - _zval(y, grad, step, z, im, j)), thr)
            + clip(0.5 * (_zval(y, grad, step, z, i, jp) - zc), thr)
            - clip(0.5 * (zc - _zval(y, grad, step, z, i, jm)), thr))
    tv = abs(y[z, ip, j] - yc) + abs(y[z, i, jp] - yc)
    if z + 1 < nz:
        corr += clip(0.5 * (_zval(y, grad, step, z + 1, i, j) - zc), thr)
        tv += abs(y[z + 1, i, j] - yc)
    if z > 0:
        corr -= clip(0.5 * (zc - _zval(y, grad, step, z - 1, i, j)), thr)
    xn = zc + corr / 6.0
    xn = xn - clip(xn, l1thr)  # soft threshold (l1); l1thr = 0 leaves xn
    xn = max(xn, lo)
    xo = x[z, i, j]
    x[z, i, j] = xn
    y_next[z, i, j] = xn + beta * (xn - xo)
    return tv, abs(yc), (yc - xn) * (xn - xo)


@njit(**PARALLEL_FAST)
def proximal_step_3d(y, grad, x, y_next, step, thr, l1thr, beta, nonneg):
    """One accelerated proximal-gradient update on a volume (nz, n0, n1), fused.

    z = y - step * grad; TV: the Haar-shift approximation of App. A.1 along z, y and
    x (threshold ``thr`` on the half-differences, the three axes averaged, so each
    voxel moves by sum_axes [clip(d_k) - clip(d_{k-1})] / 6); then the l1 soft
    threshold ``l1thr``; then max(., 0) if ``nonneg``; x_new is written to ``x``
    and y_next = x_new + beta * (x_new - x_old). ``thr = 0`` / ``l1thr = 0`` disable
    the terms. Depth pairs stop at the first and last planes (no wrap in z).

    Returns
    -------
    tv_y : float
        Anisotropic TV of ``y`` (laterally circular, non-circular in z).
    l1_y : float
        sum |y|.
    restart_dot : float
        <y - x_new, x_new - x_old> (gradient restart test).
    """
    nz, n0, n1 = y.shape
    lo = np.float32(0.0) if nonneg else np.float32(-np.inf)
    step = np.float32(step)
    thr = np.float32(thr)
    l1thr = np.float32(l1thr)
    beta = np.float32(beta)
    tv = 0.0
    l1 = 0.0
    dot = 0.0
    for zi in prange(nz * n0):
        z = zi // n0
        i = zi - z * n0
        im = i - 1 if i > 0 else n0 - 1
        ip = i + 1 if i < n0 - 1 else 0
        tv_row = np.float32(0.0)
        l1_row = np.float32(0.0)
        dot_row = np.float32(0.0)
        for j in range(n1):
            jm = j - 1 if j > 0 else n1 - 1
            jp = j + 1 if j < n1 - 1 else 0
            a, b, c = _prox_vox(y, grad, x, y_next, z, i, j, im, ip, jm, jp, nz, step, thr,
                                l1thr, beta, lo)
            tv_row += a
            l1_row += b
            dot_row += c
        tv += tv_row
        l1 += l1_row
        dot += dot_row
    return tv, l1, dot


@njit(**PARALLEL_FAST)
def slab_penalty(y, after, has_after):
    """Anisotropic TV and l1 of a slab of planes ``y`` (k, n0, n1), read only.

    The terms of :func:`proximal_step_3d`'s ``tv_y`` and ``l1_y`` for the planes of
    one slab of a volume split along z: laterally circular; the depth pair of the
    slab's last plane uses ``after`` (n0, n1), the next slab's first plane, when
    ``has_after`` (the volume's last plane has none).
    """
    k, n0, n1 = y.shape
    tv = 0.0
    l1 = 0.0
    for zi in prange(k * n0):
        z = zi // n0
        i = zi - z * n0
        ip = i + 1 if i < n0 - 1 else 0
        tv_row = np.float32(0.0)
        l1_row = np.float32(0.0)
        for j in range(n1):
            jp = j + 1 if j < n1 - 1 else 0
            yc = y[z, i, j]
            t = abs(y[z, ip, j] - yc) + abs(y[z, i, jp] - yc)
            if z + 1 < k:
                t += abs(y[z + 1, i, j] - yc)
            elif has_after:
                t += abs(after[i, j] - yc)
            tv_row += t
            l1_row += abs(yc)
        tv += tv_row
        l1 += l1_row
    return tv, l1


@njit(**PARALLEL_FAST)
def slab_prox(v, before, after, has_before, has_after, y, x, thr, l1thr, beta, nonneg):
    """The proximal update of :func:`proximal_step_3d` on one slab, from ``v = y - step grad``.

    ``v``, ``y``, ``x`` are (k, n0, n1) float32; ``before`` / ``after`` (n0, n1) are
    ``v`` of the planes next to the slab (the previous slab's last, the next slab's
    first), used when ``has_before`` / ``has_after``. Writes ``x <- x_new`` and,
    in place, ``y <- x_new + beta (x_new - x_old)`` (each voxel of ``y`` is read
    once, before it is written, so no second volume is needed). Same arithmetic as
    :func:`proximal_step_3d` voxel for voxel.

    Returns
    -------
    restart_dot : float
        <y - x_new, x_new - x_old> over the slab.
    """
    k, n0, n1 = v.shape
    lo = np.float32(0.0) if nonneg else np.float32(-np.inf)
    thr = np.float32(thr)
    l1thr = np.float32(l1thr)
    beta = np.float32(beta)
    dot = 0.0
    for zi in prange(k * n0):
        z = zi // n0
        i = zi - z * n0
        im = i - 1 if i > 0 else n0 - 1
        ip = i + 1 if i < n0 - 1 else 0
        dot_row = np.float32(0.0)
        for j in range(n1):
            jm = j - 1 if j > 0 else n1 - 1
            jp = j + 1 if j < n1 - 1 else 0
            zc = v[z, i, j]
            corr = (clip(0.5 * (v[z, ip, j] - zc), thr) - clip(0.5 * (zc - v[z, im, j]), thr)
                    + clip(0.5 * (v[z, i, jp] - zc), thr)
                    - clip(0.5 * (zc - v[z, i, jm]), thr))
            if z + 1 < k:
                corr += clip(0.5 * (v[z + 1, i, j] - zc), thr)
            elif has_after:
                corr += clip(0.5 * (after[i, j] - zc), thr)
            if z > 0:
                corr -= clip(0.5 * (zc - v[z - 1, i, j]), thr)
            elif has_before:
                corr -= clip(0.5 * (zc - before[i, j]), thr)
            xn = zc + corr / 6.0
            xn = xn - clip(xn, l1thr)
            xn = max(xn, lo)
            xo = x[z, i, j]
            yc = y[z, i, j]
            x[z, i, j] = xn
            y[z, i, j] = xn + beta * (xn - xo)
            dot_row += (yc - xn) * (xn - xo)
        dot += dot_row
    return dot
