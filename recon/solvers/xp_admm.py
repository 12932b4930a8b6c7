"""2D ADMM with crop, TV, l1 and non-negativity splits on any array-API backend.

The algorithm of :func:`recon.solvers.admm.admm` (Kuo 2020, Eq. 4.5 / App. A.3;
Antipa et al. 2018), iteration for iteration: the same q-form splits, the same
residual balancing (:class:`recon.solvers.AdmmPenalty`), the same diagonal x-update in
Fourier space (2 rfft2 + 2 irfft2, batched in pairs), written with whole-array
operations instead of the fused numba passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import array_namespace, device_of
from ..errors import ReconInputError
from ..xp_operators import XpConvolution
from .common import SolveResult
from .penalty import tie_nonneg_penalty
from .xp_common import (
    XpMonitor,
    balance_terms,
    check_measurement_xp,
    data_split,
    shrink_split,
    total,
    tv_circular,
)

__all__ = ["XpAdmmState", "admm_xp", "device_plan", "fourier_x_update", "memory_bytes"]


def memory_bytes(padded_shape: tuple[int, int]) -> int:
    """Peak device memory of :func:`admm_xp` (bytes): about 24 float32 planes of the
    padded grid (x, M x, five q's, four stored duals, temporaries of the split pass)
    and 6 complex half-spectra (the batched pair and the operator's)."""
    plane = 4 * padded_shape[0] * padded_shape[1]
    return 24 * plane + 6 * plane


@dataclass
class XpAdmmState:
    """The ADMM iterate of :func:`admm_xp` carried between solves (a live view's warm
    start): :class:`recon.solvers.admm.AdmmState` on a device.

    Attributes
    ----------
    x, mx : array, float32, (P0, P1)
        Primal iterate (before the non-negativity clip) and M x.
    qv, qux, quy, qw : array, float32, (P0, P1)
        q = z - a of the crop, the two TV and the non-negativity splits.
    av, aux, auy, aw : array, float32, (P0, P1)
        Scaled duals stored by the balancing passes.
    mu : (mu1, mu2, mu3)
        Current penalties.
    use_tv : bool
        Whether the TV splits are in use (``tv > 0``).
    """

    x: object
    mx: object
    qv: object
    qux: object
    quy: object
    qw: object
    av: object
    aux: object
    auy: object
    aw: object
    mu: tuple
    use_tv: bool

    @classmethod
    def zeros(cls, xp, shape: tuple[int, int], device, mu, use_tv: bool) -> XpAdmmState:
        """The cold start: every array zero (x_0 = 0), penalties ``mu``."""
        zero = xp.zeros(shape, dtype=xp.float32, device=device)
        return cls(*(zero,) * 10, tuple(mu), bool(use_tv))

    def scale(self, factor: float) -> None:
        """Multiply x, M x and every q by ``factor`` (:meth:`AdmmState.scale
        <recon.solvers.admm.AdmmState.scale>`: the measurement's scale changed)."""
        f = float(np.float32(factor))
        for name in ("x", "mx", "qv", "qux", "quy", "qw"):
            setattr(self, name, getattr(self, name) * f)


def _rescale(q, a, old: float, new: float):
    """:func:`recon.solvers.penalty.rescale_duals` for one split, out of place."""
    return q + a * (1.0 - old / new) if old != new else q


def fourier_x_update(xop, x, mx, q, mu, inv_den, use_tv: bool):
    """The exact x-update of App. A.3 (:meth:`recon.solvers.admm.AdmmPlan.x_update`):
    a diagonal solve in Fourier space, 2 rfft2 + 2 irfft2 batched in pairs.

    Parameters
    ----------
    xop : XpConvolution
    x, mx : arrays, float32, (P0, P1)
        Not used (the solve is exact); the signature of every plan's x-update.
    q : (qv, qux, quy, qw)
        The splits' q's.
    mu : (mu1, mu2, mu3)
    inv_den : array, float32, (P0, P1 // 2 + 1)
        1 / (mu1 |H|^2 + mu2 |F Psi|^2 + mu3).
    use_tv : bool

    Returns
    -------
    (x, mx) : arrays, float32, (P0, P1)
    """
    xp = xop.xp
    qv, qux, quy, qw = q
    mu1, mu2, mu3 = mu
    # R = mu2 Psi^T q_u + mu3 q_w, then the diagonal solve
    rhs = mu3 * qw
    if use_tv:
        rhs = rhs + mu2 * (xp.roll(qux, 1, axis=1) - qux + xp.roll(quy, 1, axis=0) - quy)
    spectra = xp.fft.rfftn(xp.stack([qv, rhs]), axes=(-2, -1))
    x_hat = (mu1 * xop.spectrum_conj * spectra[0, ...] + spectra[1, ...]) * inv_den
    out = xp.fft.irfftn(xp.stack([xop.spectrum * x_hat, x_hat]), s=xop.padded_shape,
                        axes=(-2, -1))
    return out[1, ...], out[0, ...]


def device_plan(plan, b):
    """The plan's operator, power spectra and x-update on ``b``'s device, made once per
    plan and device (kept on the plan: a live view reuses its plan frame after frame).

    A plan with another x-update names its own (``plan.device_parts(b)`` -> operator,
    x-update: :meth:`recon.spatial.SpatialAdmmPlan.device_parts`).

    Parameters
    ----------
    plan : AdmmPlan
    b : array (array API)
        Any array of the target backend and device.

    Returns
    -------
    (XpConvolution, h_pow, d_pow, x_update)
        The operator on the device, |H|^2 and |F Psi|^2 there (float32,
        (P0, P1 // 2 + 1)), and the x-update (:func:`fourier_x_update`'s signature).
    """
    key = (array_namespace(b).__name__, str(device_of(b)))
    cache = plan.__dict__.setdefault("_device_copies", {})
    if key not in cache:
        parts = getattr(plan, "device_parts", None)
        xop, x_update = (parts(b) if parts is not None
                         else (XpConvolution(plan.op, b), fourier_x_update))
        cache[key] = (xop, xop.asarray(plan.h_pow), xop.asarray(plan.d_pow), x_update)
    return cache[key]


def admm_xp(plan, b, *, iterations: int, tv: float, l1: float, penalty, stop=None,
            state: XpAdmmState | None = None) -> SolveResult:
    """ADMM of :func:`recon.solvers.admm.admm` on ``b``'s backend (validated parameters).

    Parameters
    ----------
    plan : AdmmPlan
        The NumPy path's plan (:class:`recon.solvers.admm.AdmmPlan`): its operator's
        spectrum and weights and its power spectra are moved to ``b``'s device (a
        plan with another x-update, :class:`recon.spatial.SpatialAdmmPlan`, gives its
        generic operator and x-update by ``device_parts``).
    b : array (array API), float32, ``op.shape_out``
        Scaled, weighted measurement on the target device.
    iterations : int
    tv, l1 : float
        Weights (validated, >= 0).
    penalty : AdmmPenalty
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping).
    state : XpAdmmState, optional
        Start from this iterate and its penalties (a warm start, as
        :func:`recon.solvers.admm.run_admm` from an ``AdmmState``) and leave the final
        iterate in it; default a cold start with ``penalty``'s initial penalties.

    Returns
    -------
    SolveResult
        ``x`` on ``b``'s device (P0, P1) float32; history and parameters as the NumPy
        path's.

    Raises
    ------
    DivergenceError, ReconInputError
        As :func:`recon.solvers.admm.admm`; a ``state`` made for the other sign of
        ``tv``.
    """
    op = plan.op
    xop, h_pow, d_pow, x_update = device_plan(plan, b)
    xp = xop.xp
    b = check_measurement_xp(b, op.shape_out)
    shape = xop.padded_shape
    bp, wp = xop.pad(b), xop.wp
    use_tv = tv > 0
    if state is None:
        state = XpAdmmState.zeros(xp, shape, xop.device, penalty.initial(), use_tv)
    if state.use_tv != use_tv:
        raise ReconInputError(f"ADMM state was made for tv {'> 0' if state.use_tv else '= 0'}"
                              f" but tv={tv}; start from XpAdmmState.zeros(..., tv > 0)")
    mu1, mu2, mu3 = state.mu
    ratio = mu3 / mu1

    def inverse_denominator(m1, m2, m3):
        den = m1 * h_pow + m3
        return 1.0 / (den + m2 * d_pow if use_tv else den)

    inv_den = inverse_denominator(mu1, mu2, mu3)
    x, mx, qv, qux, quy, qw = state.x, state.mx, state.qv, state.qux, state.quy, state.qw
    av, aux, auy, aw = state.av, state.aux, state.auy, state.aw
    mon = XpMonitor(xp, total(xp, b * b), "ADMM")
    mus = [(mu1, mu2, mu3)]
    last_balance = penalty.last_balance(iterations)
    used = iterations
    for k in range(iterations):
        mon.start()
        mode = penalty.mode(k, last_balance)
        thr = tv / mu2 if use_tv else 0.0
        qv_new, a_v, z_v, r = data_split(mx, qv, wp, bp, mu1)
        qw_new, a_w, z_w = shrink_split(xp, x, qw, l1 / mu3, True)
        gx = xp.roll(x, -1, axis=1) - x
        gy = xp.roll(x, -1, axis=0) - x
        tv_x = total(xp, xp.abs(gx) + xp.abs(gy))
        if use_tv:
            qux_new, a_ux, z_ux = shrink_split(xp, gx, qux, thr, False)
            quy_new, a_uy, z_uy = shrink_split(xp, gy, quy, thr, False)
        if mode == 2:
            tv_v = balance_terms(xp, mx, qv, a_v, z_v, av)
            tv_w = balance_terms(xp, x, qw, a_w, z_w, aw)
            if use_tv:
                tx = balance_terms(xp, gx, qux, a_ux, z_ux, aux)
                ty = balance_terms(xp, gy, quy, a_uy, z_uy, auy)
                tv_u = tuple(p + q for p, q in zip(tx, ty, strict=True))
        if mode != 0:
            av, aw = a_v, a_w
            if use_tv:
                aux, auy = a_ux, a_uy
        data_sq = total(xp, r * r)
        qv, qw = qv_new, qw_new
        if use_tv:
            qux, quy = qux_new, quy_new
        if mode == 2:
            new = [penalty.balanced(mu1, *tv_v),
                   penalty.balanced(mu2, *tv_u) if use_tv else mu2,
                   penalty.balanced(mu3, *tv_w)]
            tie_nonneg_penalty(new, ratio, use_tv)
            if tuple(new) != (mu1, mu2, mu3):
                qv = _rescale(qv, av, mu1, new[0])
                qw = _rescale(qw, aw, mu3, new[2])
                if use_tv:
                    qux = _rescale(qux, aux, mu2, new[1])
                    quy = _rescale(quy, auy, mu2, new[1])
                mu1, mu2, mu3 = new
                inv_den = inverse_denominator(mu1, mu2, mu3)
                mus.append((mu1, mu2, mu3))
        x, mx = x_update(xop, x, mx, (qv, qux, quy, qw), (mu1, mu2, mu3), inv_den, use_tv)
        l1_x = l1 * total(xp, xp.clip(x, min=0.0)) if l1 > 0 else 0.0
        mon.record(0.5 * data_sq + tv * tv_x + l1_x, data_sq, x=x,
                   hint="try --method fista or a smaller TV weight")
        if stop is not None and stop(mon.history):
            used = k + 1
            break
    state.x, state.mx, state.qv, state.qux, state.quy, state.qw = x, mx, qv, qux, quy, qw
    state.av, state.aux, state.auy, state.aw = av, aux, auy, aw
    state.mu = (mu1, mu2, mu3)
    x = xp.clip(x, min=0.0)
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    objective = 0.5 * data_sq + tv * tv_circular(xp, x, (0, 1)) + l1 * total(xp, x)
    mon.history.extra["mu"] = [list(m) for m in mus]
    return SolveResult(x, mon.history, objective, float(np.sqrt(data_sq)) / mon.b_norm,
                       {"tv": tv, "l1": l1, "mu_initial": list(mus[0]),
                        "mu_final": [mu1, mu2, mu3], "balance": penalty.balance,
                        "iterations": iterations, "iterations_used": used,
                        "backend": xop.xp.__name__})
