"""The generic ADMM kernel set: every ADMM on any array-API backend (2D, 3D, PSF grids).

The loop is the one of every ADMM (:func:`recon.solvers.admm_loop.run_admm`); this
module is its kernel set for arrays of another backend (CuPy, PyTorch, or any
array-API library): :class:`XpKernels` does the split updates of Eq. 4.5 / App. A.3
(Kuo 2020; Antipa et al. 2018) in q-form with whole-array operations -- the same
arithmetic in float32 as the fused numba passes of the NumPy path
(:mod:`recon._kernels`, :mod:`recon.volume._admm_kernels3d`) -- for the 2D and the 3D
model alike, with the plan's regulariser split (:class:`Differences`: TV) and its
x-update.

:class:`XpAdmmPlan` is :class:`recon.solvers.admm.AdmmPlan` on a device (the diagonal
x-update in Fourier space, :func:`fourier_x_update`, or a plan's own:
:meth:`recon.spatial.SpatialAdmmPlan.device_parts`);
:class:`recon.volume.xp_admm3d.XpVolumeAdmmPlan` the volume's. Both have the
interface of the automatic weight (``zeros``, ``warm``, ``run``, ``objective``,
:func:`recon.auto.weight.admm_auto`) and one state class, :class:`XpAdmmState`, kept
on the device between solves (the live view's warm start, the weight path).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import reduce

import numpy as np

from ..backend import array_namespace, device_of
from ..errors import ReconInputError
from ..priors import Prior, TotalVariation, prior_of
from ..xp_operators import XpConvolution
from .admm_loop import AdmmPlanBase, SplitStep
from .xp_common import (
    XpMonitor,
    balance_terms,
    check_measurement_xp,
    data_split,
    forward_difference,
    shrink_split,
    total,
    tv_circular,
)

__all__ = ["IDENTITY", "Differences", "IdentitySplit", "XpAdmmPlan", "XpAdmmState",
           "XpKernels", "XpPlanBase", "fourier_x_update", "memory_bytes"]


def memory_bytes(padded_shape: tuple[int, int]) -> int:
    """Peak device memory of a 2D generic ADMM solve (bytes): about 24 float32 planes
    of the padded grid (x, M x, five q's, four stored duals, temporaries of the split
    pass) and 6 complex half-spectra (the batched pair and the operator's)."""
    plane = 4 * padded_shape[0] * padded_shape[1]
    return 24 * plane + 6 * plane


def _rescale(q, a, old: float, new: float):
    """:func:`recon.solvers.penalty.rescale_duals` for one split, out of place."""
    return q + a * (1.0 - old / new) if old != new else q


@dataclass(frozen=True)
class Differences:
    """The TV split's G_u = Psi for the generic kernel set: forward differences along
    ``axes`` (in that order: one q per axis), circular except along ``open_axis``
    (a volume's depth: zero across the last plane, no wrap).

    The regulariser's seam on the generic path: :class:`XpKernels` soft-thresholds
    ``apply(x)`` (the u-update) and the x-updates use ``adjoint`` (Psi^T q_u).
    """

    axes: tuple[int, ...]
    open_axis: int | None = None

    @property
    def count(self) -> int:
        """Split arrays (one per axis)."""
        return len(self.axes)

    def apply(self, xp, x) -> tuple:
        """Psi x: one difference array per axis, like ``x``."""
        return tuple(forward_difference(xp, x, ax, ax != self.open_axis) for ax in self.axes)

    def adjoint(self, xp, qs):
        """Psi^T q: ``sum_axes roll(q, 1) - q`` (along ``open_axis`` too: its q is zero
        on the last plane, as :meth:`apply` leaves it, so nothing wraps)."""
        return reduce(lambda s, t: s + t,
                      (xp.roll(q, 1, axis=ax) - q for q, ax in zip(qs, self.axes, strict=True)))


#: Psi of the 2D image: circular forward differences along columns, then rows.
DIFFERENCES_2D = Differences((1, 0))


@dataclass(frozen=True)
class IdentitySplit:
    """G_u = I for the priors that act on the image itself (:class:`recon.priors.WaveletPrior`,
    :class:`recon.priors.DncnnPrior`): one split array u = x; |F G_u|^2 = 1 in the
    x-update's denominator."""

    count = 1

    def apply(self, xp, x) -> tuple:
        """(x,)."""
        return (x,)

    def adjoint(self, xp, qs):
        """q itself."""
        (q,) = qs
        return q


#: The identity split (:class:`IdentitySplit`).
IDENTITY = IdentitySplit()


def fourier_x_update(xop, x, mx, q, mu, inv_den, use_tv: bool, differences=DIFFERENCES_2D):
    """The exact x-update of App. A.3 (:meth:`recon.solvers.admm.AdmmPlan.x_update`):
    a diagonal solve in Fourier space, 2 rfft2 + 2 irfft2 batched in pairs.

    Parameters
    ----------
    xop : XpConvolution
    x, mx : arrays, float32, (P0, P1)
        Not used (the solve is exact); the signature of every plan's x-update.
    q : (qv, *qu, qw)
        The splits' q's (qu: qux, quy for TV; one array for an identity split).
    mu : (mu1, mu2, mu3)
    inv_den : array, float32, (P0, P1 // 2 + 1)
        1 / (mu1 |H|^2 + mu2 |F G_u|^2 + mu3).
    use_tv : bool
        Whether there is a u split.
    differences : Differences or IdentitySplit
        G_u of the u split (default the TV's :data:`DIFFERENCES_2D`).

    Returns
    -------
    (x, mx) : arrays, float32, (P0, P1)
    """
    xp = xop.xp
    qv, *qu, qw = q
    mu1, mu2, mu3 = mu
    # R = mu2 G_u^T q_u + mu3 q_w, then the diagonal solve
    rhs = mu3 * qw
    if use_tv:
        rhs = rhs + mu2 * differences.adjoint(xp, qu)
    spectra = xp.fft.rfftn(xp.stack([qv, rhs]), axes=(-2, -1))
    x_hat = (mu1 * xop.spectrum_conj * spectra[0, ...] + spectra[1, ...]) * inv_den
    out = xp.fft.irfftn(xp.stack([xop.spectrum * x_hat, x_hat]), s=xop.padded_shape,
                        axes=(-2, -1))
    return out[1, ...], out[0, ...]


@dataclass
class XpAdmmState:
    """An ADMM iterate on a device (:class:`recon.solvers.admm.AdmmState` and
    :class:`recon.volume.VolumeAdmmState` of the NumPy path): the arrays are replaced,
    not written in place.

    Attributes
    ----------
    x : array, float32, ``op.shape_in``
        The primal iterate (before the non-negativity clip).
    mx : array, float32, (P0, P1)
        M x, uncropped.
    qv : array, float32, (P0, P1)
        q = z - a of the crop split v = M x.
    qu : tuple of arrays like ``x``
        q of the regulariser's splits (one per axis of :class:`Differences`).
    qw : array like ``x``
        q of the identity split w = x (non-negativity, l1).
    mu : (mu1, mu2, mu3)
    inv_den : array or None
        The plan's x-update denominator for ``mu`` (2D: 1 / (mu1 |H|^2 [+ mu2
        |F Psi|^2] + mu3) on the half-spectrum; None for a plan that solves per
        frequency, the volume's).
    use_tv : bool
    """

    x: object
    mx: object
    qv: object
    qu: tuple
    qw: object
    mu: tuple
    inv_den: object
    use_tv: bool

    def scale(self, factor: float) -> None:
        """Multiply x, M x and every q by ``factor`` (:meth:`AdmmState.scale
        <recon.solvers.admm.AdmmState.scale>`: the measurement's scale changed, a live
        view's next frame); the penalties stay."""
        f = float(np.float32(factor))
        self.x, self.mx, self.qv, self.qw = (a * f for a in (self.x, self.mx, self.qv,
                                                             self.qw))
        self.qu = tuple(q * f for q in self.qu)

    def set_penalties(self, plan, mu) -> None:
        """Adopt ``mu`` and the plan's x-update denominator for it."""
        self.mu = tuple(mu)
        self.inv_den = plan.inverse_denominator(self.mu, self.use_tv)


class XpKernels:
    """The generic kernel set (:class:`~recon.solvers.admm_loop.AdmmKernels`) of any
    ADMM plan on an array-API backend: whole-array split updates in q-form.

    Per iteration (:meth:`splits`): v = (w b + mu1 t) / (w^2 + mu1) on the padded plane
    (:func:`~recon.solvers.xp_common.data_split`), w = max(soft(t, l1 / mu3), 0)
    (without ``nonneg`` the soft threshold alone), u = the plan's prior's prox of
    G_u x + a_u (:attr:`XpPlanBase.prior`; TV: soft(Psi x + a_u, tv / mu2) with the
    plan's Psi, :class:`Differences`; ``tv`` is the prior's weight), t = G x + a each
    time; then the plan's
    x-update (``plan.x_update(state) -> (x, mx)``). The scaled duals are stored for
    balancing (zero at the start of each solve; only mode-1 passes write what the
    next mode-2 pass reads).

    Parameters
    ----------
    plan : XpPlanBase
        :class:`XpAdmmPlan` or :class:`recon.volume.xp_admm3d.XpVolumeAdmmPlan`.
    b : array (array API), float32, ``op.shape_out``
        Scaled, weighted measurement on the plan's device.
    state : XpAdmmState
    tv, l1 : float
        Validated weights (>= 0).
    nonneg : bool

    Raises
    ------
    ReconInputError
        A misshapen, non-finite or all-zero ``b``.
    """

    def __init__(self, plan, b, state: XpAdmmState, *, tv: float, l1: float, nonneg: bool):
        xp = self.xp = plan.xp
        self.b = check_measurement_xp(b, plan.op.shape_out)
        self.bp, self.wp = plan.xop.pad(self.b), plan.xop.wp
        self.plan, self.state, self.tv, self.l1, self.nonneg = plan, state, tv, l1, nonneg
        self.monitor = XpMonitor(xp, total(xp, self.b * self.b), plan.label)
        self.report = {"ffts_per_iteration": plan.ffts_per_iteration(), "backend": xp.__name__}
        self.av = xp.zeros_like(state.mx)
        self.aw = xp.zeros_like(state.x)
        self.au = tuple(self.aw for _ in state.qu)

    def splits(self, mode: int) -> SplitStep:
        """The v, w and u updates of the state, whole arrays."""
        xp, st = self.xp, self.state
        mu1, mu2, mu3 = st.mu
        qv, a_v, z_v, r = data_split(st.mx, st.qv, self.wp, self.bp, mu1)
        qw, a_w, z_w = shrink_split(xp, st.x, st.qw, self.l1 / mu3, self.nonneg)
        prior = self.plan.prior
        g = self.plan.differences.apply(xp, st.x)
        tv_x = prior.value(xp, st.x, g) if self.tv > 0 else 0.0
        l1_x = 0.0
        if self.l1 > 0:  # of the estimate the entering iterate gives
            l1_x = total(xp, xp.clip(st.x, min=0.0) if self.nonneg else xp.abs(st.x))
        data_sq = total(xp, r * r)
        u = None
        if st.use_tv:  # the prior's u-update: z = prox(G_u x + a_u), q = z - a_u
            a_u = tuple(d - q for d, q in zip(g, st.qu, strict=True))
            z_u = prior.prox(xp, tuple(d + a for d, a in zip(g, a_u, strict=True)),
                             self.tv, mu2)
            u = [(z - a, a, z) for z, a in zip(z_u, a_u, strict=True)]
        balance = None
        if mode == 2:
            t_u = None
            if u is not None:
                t_u = reduce(lambda s, t: tuple(p + q for p, q in zip(s, t, strict=True)),
                             (balance_terms(xp, d, q, s[1], s[2], a)
                              for d, q, s, a in zip(g, st.qu, u, self.au, strict=True)))
            balance = (balance_terms(xp, st.mx, st.qv, a_v, z_v, self.av), t_u,
                       balance_terms(xp, st.x, st.qw, a_w, z_w, self.aw))
        if mode != 0:
            self.av, self.aw = a_v, a_w
            if u is not None:
                self.au = tuple(s[1] for s in u)
        st.qv, st.qw = qv, qw
        if u is not None:
            st.qu = tuple(s[0] for s in u)
        return SplitStep(data_sq, (self.tv * tv_x, self.l1 * l1_x), balance)

    def set_penalties(self, old: tuple, new: tuple) -> None:
        """Rescale the q's by the stored duals; the state adopts ``new``."""
        st = self.state
        st.qv = _rescale(st.qv, self.av, old[0], new[0])
        st.qw = _rescale(st.qw, self.aw, old[2], new[2])
        if st.use_tv:
            st.qu = tuple(_rescale(q, a, old[1], new[1]) for q, a in zip(st.qu, self.au,
                                                                          strict=True))
        st.set_penalties(self.plan, new)

    def end_balancing(self) -> None:
        """Release the stored duals (no later pass reads them)."""
        self.av = self.aw = None
        self.au = ()

    def x_update(self) -> None:
        """The plan's x-update."""
        self.state.x, self.state.mx = self.plan.x_update(self.state)

    def iterate(self):
        """The current x (on the device)."""
        return self.state.x

    def estimate(self):
        """max(x, 0) with ``nonneg``, else x."""
        return self.xp.clip(self.state.x, min=0.0) if self.nonneg else self.state.x


class XpPlanBase(AdmmPlanBase):
    """What the 2D and 3D generic ADMM plans share (:class:`XpAdmmPlan`,
    :class:`recon.volume.xp_admm3d.XpVolumeAdmmPlan`): the ``plan_of`` maker, the cold
    and warm states and the kernel set. A subclass has ``plan`` (the NumPy plan),
    ``op``, ``xp``, ``xop``, ``differences`` (:class:`Differences`, or
    :data:`IDENTITY` for a prior on the image itself), ``inverse_denominator(mu,
    use_tv)``, ``x_update(state) -> (x, mx)`` and ``objective``."""

    #: The u split's prior (:mod:`recon.priors`); a plan made with another sets its own
    #: (:meth:`adopt_prior`).
    prior: Prior = TotalVariation()

    def adopt_prior(self, prior) -> None:
        """Take ``prior`` (a name, a :class:`~recon.priors.Prior` or None for TV) as the
        u split's: a prior on the image itself makes the split the identity
        (:data:`IDENTITY`), TV keeps the plan's differences.

        Raises
        ------
        ReconInputError
            An unknown prior name.
        """
        self.prior = prior_of(prior)
        if self.prior.identity_split:
            self.differences = IDENTITY

    @classmethod
    def maker(cls, like, numpy_plan_of, **options):
        """``plan_of(op) -> plan`` on ``like``'s device from the NumPy plans of
        ``numpy_plan_of`` (e.g. :meth:`recon.solvers.admm.AdmmPlan.of`), for
        :func:`recon.auto.weight.admm_auto`; ``options`` go to the plan (``prior``)."""
        return lambda op: cls(numpy_plan_of(op), like, **options)

    # the solver's name in errors, the divergence advice, the penalty tie and whether
    # nonneg=False is allowed: the NumPy plan's (AdmmPlanBase)
    label = property(lambda self: self.plan.label)
    hint = property(lambda self: self.plan.hint)
    tie_nonneg = property(lambda self: self.plan.tie_nonneg)
    signed = property(lambda self: self.plan.signed)

    def ffts_per_iteration(self) -> dict:
        """As the NumPy plan's."""
        return self.plan.ffts_per_iteration()

    def zeros(self, mu, use_tv: bool) -> XpAdmmState:
        """The cold start: everything zero, penalties ``mu``."""
        xp, dev = self.xp, self.xop.device
        z = xp.zeros(self.op.shape_in, dtype=xp.float32, device=dev)
        plane = xp.zeros(self.xop.padded_shape, dtype=xp.float32, device=dev)
        state = XpAdmmState(z, plane, plane, tuple(z for _ in range(self.differences.count)), z,
                            tuple(float(m) for m in mu), None, bool(use_tv))
        state.set_penalties(self, mu)
        return state

    def warm(self, x, mu, use_tv: bool) -> XpAdmmState:
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
            state.qu = self.differences.apply(xp, x)
        return state

    def kernels(self, b, state: XpAdmmState, *, tv: float, l1: float, nonneg: bool = True,
                balancing: bool = True) -> XpKernels:
        """The generic kernel set of one solve (:class:`XpKernels`)."""
        return XpKernels(self, b, state, tv=tv, l1=l1, nonneg=nonneg)


class XpAdmmPlan(XpPlanBase):
    """:class:`recon.solvers.admm.AdmmPlan` on the device of ``like``, with a prior.

    The operator's spectrum and weights and the power spectra are copied to the
    device once per NumPy plan and device (kept on the plan: a live view reuses its
    plan frame after frame). On NumPy arrays this is the path of the priors other
    than TV (the fused numba passes do TV only).

    Parameters
    ----------
    plan : AdmmPlan
        The NumPy path's plan.
    like : array
        Any array of the target backend and device.
    prior : Prior or str, optional
        The u split's prior (:mod:`recon.priors`; default TV).

    Attributes
    ----------
    plan : AdmmPlan
    op : ConvolutionOperator
        ``plan.op`` (the NumPy operator: validation, crop, shapes).
    xop : XpConvolution
        The operator on the device.
    h_pow, d_pow : array, float32, (P0, P1 // 2 + 1)
        On the device.
    prior : Prior
    differences : Differences or IdentitySplit
        G_u: :data:`DIFFERENCES_2D` for TV, :data:`IDENTITY` for a prior on the image.
    solve_x : callable
        ``solve_x(xop, x, mx, (qv, *qu, qw), mu, inv_den, use_tv) -> (x, mx)``:
        :func:`fourier_x_update`, or the plan's own: a plan with another x-update
        names it (``plan.device_parts(like)`` -> operator, x-update:
        :meth:`recon.spatial.SpatialAdmmPlan.device_parts`; TV only).

    Raises
    ------
    ReconInputError
        An unknown prior, or a prior other than TV with a plan of its own x-update.
    """

    differences = DIFFERENCES_2D

    def __init__(self, plan, like, prior=None):
        key = (array_namespace(like).__name__, str(device_of(like)))
        cache = plan.__dict__.setdefault("_device_copies", {})
        parts = getattr(plan, "device_parts", None)
        self.adopt_prior(prior)
        if self.prior.identity_split and parts is not None:
            raise ReconInputError(f"the {self.prior.name} prior needs a convolution model; "
                                  "the spatially varying model takes TV (--prior tv)")
        if key not in cache:
            xop, solve_x = (parts(like) if parts is not None
                            else (XpConvolution(plan.op, like), fourier_x_update))
            cache[key] = (xop, xop.asarray(plan.h_pow), xop.asarray(plan.d_pow), solve_x)
        self.plan, self.op = plan, plan.op
        self.xop, self.h_pow, self.d_pow, self.solve_x = cache[key]
        self.xp, self.shape = self.xop.xp, self.xop.padded_shape

    def inverse_denominator(self, mu, use_tv: bool):
        """1 / (mu1 |H|^2 [+ mu2 |F G_u|^2] + mu3) on the device (|F G_u|^2 = 1 for the
        identity split)."""
        mu1, mu2, mu3 = mu
        den = mu1 * self.h_pow + mu3
        if not use_tv:
            return 1.0 / den
        return 1.0 / (den + (mu2 if self.prior.identity_split else mu2 * self.d_pow))

    def x_update(self, state: XpAdmmState):
        """:attr:`solve_x` from the state's q's and penalties."""
        q = (state.qv, *state.qu, state.qw)
        if self.solve_x is fourier_x_update:
            return fourier_x_update(self.xop, state.x, state.mx, q, state.mu, state.inv_den,
                                    state.use_tv, self.differences)
        return self.solve_x(self.xop, state.x, state.mx, q, state.mu, state.inv_den,
                            state.use_tv)

    def objective(self, b, x, *, tv: float, l1: float, b_norm: float) -> tuple[float, float]:
        """:func:`recon.solvers.admm.objective_of` on the device, with the prior's term."""
        xp = self.xp
        r = self.xop.forward(x) - b
        data_sq = total(xp, r * r)
        reg = 0.0
        if tv > 0:
            reg = (tv_circular(xp, x, (0, 1)) if self.prior.name == "tv"
                   else self.prior.value(xp, x, self.differences.apply(xp, x)))
        objective = 0.5 * data_sq + tv * reg + l1 * total(xp, x)
        return objective, float(np.sqrt(data_sq)) / b_norm
