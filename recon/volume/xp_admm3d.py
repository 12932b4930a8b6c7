"""3D ADMM with 3D TV, l1 and non-negativity on any array-API backend.

The algorithm of :func:`recon.volume.admm3d` (Kuo 2020, Eq. 4.5 / App. A.3) iteration
for iteration: q-form splits (v on the padded plane, w = x, u = the z, y, x forward
differences, no wrap in z), residual balancing, and the exact per-frequency x-update
(tridiagonal Thomas solve across depth and Sherman-Morrison,
:func:`recon.volume._admm_kernels3d.admm_xupdate_3d`), vectorised over the lateral
frequencies instead of looped in numba.
"""

from __future__ import annotations

import math

from ..backend import total
from ..solvers.common import SolveResult
from ..solvers.xp_admm import _rescale
from ..solvers.xp_common import (
    XpMonitor,
    balance_terms,
    check_measurement_xp,
    data_split,
    shrink_split,
)
from ..xp_operators import XpVolumeConvolution

__all__ = ["admm3d_xp", "memory_bytes", "x_update"]


def memory_bytes(n_z: int, padded_shape: tuple[int, int], use_tv: bool = True) -> int:
    """Peak device memory of :func:`admm3d_xp` in bytes (an estimate with margin).

    Volumes of ``(n_z, P0, P1)`` float32: x, q_w, the stored dual a_w, with TV three
    q's and three duals, and about six temporaries of the split pass; complex
    half-spectra (about half a float32 volume's elements, twice the bytes): the PSF
    spectra, the batched spectrum of [R, q_v] and the Thomas sweep's two stacks.
    """
    vol = 4 * n_z * padded_shape[0] * padded_shape[1]
    volumes = 3 + (6 if use_tv else 0) + 6
    spectra = 4 * vol * (padded_shape[1] // 2 + 1) / padded_shape[1] * 2
    return int(volumes * vol + spectra)


def x_update(xp, spec, h, d_lat, mu1: float, mu2: float, mu3: float):
    """The exact x-update at every lateral frequency (see
    :func:`recon.volume._admm_kernels3d.admm_xupdate_3d`: same pivots, same order).

    Parameters
    ----------
    spec : array, complex64, (n_z + 1, F0, F1)
        R (planes 0..n_z-1) and Qv (plane n_z).
    h : array, complex64, (n_z, F0, F1)
        PSF spectra.
    d_lat : array, float32, (F0, F1)
    mu1, mu2, mu3 : float
        ``mu2 = 0`` without TV.

    Returns
    -------
    array, complex64, (n_z + 1, F0, F1)
        X (planes 0..n_z-1) and ``h^T X`` (plane n_z).
    """
    nz = h.shape[0]
    off = -mu2
    c = mu3 + mu2 * d_lat
    qv = spec[nz, ...]
    ys, gs, cps = [], [], []
    e_prev = None
    for k in range(nz):
        last = k == nz - 1
        hc = xp.conj(h[k, ...])
        r = spec[k, ...] + mu1 * hc * qv
        if k == 0:
            e = c
        else:
            e = c - e_prev * cps[k - 1]  # c + mu2 e_{k-1} / m_{k-1}
        inv = 1.0 / (e if last else e + mu2)
        if k == 0:
            ys.append(r * inv)
            gs.append(hc * inv)
        else:
            ys.append((r - off * ys[k - 1]) * inv)
            gs.append((hc - off * gs[k - 1]) * inv)
        e_prev = e
        cps.append(off * inv)
    s1 = h[nz - 1, ...] * ys[nz - 1]
    s2 = xp.real(h[nz - 1, ...] * gs[nz - 1])
    for k in range(nz - 2, -1, -1):
        ys[k] = ys[k] - cps[k] * ys[k + 1]
        gs[k] = gs[k] - cps[k] * gs[k + 1]
        s1 = s1 + h[k, ...] * ys[k]
        s2 = s2 + xp.real(h[k, ...] * gs[k])
    s1 = s1 * (1.0 / (1.0 + mu1 * s2))
    return xp.stack([*(ys[k] - (mu1 * s1) * gs[k] for k in range(nz)), s1])


def _differences(xp, x):
    """Forward differences along z (no wrap: zero on the last plane), y and x."""
    gz = xp.concat([x[1:, ...] - x[:-1, ...], xp.zeros_like(x[:1, ...])], axis=0)
    return gz, xp.roll(x, -1, axis=1) - x, xp.roll(x, -1, axis=2) - x


def admm3d_xp(plan, b, *, iterations: int, tv: float, l1: float, nonneg: bool,
              penalty, mu0) -> SolveResult:
    """3D ADMM of :func:`recon.volume.admm3d` on ``b``'s backend (validated parameters).

    Parameters
    ----------
    plan : VolumeAdmmPlan
        The NumPy path's plan (:class:`recon.volume.VolumeAdmmPlan`): its operator's
        spectra and weights and its lateral ``|F Psi|^2`` move to ``b``'s device.
    b : array (array API), float32, ``op.shape_out``
    iterations : int
    tv, l1 : float
    nonneg : bool
    penalty : AdmmPenalty
    mu0 : (mu1, mu2, mu3)
        Initial penalties.

    Returns
    -------
    SolveResult
        ``x`` (n_z, P0, P1) on ``b``'s device; history as the NumPy path's.

    Raises
    ------
    DivergenceError, ReconInputError
        As :func:`recon.volume.admm3d`.
    """
    op = plan.op
    xop = XpVolumeConvolution(op, b)
    xp = xop.xp
    b = check_measurement_xp(b, op.shape_out)
    nz, shape = op.n_z, xop.padded_shape
    bp, wp = xop.pad(b), xop.wp
    d_lat = xop.asarray(plan.d_lat)
    use_tv = tv > 0
    mu1, mu2, mu3 = mu0
    zeros = xp.zeros(op.shape_in, dtype=xp.float32, device=xop.device)
    x = qw = quz = quy = qux = zeros
    aw = auz = auy = aux = zeros
    mx = qv = av = xp.zeros(shape, dtype=xp.float32, device=xop.device)
    last_balance = penalty.last_balance(iterations)
    mon = XpMonitor(xp, total(xp, b * b), "3D ADMM")
    mus = [(mu1, mu2, mu3)]
    for k in range(iterations):
        mon.start()
        if k == last_balance and k > 0:  # balancing over: release the stored duals
            av, aw = mx, x
            auz = auy = aux = x
        mode = penalty.mode(k, last_balance)
        qv_new, a_v, z_v, r = data_split(mx, qv, wp, bp, mu1)
        qw_new, a_w, z_w = shrink_split(xp, x, qw, l1 / mu3, nonneg)
        g = _differences(xp, x)
        tv_x = sum(total(xp, xp.abs(d)) for d in g)
        l1_x = total(xp, xp.abs(x))
        data_sq = total(xp, r * r)
        qs, duals = (quz, quy, qux), (auz, auy, aux)
        if use_tv:
            u = [shrink_split(xp, d, q, tv / mu2, False) for d, q in zip(g, qs, strict=True)]
        if mode == 2:
            t_v = balance_terms(xp, mx, qv, a_v, z_v, av)
            t_w = balance_terms(xp, x, qw, a_w, z_w, aw)
            if use_tv:
                t_u = [balance_terms(xp, d, q, s[1], s[2], a)
                       for d, q, s, a in zip(g, qs, u, duals, strict=True)]
                t_u = tuple(sum(t[i] for t in t_u) for i in range(4))
        if mode != 0:
            av, aw = a_v, a_w
            if use_tv:
                auz, auy, aux = (s[1] for s in u)
        qv, qw = qv_new, qw_new
        if use_tv:
            quz, quy, qux = (s[0] for s in u)
        if mode == 2:
            new = [penalty.balanced(mu1, *t_v),
                   penalty.balanced(mu2, *t_u) if use_tv else mu2,
                   penalty.balanced(mu3, *t_w)]
            if tuple(new) != (mu1, mu2, mu3):
                qv = _rescale(qv, av, mu1, new[0])
                qw = _rescale(qw, aw, mu3, new[2])
                if use_tv:
                    quz, quy, qux = (_rescale(q, a, mu2, new[1])
                                     for q, a in ((quz, auz), (quy, auy), (qux, aux)))
                mu1, mu2, mu3 = new
                mus.append((mu1, mu2, mu3))
        objective = 0.5 * data_sq + tv * tv_x + l1 * l1_x
        rhs = mu3 * qw
        if use_tv:
            div = (xp.roll(qux, 1, axis=2) - qux + xp.roll(quy, 1, axis=1) - quy - quz
                   + xp.roll(quz, 1, axis=0))  # quz's last plane is 0: no wrap in z
            rhs = rhs + mu2 * div
        spec = xp.fft.rfftn(xp.concat([rhs, qv[None, ...]], axis=0), axes=(-2, -1))
        spec = x_update(xp, spec, xop.spectra, d_lat, mu1, mu2 if use_tv else 0.0, mu3)
        stack = xp.fft.irfftn(spec, s=shape, axes=(-2, -1))
        del spec
        x, mx = stack[:nz, ...], stack[nz, ...]
        mon.record(objective, data_sq, x=x, hint="try method fista3d or smaller TV / l1 weights")
    if nonneg:
        x = xp.clip(x, min=0.0)
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    final = 0.5 * data_sq
    if tv:
        final += tv * sum(total(xp, xp.abs(d)) for d in _differences(xp, x))
    if l1:
        final += l1 * total(xp, xp.abs(x))
    mon.history.extra["mu"] = [list(m) for m in mus]
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm,
                       {"tv": tv, "l1": l1, "nonneg": nonneg, "mu_initial": list(mus[0]),
                        "mu_final": [mu1, mu2, mu3], "balance": penalty.balance,
                        "iterations": iterations, "iterations_used": iterations,
                        "ffts_per_iteration": {"rfft2": nz + 1, "irfft2": nz + 1},
                        "backend": xp.__name__})
