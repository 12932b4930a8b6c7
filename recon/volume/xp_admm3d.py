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
from dataclasses import dataclass

from ..backend import total
from ..errors import ReconInputError
from ..solvers.common import SolveResult
from ..solvers.penalty import AdmmPenalty, admm_result
from ..solvers.xp_admm import XpPlanBase, _rescale
from ..solvers.xp_common import (
    XpMonitor,
    balance_terms,
    check_measurement_xp,
    data_split,
    shrink_split,
)
from ..xp_operators import XpVolumeConvolution

__all__ = ["XpVolumeAdmmPlan", "XpVolumeAdmmState", "admm3d_xp", "auto3d_extra_bytes",
           "memory_bytes", "run_admm3d_xp", "x_update"]


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


def auto3d_extra_bytes(n_z: int, padded_shape: tuple[int, int]) -> int:
    """Device memory the automatic 3D weight needs beyond :func:`memory_bytes` (bytes):
    up to 6 volumes (the path's kept estimates, the final solve's best iterate, the
    FISTA final solve's fit measurement) and a second copy of the PSF spectra (the fit
    plan's and the final plan's operators)."""
    vol = 4 * n_z * padded_shape[0] * padded_shape[1]
    return int(6 * vol + 2 * vol * (padded_shape[1] // 2 + 1) / padded_shape[1])


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


class XpVolumeAdmmPlan(XpPlanBase):
    """:class:`recon.volume.VolumeAdmmPlan` on the device of ``like``.

    Parameters
    ----------
    plan : VolumeAdmmPlan
        The NumPy path's plan (operator, lateral ``|F Psi|^2``).
    like : array
        Any array of the target backend and device.

    Attributes
    ----------
    plan : VolumeAdmmPlan
    op : VolumeConvolutionOperator
        ``plan.op`` (validation, crop, shapes).
    xop : XpVolumeConvolution
        The operator on the device (its PSF spectra copied there).
    d_lat : array, float32, (P0, P1 // 2 + 1)
    """

    def __init__(self, plan, like):
        self.plan, self.op = plan, plan.op
        self.xop = XpVolumeConvolution(plan.op, like)
        self.xp = self.xop.xp
        self.d_lat = self.xop.asarray(plan.d_lat)

    def zeros(self, mu, use_tv: bool) -> XpVolumeAdmmState:
        """The cold start: everything zero, penalties ``mu``."""
        xp, dev = self.xp, self.xop.device
        z = xp.zeros(self.op.shape_in, dtype=xp.float32, device=dev)
        plane = xp.zeros(self.xop.padded_shape, dtype=xp.float32, device=dev)
        return XpVolumeAdmmState(z, plane, plane, z, z, z, z, tuple(float(m) for m in mu),
                                 bool(use_tv))

    def tv_splits(self, x) -> dict:
        """G_u x of the 3D TV splits: forward differences along z (no wrap), y, x."""
        return dict(zip(("quz", "quy", "qux"), _differences(self.xp, x), strict=True))

    def run(self, b, state: XpVolumeAdmmState, *, iterations: int, tv: float,
            l1: float = 0.0, final: bool = True) -> SolveResult:
        """:func:`run_admm3d_xp` from ``state`` (updated)."""
        return run_admm3d_xp(self, b, state, iterations=iterations, tv=tv, l1=l1, final=final)

    def objective(self, b, x, *, tv: float, l1: float, b_norm: float) -> tuple[float, float]:
        """Objective of Eq. 4.5 at ``x`` and its relative data residual against ``b``
        (:meth:`recon.volume.VolumeAdmmPlan.objective` on the device)."""
        final, data_sq = _final_objective(self.xp, self.xop, x, b, tv, l1)
        return final, math.sqrt(data_sq) / b_norm


@dataclass
class XpVolumeAdmmState:
    """:class:`recon.volume.admm.VolumeAdmmState` on a device: ``x`` (n_z, P0, P1),
    ``mx`` (M x, P0 x P1), the q's of the crop (``qv``), identity (``qw``) and 3D TV
    (``quz``, ``quy``, ``qux``) splits, float32, and the penalties; the arrays are
    replaced, not written in place."""

    x: object
    mx: object
    qv: object
    qw: object
    quz: object
    quy: object
    qux: object
    mu: tuple
    use_tv: bool


def _final_objective(xp, xop, x, b, tv: float, l1: float) -> tuple[float, float]:
    """:func:`recon.volume.fista.final_objective` on the device: the objective and the
    squared data residual."""
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    final = 0.5 * data_sq
    if tv:
        final += tv * sum(total(xp, xp.abs(d)) for d in _differences(xp, x))
    if l1:
        final += l1 * total(xp, xp.abs(x))
    return final, data_sq


def run_admm3d_xp(plan: XpVolumeAdmmPlan, b, state: XpVolumeAdmmState, *, iterations: int,
                  tv: float, l1: float = 0.0, nonneg: bool = True,
                  penalty: AdmmPenalty | None = None, final: bool = True) -> SolveResult:
    """:func:`recon.volume.admm.run_admm3d` on the device: ``iterations`` 3D ADMM
    iterations from ``state`` (updated: on return the last iterate, x before the clip).

    Parameters
    ----------
    plan : XpVolumeAdmmPlan
    b : array (array API), float32, ``op.shape_out``
        On the plan's device.
    state : XpVolumeAdmmState
        ``state.use_tv`` must equal ``tv > 0``.
    iterations : int
    tv, l1 : float
        Validated weights (>= 0).
    nonneg : bool
    penalty : AdmmPenalty, optional
        Residual balancing (default ``AdmmPenalty()``), over the first
        ``balance_until`` of this call's iterations; the state carries the penalties.
    final : bool
        Evaluate the estimate's objective and residual (one forward model); False
        reports the last iteration's from the history.

    Returns
    -------
    SolveResult
        ``x`` (n_z, P0, P1) on ``b``'s device; history as the NumPy path's.

    Raises
    ------
    DivergenceError, ReconInputError
        As :func:`recon.volume.admm.run_admm3d`.
    """
    op, xop, xp = plan.op, plan.xop, plan.xp
    if state.use_tv != (tv > 0):
        raise ReconInputError(f"3D ADMM state was made for tv {'> 0' if state.use_tv else '= 0'}"
                              f" but tv={tv}; start from the plan's zeros(mu, tv > 0)")
    penalty = AdmmPenalty() if penalty is None else penalty
    b = check_measurement_xp(b, op.shape_out)
    nz, shape = op.n_z, xop.padded_shape
    bp, wp = xop.pad(b), xop.wp
    use_tv = state.use_tv
    mu1, mu2, mu3 = state.mu
    x, mx, qv, qw = state.x, state.mx, state.qv, state.qw
    quz, quy, qux = state.quz, state.quy, state.qux
    zeros = xp.zeros(op.shape_in, dtype=xp.float32, device=xop.device)
    aw = auz = auy = aux = zeros  # the stored duals start at zero in every call
    av = xp.zeros(shape, dtype=xp.float32, device=xop.device)
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
        spec = x_update(xp, spec, xop.spectra, plan.d_lat, mu1, mu2 if use_tv else 0.0, mu3)
        stack = xp.fft.irfftn(spec, s=shape, axes=(-2, -1))
        del spec
        x, mx = stack[:nz, ...], stack[nz, ...]
        mon.record(objective, data_sq, x=x, hint="try method fista3d or smaller TV / l1 weights")
    state.x, state.mx, state.qv, state.qw = x, mx, qv, qw
    state.quz, state.quy, state.qux = quz, quy, qux
    state.mu = (mu1, mu2, mu3)
    if nonneg:
        x = xp.clip(x, min=0.0)
    if final:
        objective, data_sq = _final_objective(xp, xop, x, b, tv, l1)
        relative = math.sqrt(data_sq) / mon.b_norm
    else:
        objective, relative = mon.history.objective[-1], mon.history.data_residual[-1]
    return admm_result(x, mon.history, objective, relative, tv=tv, l1=l1, mus=mus,
                       penalty=penalty, iterations=iterations, used=iterations,
                       nonneg=nonneg, ffts_per_iteration={"rfft2": nz + 1, "irfft2": nz + 1},
                       backend=xp.__name__)


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
        As :func:`run_admm3d_xp` from the cold start; errors as
        :func:`recon.volume.admm3d`'s.
    """
    xplan = XpVolumeAdmmPlan(plan, b)
    return run_admm3d_xp(xplan, b, xplan.zeros(mu0, tv > 0), iterations=iterations, tv=tv,
                         l1=l1, nonneg=nonneg, penalty=penalty)
