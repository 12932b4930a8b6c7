"""Fused, multithreaded elementwise kernels for the solvers' hot loops (numba).

Each kernel makes one pass over its arrays so an iteration costs little more than
its FFTs (the speed goal is stated as a ratio to the FFT floor). The reference
formulas live in the solver docstrings and are checked in the tests against plain
numpy. Arrays are C-contiguous float32 (complex64 in Fourier space); padded-grid
neighbours wrap circularly, matching the circular convolution of Eq. 3.4.
"""

from __future__ import annotations

import numpy as np

from .jit import PARALLEL_FAST, balance_terms, clip, data_split, njit, prange, shrink_split


@njit(**PARALLEL_FAST)
def crop_residual(full, b, w, top, left):
    """In place: ``full <- P(w * (w * C full - b))``; returns ||w * C full - b||^2.

    ``full`` (P0, P1) is the padded-grid convolution; ``b`` and ``w`` (S0, S1) are
    the (pre-weighted) measurement and the sensor weights; the sensor sits at
    (top, left). Outside the sensor the result is zero (the pad P = C^T).
    """
    n0, n1 = full.shape
    s0, s1 = b.shape
    acc = 0.0
    for i in prange(n0):
        si = i - top
        if si < 0 or si >= s0:
            for j in range(n1):
                full[i, j] = 0.0
            continue
        for j in range(n1):
            sj = j - left
            if sj < 0 or sj >= s1:
                full[i, j] = 0.0
            else:
                ww = w[si, sj]
                r = ww * full[i, j] - b[si, sj]
                acc += r * r
                full[i, j] = ww * r
    return acc


@njit(**PARALLEL_FAST)
def multiply_spectrum(spec, h, conjugate):
    """In place: spec *= h, or spec *= conj(h) if ``conjugate`` (both threads)."""
    n0, n1 = spec.shape
    for i in prange(n0):
        for j in range(n1):
            hh = h[i, j]
            spec[i, j] *= hh.conjugate() if conjugate else hh


@njit(inline="always")
def _prox_px(y, grad, x, y_next, i, j, im, ip, jm, jp, step, thr, beta, lo):
    yc = y[i, j]
    zc = yc - step * grad[i, j]
    zi_p = y[ip, j] - step * grad[ip, j]
    zi_m = y[im, j] - step * grad[im, j]
    zj_p = y[i, jp] - step * grad[i, jp]
    zj_m = y[i, jm] - step * grad[i, jm]
    corr = (clip(0.5 * (zi_p - zc), thr) - clip(0.5 * (zc - zi_m), thr)
            + clip(0.5 * (zj_p - zc), thr) - clip(0.5 * (zc - zj_m), thr))
    xn = max(zc + 0.25 * corr, lo)
    xo = x[i, j]
    x[i, j] = xn
    y_next[i, j] = xn + beta * (xn - xo)
    return abs(y[ip, j] - yc) + abs(y[i, jp] - yc), (yc - xn) * (xn - xo)


@njit(**PARALLEL_FAST)
def proximal_step_2d(y, grad, x, y_next, step, thr, beta, nonneg):
    """One accelerated proximal-gradient update on a 2D grid, fused.

    z = y - step * grad; x_new = prox(z) with the Haar-shift TV approximation of
    App. A.1 (threshold ``thr`` on the half-differences, averaged over both axes;
    ``thr = 0`` disables TV), then max(., 0) if ``nonneg``;
    y_next = x_new + beta * (x_new - x_old). ``x`` is overwritten by x_new.

    Returns
    -------
    tv_y : float
        Anisotropic TV of ``y`` (sum of |forward differences|), for the objective.
    restart_dot : float
        <y - x_new, x_new - x_old>; positive means the momentum points uphill
        (gradient restart test of O'Donoghue & Candes 2015).
    """
    n0, n1 = y.shape
    lo = np.float32(0.0) if nonneg else np.float32(-np.inf)
    step = np.float32(step)
    thr = np.float32(thr)
    beta = np.float32(beta)
    tv = 0.0
    dot = 0.0
    for i in prange(n0):
        im = i - 1 if i > 0 else n0 - 1
        ip = i + 1 if i < n0 - 1 else 0
        tv_row = np.float32(0.0)
        dot_row = np.float32(0.0)
        a, c = _prox_px(y, grad, x, y_next, i, 0, im, ip, n1 - 1, 1, step, thr, beta, lo)
        tv_row += a
        dot_row += c
        for j in range(1, n1 - 1):
            a, c = _prox_px(y, grad, x, y_next, i, j, im, ip, j - 1, j + 1, step, thr, beta,
                            lo)
            tv_row += a
            dot_row += c
        a, c = _prox_px(y, grad, x, y_next, i, n1 - 1, im, ip, n1 - 2, 0, step, thr, beta,
                        lo)
        tv += tv_row + a
        dot += dot_row + c
    return tv, dot


@njit(inline="always")
def _group_shrink_split(gx, gy, qx, qy, thr):
    """The isotropic TV split of one pixel in q-form (:func:`recon.jit.shrink_split`
    with the group soft threshold of the 2-vector t = g + a at ``thr``): returns
    (q_new, a, z) for x, then for y."""
    ax = gx - qx
    ay = gy - qy
    tx = gx + ax
    ty = gy + ay
    n = np.sqrt(tx * tx + ty * ty)
    s = max(np.float32(1.0) - thr / n, np.float32(0.0)) if n > 0 else np.float32(0.0)
    zx = tx * s
    zy = ty * s
    return zx - ax, ax, zx, zy - ay, ay, zy


@njit(inline="always")
def _admm_px(x, mx, qv, qux, quy, qw, bp, wp, i, j, ip, jp, mu1, thr, use_tv, mode,
             av, aux, auy, aw, l1thr, iso):
    """One pixel of :func:`admm_split_updates_2d`; returns its reduction terms."""
    zero = np.float32(0.0)
    ninf = np.float32(-np.inf)
    rv = sv = ru = su = rw = sw = zero
    nv = nu = nw = zero  # mode 2: max(|G x|^2, |z|^2) proxies and |a|^2 per split
    dv = du = dw = zero
    # v split (crop / data): bp, wp are the weights and measurement padded with zeros
    g = mx[i, j]
    q = qv[i, j]
    qn, a, z, res = data_split(g, q, wp[i, j], bp[i, j], mu1)
    if mode == 2:
        rv, sv, nv, dv = balance_terms(g, q, a, z, av[i, j])
    if mode != 0:
        av[i, j] = a
    qv[i, j] = qn
    # w split (non-negativity)
    g = x[i, j]
    q = qw[i, j]
    qn, a, z = shrink_split(g, q, l1thr, zero)  # l1 on x >= 0: max(t - l1 / mu3, 0)
    if mode == 2:
        rw, sw, nw, dw = balance_terms(g, q, a, z, aw[i, j])
    if mode != 0:
        aw[i, j] = a
    qw[i, j] = qn
    # u split (anisotropic TV; isotropic with ``iso``)
    gx = x[i, jp] - g
    gy = x[ip, j] - g
    if use_tv and iso:
        qx = qux[i, j]
        qy = quy[i, j]
        qnx, a, z, qny, a2, z2 = _group_shrink_split(gx, gy, qx, qy, thr)
        if mode == 2:
            ru, su, nu, du = balance_terms(gx, qx, a, z, aux[i, j])
            r2, s2, n2, d2 = balance_terms(gy, qy, a2, z2, auy[i, j])
            ru, su, nu, du = ru + r2, su + s2, nu + n2, du + d2
        if mode != 0:
            aux[i, j] = a
            auy[i, j] = a2
        qux[i, j] = qnx
        quy[i, j] = qny
    elif use_tv:
        q = qux[i, j]
        qn, a, z = shrink_split(gx, q, thr, ninf)
        if mode == 2:
            ru, su, nu, du = balance_terms(gx, q, a, z, aux[i, j])
        if mode != 0:
            aux[i, j] = a
        qux[i, j] = qn
        q = quy[i, j]
        qn, a, z = shrink_split(gy, q, thr, ninf)
        if mode == 2:
            r2, s2, n2, d2 = balance_terms(gy, q, a, z, auy[i, j])
            ru, su, nu, du = ru + r2, su + s2, nu + n2, du + d2
        if mode != 0:
            auy[i, j] = a
        quy[i, j] = qn
    tv = np.sqrt(gx * gx + gy * gy) if iso else abs(gx) + abs(gy)
    return (res, tv, rv, sv, ru, su, rw, sw, nv, dv, nu, du, nw, dw)


@njit(**PARALLEL_FAST)
def admm_split_updates_2d(x, mx, qv, qux, quy, qw, bp, wp,
                          mu1, mu2, mu3, tau, use_tv, mode, av, aux, auy, aw, l1=0.0,
                          rhs=None, iso=False):
    """ADMM z- and dual updates of Eq. 4.5 / App. A.3 in 2D, fused, in q-form.

    For each split with G x = g (v: M x, u: Psi x as forward differences, w: x),
    keeping only q = z - a (a = scaled dual) between iterations:
    a_new = g - q_old; z_new = prox(g + a_new); q_new = z_new - a_new, where the
    proxes are v: (w b + mu1 t) / (w^2 + mu1) (w, b zero-padded off the sensor);
    u: soft threshold tau/mu2 (with ``iso``: the group soft threshold of each
    pixel's difference vector, isotropic TV); w: max(t - l1/mu3, 0) (non-negativity, and the l1
    weight ``l1`` when > 0: on x >= 0, l1 ||x||_1 is linear). This is the textbook
    scaled-dual ADMM with the dual step of iteration k fused into the z-step of k+1.

    mode 0: plain; 1: store a_new in (av, aux, auy, aw); 2: also compute the
    residual norms r = ||a_new - a_old|| (primal) and ||z_new - z_old|| (for the
    dual residual) from a_old held in those buffers, then store a_new.

    ``rhs`` (optional, float32 like ``x``): also write the x-update's right-hand
    side mu2 Psi^T q_u + mu3 q_w of the new q's into it, as :func:`admm_rhs_2d`
    does (same arithmetic, same values) but in the same pass: each thread runs
    blocks of consecutive rows, so row i's right-hand side is formed right after
    row i, from rows i and i - 1 still in cache; the first row of each block,
    whose row i - 1 another thread wrote, is done after the parallel loop.

    Returns
    -------
    out : ndarray, shape (14,), float64
        [||w C M x - b||^2, TV(x) (isotropic with ``iso``), r_v^2, s_v^2, r_u^2, s_u^2,
        r_w^2, s_w^2, then per split (v, u, w) sum max(|G x|^2, |z|^2) and ||a||^2] (the
        last 11 in mode 2).
    """
    n0, n1 = x.shape
    thr = np.float32(tau / mu2 if use_tv else 0.0)
    l1thr = np.float32(l1 / mu3)
    mu1 = np.float32(mu1)
    rows = np.zeros((n0, 14))
    blocks = min(n0, _ROW_BLOCKS)
    for blk in prange(blocks):
        start = blk * n0 // blocks
        for i in range(start, (blk + 1) * n0 // blocks):
            # One row loop per mode, each with the mode a literal: the loop of a run-time
            # mode is vectorised with masked stores to the dual buffers that are all-off
            # in mode 0 yet cost a microcode assist per vector on pages the kernel has
            # not stored to lately (mode 0 measured 34-40 ms against 8-10 ms for mode 1
            # at 1200 x 1600; specialised, 2.2-3.5 ms). Same arithmetic, same results.
            if mode == 0:
                acc = _admm_row(x, mx, qv, qux, quy, qw, bp, wp, i, mu1, thr, use_tv, 0,
                                av, aux, auy, aw, l1thr, iso)
            elif mode == 1:
                acc = _admm_row(x, mx, qv, qux, quy, qw, bp, wp, i, mu1, thr, use_tv, 1,
                                av, aux, auy, aw, l1thr, iso)
            else:
                acc = _admm_row(x, mx, qv, qux, quy, qw, bp, wp, i, mu1, thr, use_tv, 2,
                                av, aux, auy, aw, l1thr, iso)
            for k in range(14):
                rows[i, k] = acc[k]
            if rhs is not None and i > start:
                _rhs_row(qux, quy, qw, rhs, i, mu2, mu3, use_tv)
    if rhs is not None:
        for blk in range(blocks):
            _rhs_row(qux, quy, qw, rhs, blk * n0 // blocks, mu2, mu3, use_tv)
    out = np.zeros(14)
    for i in range(n0):
        for k in range(14):
            out[k] += rows[i, k]
    return out


#: Row blocks of :func:`admm_split_updates_2d` (a few per thread; each block's first
#: row has its right-hand side done after the parallel loop).
_ROW_BLOCKS = 16


@njit(inline="always")
def _admm_row(x, mx, qv, qux, quy, qw, bp, wp, i, mu1, thr, use_tv, mode, av, aux, auy, aw,
              l1thr, iso):
    """Row ``i`` of :func:`admm_split_updates_2d`; returns its 14 reduction sums."""
    n0, n1 = x.shape
    ip = i + 1 if i < n0 - 1 else 0
    z0 = np.float32(0.0)
    acc = (z0, z0, z0, z0, z0, z0, z0, z0, z0, z0, z0, z0, z0, z0)
    for j in range(n1):
        jp = j + 1 if j < n1 - 1 else 0
        c = _admm_px(x, mx, qv, qux, quy, qw, bp, wp, i, j, ip, jp, mu1, thr, use_tv, mode,
                     av, aux, auy, aw, l1thr, iso)
        acc = _add14(acc, c)
    return acc


@njit(inline="always")
def _add14(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5],
            a[6] + b[6], a[7] + b[7], a[8] + b[8], a[9] + b[9], a[10] + b[10],
            a[11] + b[11], a[12] + b[12], a[13] + b[13])


@njit(inline="always")
def _rhs_row(qux, quy, qw, out, i, mu2, mu3, use_tv):
    """Row ``i`` of :func:`admm_rhs_2d`."""
    n0, n1 = qw.shape
    im = i - 1 if i > 0 else n0 - 1
    for j in range(n1):
        jm = j - 1 if j > 0 else n1 - 1
        val = mu3 * qw[i, j]
        if use_tv:
            val += mu2 * (qux[i, jm] - qux[i, j] + quy[im, j] - quy[i, j])
        out[i, j] = val


@njit(**PARALLEL_FAST)
def admm_rhs_2d(qux, quy, qw, out, mu2, mu3, use_tv):
    """out = mu2 * Psi^T q_u + mu3 * q_w, Psi^T of forward differences (circular)."""
    for i in prange(qw.shape[0]):
        _rhs_row(qux, quy, qw, out, i, mu2, mu3, use_tv)


@njit(**PARALLEL_FAST)
def admm_inverse_denominator(h_pow, d_pow, mu1, mu2, mu3, use_tv, out):
    """out = 1 / (mu1 |H|^2 + mu2 |F Psi|^2 + mu3) (the x-update of App. A.3)."""
    n0, n1 = out.shape
    for i in prange(n0):
        for j in range(n1):
            den = mu1 * h_pow[i, j] + mu3
            if use_tv:
                den += mu2 * d_pow[i, j]
            out[i, j] = 1.0 / den


@njit(**PARALLEL_FAST)
def admm_fourier_2d(qv_hat, rhs_hat, spec, inv_den, mu1):
    """x_hat = (mu1 conj(H) Qv + R) * inv_den into rhs_hat; H x_hat into qv_hat."""
    n0, n1 = qv_hat.shape
    for i in prange(n0):
        for j in range(n1):
            h = spec[i, j]
            xh = (mu1 * h.conjugate() * qv_hat[i, j] + rhs_hat[i, j]) * inv_den[i, j]
            rhs_hat[i, j] = xh
            qv_hat[i, j] = h * xh
