"""Fused numba kernels of the 3D ADMM (Kuo 2020, Eq. 4.5, App. A.3).

Conventions as in :mod:`recon._kernels` and :mod:`recon.volume._kernels3d`:
C-contiguous float32 / complex64, one pass per kernel, parallel over rows. Lateral
neighbours wrap circularly (the padded grid of Eq. 3.4); depth planes do **not**
wrap (no difference between the last and the first plane), as in
:func:`recon.volume.fista3d`.

Split state is kept in q-form (q = z - a, a the scaled dual) as in
:func:`recon._kernels.admm_split_updates_2d`; ``mode`` 0 is a plain update, 1 also
stores a_new, 2 additionally returns the residual terms used by the balancing.
"""

from __future__ import annotations

import numpy as np

from ..jit import PARALLEL_FAST, balance_terms, data_split, njit, prange, shrink_split


@njit(**PARALLEL_FAST)
def admm_split_plane(mx, qv, bp, wp, mu1, mode, av):
    """The v split (crop / data) on the padded plane, in q-form, in place.

    v = (w b + mu1 t) / (w^2 + mu1) with t = M x + a_v and ``wp``, ``bp`` the sensor
    weights and measurement zero-padded to the plane (so off the sensor v = t).

    Returns
    -------
    data_sq, r2, s2, n2, d2 : float
        ||w C M x - b||^2 and (mode 2) the balancing terms of the split.
    """
    n0, n1 = mx.shape
    mu1 = np.float32(mu1)
    data = 0.0
    r2 = 0.0
    s2 = 0.0
    n2 = 0.0
    d2 = 0.0
    for i in prange(n0):
        dr = np.float32(0.0)
        rr = np.float32(0.0)
        ss = np.float32(0.0)
        nn = np.float32(0.0)
        dd = np.float32(0.0)
        for j in range(n1):
            g = mx[i, j]
            q = qv[i, j]
            qn, a, zz, res = data_split(g, q, wp[i, j], bp[i, j], mu1)
            dr += res
            if mode == 2:
                rv, sv, nv, dv = balance_terms(g, q, a, zz, av[i, j])
                rr += rv
                ss += sv
                nn += nv
                dd += dv
            if mode != 0:
                av[i, j] = a
            qv[i, j] = qn
        data += dr
        r2 += rr
        s2 += ss
        n2 += nn
        d2 += dd
    return data, r2, s2, n2, d2


@njit(inline="always")
def _vox(x, quz, quy, qux, qw, auz, auy, aux, aw, z, i, j, ip, jp, hz, l1thr, tvthr, lo,
         use_tv, mode):
    """One voxel of :func:`admm_split_volume`; returns its 10 reduction terms."""
    zero = np.float32(0.0)
    ninf = np.float32(-np.inf)
    ru = su = nu = du = rw = sw = nw = dw = zero
    g = x[z, i, j]
    q = qw[z, i, j]
    qn, a, zz = shrink_split(g, q, l1thr, lo)
    qw[z, i, j] = qn
    if mode == 2:
        rw, sw, nw, dw = balance_terms(g, q, a, zz, aw[z, i, j])
    if mode != 0:
        aw[z, i, j] = a
    gy = x[z, ip, j] - g
    gx = x[z, i, jp] - g
    gz = x[z + 1, i, j] - g if hz else zero
    tv = abs(gy) + abs(gx) + abs(gz)
    if use_tv:
        q = qux[z, i, j]
        qn, a, zz = shrink_split(gx, q, tvthr, ninf)
        qux[z, i, j] = qn
        if mode == 2:
            ru, su, nu, du = balance_terms(gx, q, a, zz, aux[z, i, j])
        if mode != 0:
            aux[z, i, j] = a
        q = quy[z, i, j]
        qn, a, zz = shrink_split(gy, q, tvthr, ninf)
        quy[z, i, j] = qn
        if mode == 2:
            r2, s2, n2, d2 = balance_terms(gy, q, a, zz, auy[z, i, j])
            ru, su, nu, du = ru + r2, su + s2, nu + n2, du + d2
        if mode != 0:
            auy[z, i, j] = a
        if hz:
            q = quz[z, i, j]
            qn, a, zz = shrink_split(gz, q, tvthr, ninf)
            quz[z, i, j] = qn
            if mode == 2:
                r2, s2, n2, d2 = balance_terms(gz, q, a, zz, auz[z, i, j])
                ru, su, nu, du = ru + r2, su + s2, nu + n2, du + d2
            if mode != 0:
                auz[z, i, j] = a
    return (tv, max(g, zero) if lo == zero else abs(g), ru, su, nu, du, rw, sw, nw, dw)


@njit(inline="always")
def _add10(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5],
            a[6] + b[6], a[7] + b[7], a[8] + b[8], a[9] + b[9])


@njit(**PARALLEL_FAST)
def admm_split_volume(x, quz, quy, qux, qw, l1thr, tvthr, use_tv, nonneg, mode,
                      auz, auy, aux, aw, rows):
    """The w (identity: non-negativity and l1) and u (3D TV) splits, fused, in place.

    w = max(soft(x + a_w, l1 / mu3), 0) (without ``nonneg``: the soft threshold
    alone) -- the exact prox of ``l1 ||w||_1 + 1_+(w)``; u = soft(Psi x + a_u, tau / mu2)
    with Psi the forward differences along z (no wrap: the last plane has none, its
    q stays 0), y and x (circular).

    ``rows`` is a (n_z * P0, 10) float64 scratch for the per-row sums.

    Returns
    -------
    ndarray, shape (10,), float64
        [TV(x), ||x_+||_1 (x_+ = max(x, 0) with ``nonneg``, else x: the l1 norm of the
        estimate x gives), then for u and w: r^2, s^2, sum max(g^2, z^2), ||a||^2]
        (the balancing terms in mode 2 only).
    """
    nz, n0, n1 = x.shape
    lo = np.float32(0.0) if nonneg else np.float32(-np.inf)
    l1thr = np.float32(l1thr)
    tvthr = np.float32(tvthr)
    for zi in prange(nz * n0):
        z = zi // n0
        i = zi - z * n0
        ip = i + 1 if i < n0 - 1 else 0
        hz = z + 1 < nz
        z0 = np.float32(0.0)
        acc = (z0, z0, z0, z0, z0, z0, z0, z0, z0, z0)
        for j in range(n1 - 1):
            acc = _add10(acc, _vox(x, quz, quy, qux, qw, auz, auy, aux, aw, z, i, j, ip,
                                   j + 1, hz, l1thr, tvthr, lo, use_tv, mode))
        acc = _add10(acc, _vox(x, quz, quy, qux, qw, auz, auy, aux, aw, z, i, n1 - 1, ip,
                               0, hz, l1thr, tvthr, lo, use_tv, mode))
        for k in range(10):
            rows[zi, k] = acc[k]
    out = np.zeros(10)
    for zi in range(nz * n0):
        for k in range(10):
            out[k] += rows[zi, k]
    return out


@njit(**PARALLEL_FAST)
def admm_rhs_3d(quz, quy, qux, qw, out, mu2, mu3, use_tv):
    """out = mu2 Psi^T q_u + mu3 q_w (Psi^T of the forward differences of
    :func:`admm_split_volume`: circular laterally, no wrap in z)."""
    nz, n0, n1 = qw.shape
    mu2 = np.float32(mu2)
    mu3 = np.float32(mu3)
    for zi in prange(nz * n0):
        z = zi // n0
        i = zi - z * n0
        im = i - 1 if i > 0 else n0 - 1
        for j in range(n1):
            jm = j - 1 if j > 0 else n1 - 1
            val = mu3 * qw[z, i, j]
            if use_tv:
                d = qux[z, i, jm] - qux[z, i, j] + quy[z, im, j] - quy[z, i, j] - quz[z, i, j]
                if z > 0:
                    d += quz[z - 1, i, j]
                val += mu2 * d
            out[z, i, j] = val


@njit(**PARALLEL_FAST)
def admm_xupdate_3d(spec, h, d_lat, mu1, mu2, mu3, nblocks):
    """The x-update of App. A.3 at every lateral frequency, exactly, in place.

    At one lateral frequency f the system across depth is

        (mu1 conj(h) h^T + B) X = R + mu1 conj(h) Qv,   B = mu2 (L_z + d_lat(f) I) + mu3 I

    with h = (H_z(f))_z the PSF spectra, L_z the depth Laplacian D^T D of the
    non-wrapping forward differences (tridiagonal: 1, 2, ..., 2, 1 on the diagonal,
    -1 off it) and d_lat(f) the lateral |F Psi|^2. B is real, symmetric, strictly
    diagonally dominant and tridiagonal: one Thomas factorisation solves
    B y = rhs and B g = conj(h); Sherman-Morrison then gives
    X = y - g mu1 (h^T y) / (1 + mu1 h^T g) and h^T X = (h^T y) / (1 + mu1 h^T g)
    (h^T g = conj(h)^H B^-1 conj(h) > 0). O(n_z) per frequency; ``mu2 = 0`` (no TV)
    makes B = mu3 I.

    Parameters
    ----------
    spec : ndarray, complex64, shape (n_z + 1, F0, F1)
        In: planes 0..n_z-1 the spectrum R of the right-hand side
        mu2 Psi^T q_u + mu3 q_w, plane n_z the spectrum Qv of q_v.
        Out: planes 0..n_z-1 the solution X, plane n_z the spectrum h^T X of M x.
    h : ndarray, complex64, shape (n_z, F0, F1)
    d_lat : ndarray, float32, shape (F0, F1)
    mu1, mu2, mu3 : float
    nblocks : int
        Row blocks run in parallel (each allocates its O(n_z F1) scratch once).
    """
    nz, n0, n1 = h.shape
    mu1 = np.float32(mu1)
    mu2 = np.float32(mu2)
    mu3 = np.float32(mu3)
    off = -mu2
    one = np.float32(1.0)
    nblocks = max(1, min(n0, nblocks))
    per = (n0 + nblocks - 1) // nblocks
    for blk in prange(nblocks):
        cp = np.empty((nz, n1), np.float32)
        ys = np.empty((nz, n1), np.complex64)
        gs = np.empty((nz, n1), np.complex64)
        s1 = np.empty(n1, np.complex64)
        s2 = np.empty(n1, np.float32)
        ep = np.empty(n1, np.float32)
        for i in range(blk * per, min(n0, (blk + 1) * per)):
            # forward sweep of the Thomas algorithm, vectorised along j. The pivots
            # m_k are tracked through their excess e_k = m_k - mu2 (interior rows):
            # m_k = c + mu2 deg_k - mu2^2 / m_{k-1} cancels catastrophically when
            # mu3 << mu2 (B is then nearly singular at DC), this form only adds
            # positive terms: e_k = c + mu2 e_{k-1} / m_{k-1}.
            for k in range(nz):
                last = k == nz - 1
                for j in range(n1):
                    c = mu3 + mu2 * d_lat[i, j]
                    hc = h[k, i, j].conjugate()
                    r = spec[k, i, j] + mu1 * hc * spec[nz, i, j]
                    if k == 0:
                        e = c
                        m = c if last else c + mu2
                        inv = one / m
                        ys[k, j] = r * inv
                        gs[k, j] = hc * inv
                    else:
                        e = c - ep[j] * cp[k - 1, j]  # c + mu2 e_{k-1} / m_{k-1}
                        m = e if last else e + mu2
                        inv = one / m
                        ys[k, j] = (r - off * ys[k - 1, j]) * inv
                        gs[k, j] = (hc - off * gs[k - 1, j]) * inv
                    ep[j] = e
                    cp[k, j] = off * inv
            # back substitution, accumulating h^T y and h^T g
            for j in range(n1):
                hh = h[nz - 1, i, j]
                s1[j] = hh * ys[nz - 1, j]
                s2[j] = (hh * gs[nz - 1, j]).real
            for k in range(nz - 2, -1, -1):
                for j in range(n1):
                    c = cp[k, j]
                    y = ys[k, j] - c * ys[k + 1, j]
                    g = gs[k, j] - c * gs[k + 1, j]
                    ys[k, j] = y
                    gs[k, j] = g
                    hh = h[k, i, j]
                    s1[j] += hh * y
                    s2[j] += (hh * g).real
            for j in range(n1):
                den = one / (one + mu1 * s2[j])
                s1[j] *= den
                spec[nz, i, j] = s1[j]  # h^T X = h^T y / (1 + mu1 h^T g)
                s1[j] *= mu1
            for k in range(nz):
                for j in range(n1):
                    spec[k, i, j] = ys[k, j] - s1[j] * gs[k, j]
