"""2D ADMM with crop, TV, l1 and non-negativity splits on any array-API backend.

The algorithm of :func:`recon.solvers.admm.admm` (Kuo 2020, Eq. 4.5 / App. A.3;
Antipa et al. 2018), iteration for iteration: the same q-form splits, the same
residual balancing (:class:`recon.solvers.AdmmPenalty`), the same diagonal x-update in
Fourier space (2 rfft2 + 2 irfft2, batched in pairs), written with whole-array
operations instead of the fused numba passes.

:class:`XpAdmmPlan` and :class:`XpAdmmState` are :class:`recon.solvers.admm.AdmmPlan`
and :class:`~recon.solvers.admm.AdmmState` on a device, with the same interface
(``zeros``, ``warm``, ``run``, ``objective``): the automatic weight's warm-started path
(:func:`recon.auto.weight.admm_auto`) runs on them with every iterate kept on the
device between its solves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backend import array_namespace, device_of
from ..errors import ReconInputError
from ..xp_operators import XpConvolution
from .common import SolveResult
from .penalty import AdmmPenalty, admm_result, tie_nonneg_penalty
from .xp_common import (
    XpMonitor,
    balance_terms,
    check_measurement_xp,
    data_split,
    shrink_split,
    total,
    tv_circular,
)

__all__ = ["XpAdmmPlan", "XpAdmmState", "XpPlanBase", "admm_xp", "fourier_x_update",
           "memory_bytes", "run_admm_xp"]


def memory_bytes(padded_shape: tuple[int, int]) -> int:
    """Peak device memory of :func:`admm_xp` (bytes): about 24 float32 planes of the
    padded grid (x, M x, five q's, four stored duals, temporaries of the split pass)
    and 6 complex half-spectra (the batched pair and the operator's)."""
    plane = 4 * padded_shape[0] * padded_shape[1]
    return 24 * plane + 6 * plane


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


class XpPlanBase:
    """What the 2D and 3D generic ADMM plans share (:class:`XpAdmmPlan`,
    :class:`recon.volume.xp_admm3d.XpVolumeAdmmPlan`): the ``plan_of`` maker and the
    warm start. A subclass has ``xp``, ``xop``, ``zeros(mu, use_tv)`` and
    ``tv_splits(x) -> {name: G_u x}`` for its TV splits."""

    @classmethod
    def maker(cls, like, numpy_plan_of):
        """``plan_of(op) -> plan`` on ``like``'s device from the NumPy plans of
        ``numpy_plan_of`` (e.g. :meth:`recon.solvers.admm.AdmmPlan.of`), for
        :func:`recon.auto.weight.admm_auto`."""
        return lambda op: cls(numpy_plan_of(op), like)

    def warm(self, x, mu, use_tv: bool):
        """A state at the primal ``x`` (the object grid, on the device or the host)
        with zero duals (q_i = G_i x, :meth:`recon.solvers.admm.AdmmPlan.warm`)."""
        state = self.zeros(mu, use_tv)
        if x is None:
            return state
        xp = self.xp
        x = xp.asarray(self.xop.asarray(x) if isinstance(x, np.ndarray) else x, copy=True,
                       dtype=xp.float32)
        state.x = x
        state.mx = state.qv = self.xop.convolve_full(x)
        state.qw = xp.clip(x, min=0.0)
        if use_tv:
            for name, q in self.tv_splits(x).items():
                setattr(state, name, q)
        return state


class XpAdmmPlan(XpPlanBase):
    """:class:`recon.solvers.admm.AdmmPlan` on the device of ``like``.

    The operator's spectrum and weights and the power spectra are copied to the
    device once per NumPy plan and device (kept on the plan: a live view reuses its
    plan frame after frame).

    Parameters
    ----------
    plan : AdmmPlan
        The NumPy path's plan.
    like : array
        Any array of the target backend and device.

    Attributes
    ----------
    plan : AdmmPlan
    op : ConvolutionOperator
        ``plan.op`` (the NumPy operator: validation, crop, shapes).
    xop : XpConvolution
        The operator on the device.
    h_pow, d_pow : array, float32, (P0, P1 // 2 + 1)
        On the device.
    x_update : callable
        :func:`fourier_x_update`, or the plan's own: a plan with another x-update names
        it (``plan.device_parts(like)`` -> operator, x-update:
        :meth:`recon.spatial.SpatialAdmmPlan.device_parts`).
    """

    def __init__(self, plan, like):
        key = (array_namespace(like).__name__, str(device_of(like)))
        cache = plan.__dict__.setdefault("_device_copies", {})
        if key not in cache:
            parts = getattr(plan, "device_parts", None)
            xop, x_update = (parts(like) if parts is not None
                             else (XpConvolution(plan.op, like), fourier_x_update))
            cache[key] = (xop, xop.asarray(plan.h_pow), xop.asarray(plan.d_pow), x_update)
        self.plan, self.op = plan, plan.op
        self.xop, self.h_pow, self.d_pow, self.x_update = cache[key]
        self.xp, self.shape = self.xop.xp, self.xop.padded_shape

    def zeros(self, mu, use_tv: bool) -> XpAdmmState:
        """The cold start: everything zero, penalties ``mu``."""
        z = self.xp.zeros(self.shape, dtype=self.xp.float32, device=self.xop.device)
        state = XpAdmmState(z, z, z, z, z, z, [z, z, z, z], tuple(mu), None, use_tv)
        state.set_penalties(self, mu)
        return state

    def tv_splits(self, x) -> dict:
        """G_u x of the TV splits: forward differences along columns and rows."""
        xp = self.xp
        return {"qux": xp.roll(x, -1, axis=1) - x, "quy": xp.roll(x, -1, axis=0) - x}

    def run(self, b, state: XpAdmmState, *, iterations: int, tv: float, l1: float = 0.0,
            final: bool = True) -> SolveResult:
        """:func:`run_admm_xp` from ``state`` (updated in place)."""
        return run_admm_xp(self, b, state, iterations=iterations, tv=tv, l1=l1, final=final)

    def objective(self, b, x, *, tv: float, l1: float, b_norm: float) -> tuple[float, float]:
        """:func:`recon.solvers.admm.objective_of` on the device."""
        xp = self.xp
        r = self.xop.forward(x) - b
        data_sq = total(xp, r * r)
        objective = 0.5 * data_sq + tv * tv_circular(xp, x, (0, 1)) + l1 * total(xp, x)
        return objective, float(np.sqrt(data_sq)) / b_norm


@dataclass
class XpAdmmState:
    """:class:`recon.solvers.admm.AdmmState` on a device: the primal ``x`` and ``mx``
    (M x), the q's of the splits (``qv`` crop, ``qux`` / ``quy`` TV, ``qw``
    non-negativity), the stored scaled duals ``a`` (a_v, a_ux, a_uy, a_w), the
    penalties and ``inv_den``; arrays float32 (P0, P1) (``inv_den`` the half-spectrum).
    The arrays are replaced, not written in place."""

    x: object
    mx: object
    qv: object
    qux: object
    quy: object
    qw: object
    a: list
    mu: tuple
    inv_den: object
    use_tv: bool

    def scale(self, factor: float) -> None:
        """Multiply x, M x and every q by ``factor`` (:meth:`AdmmState.scale
        <recon.solvers.admm.AdmmState.scale>`: the measurement's scale changed, a live
        view's next frame); the duals a and the penalties stay."""
        f = float(np.float32(factor))
        for name in ("x", "mx", "qv", "qux", "quy", "qw"):
            setattr(self, name, getattr(self, name) * f)

    def set_penalties(self, plan: XpAdmmPlan, mu) -> None:
        """Adopt ``mu`` and recompute ``inv_den`` = 1 / (mu1 |H|^2 [+ mu2 |F Psi|^2] + mu3)."""
        self.mu = tuple(mu)
        mu1, mu2, mu3 = self.mu
        den = mu1 * plan.h_pow + mu3
        self.inv_den = 1.0 / (den + mu2 * plan.d_pow if self.use_tv else den)


def run_admm_xp(plan: XpAdmmPlan, b, state: XpAdmmState, *, iterations: int, tv: float,
                l1: float = 0.0, penalty: AdmmPenalty | None = None, stop=None,
                final: bool = True) -> SolveResult:
    """:func:`recon.solvers.admm.run_admm` on the device: ``iterations`` ADMM iterations
    from ``state`` (updated: on return the last iterate, x before the clip).

    Parameters
    ----------
    plan : XpAdmmPlan
    b : array (array API), float32, ``op.shape_out``
        Scaled, weighted measurement on the plan's device.
    state : XpAdmmState
    iterations : int
    tv, l1 : float
        Weights (validated, >= 0); ``state.use_tv`` must equal ``tv > 0``.
    penalty : AdmmPenalty, optional
        Residual balancing (default ``AdmmPenalty()``); the state carries the penalties.
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping).
    final : bool
        Evaluate the estimate's objective and residual (one forward model); False
        reports the last iteration's from the history.

    Returns
    -------
    SolveResult
        ``x`` (P0, P1) float32 on ``b``'s device; history and parameters as the NumPy
        path's.

    Raises
    ------
    DivergenceError, ReconInputError
        As :func:`recon.solvers.admm.run_admm`.
    """
    op, xop, xp = plan.op, plan.xop, plan.xp
    penalty = AdmmPenalty() if penalty is None else penalty
    if state.use_tv != (tv > 0):
        raise ReconInputError(f"ADMM state was made for tv {'> 0' if state.use_tv else '= 0'}"
                              f" but tv={tv}; start from the plan's zeros(mu, tv > 0)")
    b = check_measurement_xp(b, op.shape_out)
    bp, wp = xop.pad(b), xop.wp
    use_tv = state.use_tv
    mu1, mu2, mu3 = state.mu
    ratio = mu3 / mu1
    x, mx, qv, qux, quy, qw = state.x, state.mx, state.qv, state.qux, state.quy, state.qw
    av, aux, auy, aw = state.a
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
                state.set_penalties(plan, new)
                mus.append((mu1, mu2, mu3))
        # the l1 term of the iterate entering this iteration, as the data and TV terms
        l1_x = l1 * total(xp, xp.clip(x, min=0.0)) if l1 > 0 else 0.0
        x, mx = plan.x_update(xop, x, mx, (qv, qux, quy, qw), (mu1, mu2, mu3), state.inv_den,
                              use_tv)
        mon.record(0.5 * data_sq + tv * tv_x + l1_x, data_sq, x=x,
                   hint="try --method fista or a smaller TV weight")
        if stop is not None and stop(mon.history):
            used = k + 1
            break
    state.x, state.mx, state.qv, state.qux, state.quy, state.qw = x, mx, qv, qux, quy, qw
    state.a = [av, aux, auy, aw]
    x = xp.clip(x, min=0.0)
    if final:
        objective, relative = plan.objective(b, x, tv=tv, l1=l1, b_norm=mon.b_norm)
    else:
        objective, relative = mon.history.objective[-1], mon.history.data_residual[-1]
    return admm_result(x, mon.history, objective, relative, tv=tv, l1=l1, mus=mus,
                       penalty=penalty, iterations=iterations, used=used,
                       backend=xp.__name__)


def admm_xp(plan, b, *, iterations: int, tv: float, l1: float, penalty, stop=None,
            state: XpAdmmState | None = None) -> SolveResult:
    """ADMM of :func:`recon.solvers.admm.admm` on ``b``'s backend (validated parameters).

    Parameters
    ----------
    plan : AdmmPlan
        The NumPy path's plan (:class:`recon.solvers.admm.AdmmPlan`): its operator's
        spectrum and weights and its power spectra are moved to ``b``'s device.
    b : array (array API), float32, ``op.shape_out``
        Scaled, weighted measurement on the target device.
    iterations : int
    tv, l1 : float
        Weights (validated, >= 0).
    penalty : AdmmPenalty
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping).
    state : XpAdmmState, optional
        Start from this iterate and its penalties (a live view's warm start; made by
        :meth:`XpAdmmPlan.zeros` of this plan and device, updated in place); default
        the cold start with ``penalty``'s initial penalties.

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
    xplan = XpAdmmPlan(plan, b)
    state = xplan.zeros(penalty.initial(), tv > 0) if state is None else state
    return run_admm_xp(xplan, b, state, iterations=iterations, tv=tv, l1=l1, penalty=penalty,
                       stop=stop)
