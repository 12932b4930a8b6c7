"""ADMM for the cropped convolution model with TV and non-negativity (2D).

The variable splitting of Eq. 4.5 / App. A.3 (Kuo 2020; Antipa et al. 2018):
v = M x (crop split, M the circular convolution), u = Psi x (finite differences,
TV), w = x (non-negativity), with closed-form updates: v and w pointwise, u by
soft thresholding, x by a diagonal solve in Fourier space. Penalties mu1..mu3 are
balanced from the primal and dual residuals (Boyd et al. 2011, Sec. 3.4.1).

The loop is the one of every ADMM (:func:`recon.solvers.admm_loop.run_admm`); this
module is the 2D plan and state and, for NumPy arrays, its kernel set
(:class:`NumbaKernels2D`: the fused numba passes of ``recon._kernels``). Other
array-API backends get the generic kernel set of ``recon.solvers.xp_admm``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .. import _kernels
from ..errors import ReconInputError
from ..fft import irfftn, rfftn
from ..operators import ConvolutionOperator
from ..priors import prior_of
from ..validate import as_int, nonneg_weight
from .admm_loop import DEFAULT_ITERATIONS, AdmmPlanBase, SplitStep, run_admm
from .common import Monitor, SolveResult, anisotropic_tv, check_measurement
from .penalty import (
    MU_RANGE,
    AdmmPenalty,
    balance_mode,
    balanced_penalty,
    check_balancing,
    check_penalties,
    check_penalty_settings,
    rescale_duals,
    tie_nonneg_penalty,
)

# the balancing steps live in .penalty; named here too for the 3D ADMM's imports
__all__ = ["MU_RANGE", "AdmmPenalty", "AdmmPlan", "AdmmState", "NumbaKernels2D", "admm",
           "balance_mode", "balanced_penalty", "check_balancing", "check_penalties",
           "check_penalty_settings", "difference_power", "objective_of", "plan_for_prior",
           "record_prior", "rescale_duals", "run_admm", "tie_nonneg_penalty"]


def difference_power(shape: tuple[int, int]) -> np.ndarray:
    """|F Psi|^2 summed over axes on the rfft grid: sum_a (2 - 2 cos(2 pi k_a / N_a))."""
    k0 = np.fft.fftfreq(shape[0])[:, None]
    k1 = np.fft.rfftfreq(shape[1])[None, :]
    return ((2 - 2 * np.cos(2 * np.pi * k0)) + (2 - 2 * np.cos(2 * np.pi * k1))).astype(
        np.float32)


@dataclass
class AdmmPlan(AdmmPlanBase):
    """What ADMM precomputes from the operator alone, reusable across measurements.

    Attributes
    ----------
    op : ConvolutionOperator
        The forward model.
    shape : (P0, P1)
        ``op.padded_shape``.
    wp : ndarray, float32, shape (P0, P1)
        Sensor weights zero-padded to the object domain (zero weight off the sensor
        gives the plain v = t update, so the fused pass is branch-free).
    h_pow : ndarray, float32, shape (P0, P1 // 2 + 1)
        |F P h|^2, the PSF's power spectrum.
    d_pow : ndarray, float32, shape (P0, P1 // 2 + 1)
        |F Psi|^2 summed over the axes (finite differences).
    isotropic : bool (class attribute)
        The u split's prior is isotropic TV (``--prior tv-iso``): the fused pass
        group-soft-thresholds each pixel's difference vector. True on the copy
        :meth:`~recon.solvers.admm.AdmmPlan.isotropic_view` makes.
    rhs_in_split : bool (class attribute)
        Whether the kernel set (:class:`NumbaKernels2D`) has the split pass write the
        x-update's right-hand side (``state.stacked[1]``) and calls :meth:`x_update`
        with ``rhs_ready=True``; False for a plan whose x-update does not use it
        (:class:`recon.spatial.SpatialAdmmPlan`).
    """

    rhs_in_split: ClassVar[bool] = True
    isotropic: ClassVar[bool] = False
    hint: ClassVar[str] = "try --method fista or a smaller TV weight"

    op: ConvolutionOperator
    shape: tuple[int, int]
    wp: np.ndarray
    h_pow: np.ndarray
    d_pow: np.ndarray

    @classmethod
    def of(cls, op: ConvolutionOperator) -> AdmmPlan:
        """Precompute for ``op``.

        Raises
        ------
        ReconInputError
            ``op`` is not a :class:`~recon.operators.ConvolutionOperator`.
        """
        if not isinstance(op, ConvolutionOperator):
            raise ReconInputError("ADMM here needs a ConvolutionOperator (optionally masked); for "
                                  "a spatially varying model use recon.spatial.spatial_admm")
        wp = np.zeros(op.padded_shape, np.float32)
        wp[op.crop] = op.sensor_weights
        spec = op.spectrum
        return cls(op, op.padded_shape, wp, (spec.real**2 + spec.imag**2).astype(np.float32),
                   difference_power(op.padded_shape))

    def isotropic_view(self) -> AdmmPlan:
        """This plan (its arrays shared) with isotropic TV as the u split's prior."""
        plan = copy.copy(self)
        plan.isotropic = True
        return plan

    # -- the interface of the automatic weight (recon.auto.weight.admm_auto), shared
    # with recon.volume.VolumeAdmmPlan --------------------------------------------
    def zeros(self, mu, use_tv: bool) -> AdmmState:
        """The cold start (:meth:`AdmmState.zeros`)."""
        return AdmmState.zeros(self, mu, use_tv)

    def warm(self, x: np.ndarray | None, mu, use_tv: bool) -> AdmmState:
        """A state at the primal ``x`` (padded grid) with zero duals (q_i = G_i x)."""
        state = AdmmState.zeros(self, mu, use_tv)
        if x is None:
            return state
        x = np.ascontiguousarray(x, np.float32)
        state.x[...] = x
        state.mx[...] = self.op.convolve_full(x)
        state.stacked[0] = state.mx
        state.qw[...] = np.maximum(x, 0)
        if use_tv:
            state.qux[...] = np.roll(x, -1, axis=1) - x
            state.quy[...] = np.roll(x, -1, axis=0) - x
        return state

    def kernels(self, b: np.ndarray, state: AdmmState, *, tv: float, l1: float,
                nonneg: bool = True, balancing: bool = True) -> NumbaKernels2D:
        """The kernel set of one solve on NumPy arrays (:class:`NumbaKernels2D`), for
        :func:`~recon.solvers.admm_loop.run_admm`.

        Raises
        ------
        ReconInputError
            A bad measurement.
        """
        return NumbaKernels2D(self, b, state, tv=tv, l1=l1, nonneg=nonneg)

    def ffts_per_iteration(self) -> dict:
        """Real 2D FFTs of one iteration at the padded shape: 2 rfft2 + 2 irfft2."""
        return {"rfft2": 2, "irfft2": 2}

    def objective(self, b: np.ndarray, x: np.ndarray, *, tv: float, l1: float,
                  b_norm: float) -> tuple[float, float]:
        """:func:`objective_of` with this plan's operator (isotropic TV's term on
        the copy :meth:`~recon.solvers.admm.AdmmPlan.isotropic_view` makes)."""
        if not self.isotropic:
            return objective_of(self.op, b, x, tv=tv, l1=l1, b_norm=b_norm)
        objective, relative = objective_of(self.op, b, x, tv=0.0, l1=l1, b_norm=b_norm)
        g = [np.roll(x, -1, axis=ax) - x for ax in (1, 0)]
        return objective + tv * float(np.hypot(*g).sum(dtype=np.float64)), relative

    def x_update(self, state: AdmmState, x: np.ndarray, mx: np.ndarray, mu, *,
                 rhs_ready: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The x-update of App. A.3: the exact minimiser of
        mu1/2 ||M x - q_v||^2 + mu2/2 ||Psi x - q_u||^2 + mu3/2 ||x - q_w||^2, a diagonal
        solve in Fourier space (2 rfft2 + 2 irfft2, plane by plane: a 2-plane batch
        outgrows the L2 cache at 600 x 800).

        Parameters
        ----------
        state : AdmmState
            Holds the q's (``stacked[0]`` is q_v; ``stacked[1]`` is overwritten with
            the right-hand side) and ``inv_den``.
        x, mx : ndarray, float32, ``shape``
            The current iterate and M x (not used here: the solve is exact).
        mu : (mu1, mu2, mu3)
        rhs_ready : bool
            ``stacked[1]`` already holds mu2 Psi^T q_u + mu3 q_w of the current q's
            and ``mu`` (written by the split pass, :class:`NumbaKernels2D`).

        Returns
        -------
        (x, mx) : new arrays, float32, ``shape``
        """
        mu1, mu2, mu3 = mu
        if not rhs_ready:
            _kernels.admm_rhs_2d(state.qux, state.quy, state.qw, state.stacked[1], mu2, mu3,
                                 state.use_tv)
        qv_hat = rfftn(state.stacked[0])
        x_hat = rfftn(state.stacked[1])
        _kernels.admm_fourier_2d(qv_hat, x_hat, self.op.spectrum, state.inv_den, mu1)
        x = irfftn(x_hat, self.shape, overwrite_x=True)
        return x, irfftn(qv_hat, self.shape, overwrite_x=True)


@dataclass
class AdmmState:
    """The ADMM iterate carried from one iteration (or one solve) to the next.

    In the q-form of ``recon._kernels.admm_split_updates_2d`` the whole state of
    scaled-dual ADMM (Boyd et al. 2011, Sec. 3.1.1) is the primal ``x``, its image
    ``M x`` and, per split, q_i = z_i - a_i (split variable minus scaled dual), plus
    the penalties. All arrays float32 on the padded grid (P0, P1).

    Attributes
    ----------
    x, mx : ndarray
        Primal iterate and M x (circular convolution, uncropped).
    stacked : ndarray, shape (2, P0, P1)
        ``stacked[0]`` is q_v (crop split), ``stacked[1]`` the x-update's right-hand
        side (scratch, written by the split pass or by :meth:`AdmmPlan.x_update`).
    qux, quy, qw : ndarray
        q of the TV splits (forward differences along columns, rows) and of the
        non-negativity split.
    scratch : list of 4 ndarray
        Scaled duals a_v, a_ux, a_uy, a_w stored by the balancing passes.
    mu : (mu1, mu2, mu3)
        Current penalties.
    inv_den : ndarray, float32, shape (P0, P1 // 2 + 1)
        1 / (mu1 |H|^2 + mu2 |F Psi|^2 + mu3) for the current penalties.
    use_tv : bool
        Whether ``inv_den`` includes the TV term.
    """

    x: np.ndarray
    mx: np.ndarray
    stacked: np.ndarray
    qux: np.ndarray
    quy: np.ndarray
    qw: np.ndarray
    scratch: list
    mu: tuple[float, float, float]
    inv_den: np.ndarray
    use_tv: bool

    @classmethod
    def zeros(cls, plan: AdmmPlan, mu: tuple[float, float, float], use_tv: bool
              ) -> AdmmState:
        """The cold start: everything zero (x_0 = 0), penalties ``mu``."""
        shape = plan.shape
        scratch = [np.zeros(shape, np.float32) for _ in range(4)]  # a_v, a_ux, a_uy, a_w
        for buf in scratch:
            # Write once so the pages are mapped writable: the vectorised split kernel
            # issues masked stores to these buffers even in mode 0 (all lanes off), and
            # a masked store to a not-yet-written calloc page takes a microcode assist:
            # measured 3.8 ms instead of 0.65 ms per pass at 600 x 800.
            buf.fill(0.0)
        state = cls(np.zeros(shape, np.float32), np.zeros(shape, np.float32),
                    np.zeros((2, *shape), np.float32),
                    *(np.zeros(shape, np.float32) for _ in range(3)), scratch, tuple(mu),
                    np.empty(plan.h_pow.shape, np.float32), use_tv)
        state.set_penalties(plan, mu)
        return state

    def set_penalties(self, plan: AdmmPlan, mu) -> None:
        """Adopt penalties ``mu`` and recompute ``inv_den`` (q rescaling is the caller's)."""
        self.mu = tuple(mu)
        _kernels.admm_inverse_denominator(plan.h_pow, plan.d_pow, *self.mu, self.use_tv,
                                          self.inv_den)

    def scale(self, factor: float) -> None:
        """Multiply x, M x and every q by ``factor`` in place (the measurement's
        scale changed by ``factor``: ADMM's linear parts are homogeneous in b)."""
        f = np.float32(factor)
        for a in (self.x, self.mx, self.stacked[0], self.qux, self.quy, self.qw):
            a *= f


def objective_of(op, b: np.ndarray, x: np.ndarray, *, tv: float, l1: float,
                 b_norm: float) -> tuple[float, float]:
    """The ADMM objective and relative data residual of an estimate.

    Parameters
    ----------
    op : forward model
        Anything with ``forward`` (e.g. :class:`recon.operators.ConvolutionOperator`).
    b : ndarray, float32, sensor shape
        The measurement the estimate was fitted to.
    x : ndarray, float32, object shape
        The (non-negative) estimate.
    tv, l1 : float
        The weights of anisotropic TV and l1 in the scaled problem.
    b_norm : float
        ``||b||``, > 0.

    Returns
    -------
    objective : float
        ``0.5 ||A x - b||^2 + tv TV(x) + l1 sum(x)`` (Eq. 3.9 with l1 added).
    relative : float
        ``||A x - b|| / ||b||``.
    """
    r = op.forward(x) - b
    data_sq = float(np.vdot(r, r))
    objective = 0.5 * data_sq + tv * anisotropic_tv(x) + l1 * float(x.sum(dtype=np.float64))
    return objective, math.sqrt(data_sq) / b_norm


class NumbaKernels2D:
    """The 2D ADMM's kernel set on NumPy arrays
    (:class:`~recon.solvers.admm_loop.AdmmKernels`): two fused numba passes and 2 rfft2
    + 2 irfft2 per iteration.

    :meth:`splits` is ``recon._kernels.admm_split_updates_2d`` -- the v (crop),
    u (TV: soft threshold of the forward differences) and w (non-negativity, l1)
    updates in one pass, which also writes the x-update's right-hand side except in
    balancing iterations (mode 2: balancing may change the q's and penalties after
    it); :meth:`x_update` is the plan's (:meth:`AdmmPlan.x_update`).

    Parameters
    ----------
    plan : AdmmPlan
    b : ndarray, float32, ``plan.op.shape_out``
        Scaled, weighted measurement (checked with
        :func:`~recon.solvers.common.check_measurement`).
    state : AdmmState
        Updated in place.
    tv, l1 : float
        Weights (validated, >= 0).
    nonneg : bool
        True (the plan is not ``signed``: :func:`~recon.solvers.admm_loop.run_admm`
        refuses False).

    Raises
    ------
    ReconInputError
        A bad measurement.
    """

    def __init__(self, plan: AdmmPlan, b: np.ndarray, state: AdmmState, *, tv: float,
                 l1: float, nonneg: bool = True):
        op = plan.op
        self.b = check_measurement(b, op.shape_out)
        self.bp = np.zeros(plan.shape, np.float32)
        self.bp[op.crop] = self.b
        self.plan, self.state, self.tv, self.l1 = plan, state, tv, l1
        self.monitor = Monitor(float(np.vdot(self.b, self.b)), plan.label)
        self.report = {"ffts_per_iteration": plan.ffts_per_iteration()}
        self._rhs_ready = False

    def splits(self, mode: int) -> SplitStep:
        """One fused pass of every split's update
        (``recon._kernels.admm_split_updates_2d``); the l1 term of the entering iterate
        in a second pass when ``l1 > 0``."""
        st, plan = self.state, self.plan
        mu1, mu2, mu3 = st.mu
        rhs = st.stacked[1] if plan.rhs_in_split and mode != 2 else None
        s = _kernels.admm_split_updates_2d(st.x, st.mx, st.stacked[0], st.qux, st.quy, st.qw,
                                           self.bp, plan.wp, mu1, mu2, mu3, self.tv,
                                           st.use_tv, mode, *st.scratch, self.l1, rhs,
                                           plan.isotropic)
        self._rhs_ready = rhs is not None
        l1_x = (self.l1 * float(np.maximum(st.x, 0).sum(dtype=np.float64)) if self.l1 > 0
                else 0.0)
        balance = None
        if mode == 2:
            balance = (s[[2, 3, 8, 9]], s[[4, 5, 10, 11]] if st.use_tv else None,
                       s[[6, 7, 12, 13]])
        return SplitStep(s[0], (self.tv * s[1], l1_x), balance)

    def set_penalties(self, old: tuple, new: tuple) -> None:
        """Rescale the q's by the duals the mode-1 pass stored, recompute ``inv_den``."""
        st = self.state
        a_v, a_ux, a_uy, a_w = st.scratch
        rescale_duals(((st.stacked[0], a_v, old[0], new[0]), (st.qux, a_ux, old[1], new[1]),
                       (st.quy, a_uy, old[1], new[1]), (st.qw, a_w, old[2], new[2])))
        st.set_penalties(self.plan, new)

    def end_balancing(self) -> None:
        """Nothing to release: the dual buffers belong to the state (mapped once)."""

    def x_update(self) -> None:
        """:meth:`AdmmPlan.x_update` (with the right-hand side the split pass wrote)."""
        st = self.state
        if self._rhs_ready:
            st.x, st.mx = self.plan.x_update(st, st.x, st.mx, st.mu, rhs_ready=True)
        else:
            st.x, st.mx = self.plan.x_update(st, st.x, st.mx, st.mu)

    def iterate(self) -> np.ndarray:
        """The current x (padded grid)."""
        return self.state.x

    def estimate(self) -> np.ndarray:
        """max(x, 0): the estimate is the non-negative split w."""
        return np.maximum(self.state.x, 0)


def admm(op: ConvolutionOperator, b: np.ndarray, *, iterations: int = DEFAULT_ITERATIONS,
         tv: float = 0.0, l1: float = 0.0, penalty: AdmmPenalty | None = None, stop=None,
         plan: AdmmPlan | None = None, prior=None) -> SolveResult:
    """ADMM with crop, TV, l1 and non-negativity splits (Eq. 4.5, App. A.3, in 2D).

    Per iteration, in scaled-dual form with q_i = z_i - a_i kept between iterations:
    u = soft(Psi x + a_u, tau/mu2); v = (D^T b + mu1 (M x + a_v)) / (D^T D + mu1);
    w = max(x + a_w, 0); x = F^-1[(mu1 conj(H) F q_v + F(mu2 Psi^T q_u + mu3 q_w))
    / (mu1 |H|^2 + mu2 |F Psi|^2 + mu3)]; a_i += G_i x - z_i. That is 2 rfft + 2 irfft
    per iteration (M x is reused from the x-update), plus two fused passes: the
    splits with the x-update's right-hand side, and the Fourier-space solve (a third,
    the right-hand side alone, in balancing iterations).

    Residual balancing (on by default; Boyd et al. 2011, Sec. 3.4.1, with the
    normalised residuals of Wohlberg 2017 so the three splits' different scales do
    not matter): every ``penalty.balance_every`` iterations, for each split,
    r_i = ||G_i x - z_i|| / max(||G_i x||, ||z_i||) and
    s_i = mu_i ||z_i - z_i^prev|| / ||y_i|| with y_i = mu_i a_i the dual variable
    (G_i^T dropped: ||M|| <= 1 for a unit-sum PSF); mu_i is multiplied by
    ``balance_factor`` when r_i > ``balance_ratio`` s_i and divided when
    s_i > ``balance_ratio`` r_i, scaled duals rescaled. It stops after
    ``balance_until`` of the iterations so the final penalties are fixed. With
    ``tv = 0``, mu3 follows mu1 at its starting ratio (:func:`tie_nonneg_penalty`).

    Parameters
    ----------
    op : ConvolutionOperator
        Forward model; erasure masks are folded into its sensor weights.
    b : ndarray, shape ``op.shape_out``, float32
        Measurement, multiplied by the sensor weights, scaled to O(1). An array of
        another array-API backend (CuPy, PyTorch: on its device) runs the same loop
        with the generic kernel set (``recon.solvers.xp_admm.XpAdmmPlan``) and
        returns ``x`` on that device.
    iterations : int
        Maximum iterations (default :data:`~recon.solvers.common.DEFAULT_ITERATIONS`).
    tv : float
        TV weight tau (default 0, as every solver's: no term unless asked); 0 removes
        the TV split.
    l1 : float
        l1 weight (native sparsity: beads, fluorescence), on the non-negativity split:
        w = max(x + a_w - l1 / mu3, 0).
    penalty : AdmmPenalty, optional
        Initial penalties and residual balancing (default ``AdmmPenalty()``: mu
        (2e-3, 2e-3, 2e-3) for the scaled problem, unit-sum PSF and |b| <= 1,
        balanced every 5 iterations during the first 60 %).
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping).
    plan : AdmmPlan, optional
        Precomputed for ``op`` (default :meth:`AdmmPlan.of`); a subclass with another
        x-update serves other forward models (:class:`recon.spatial.SpatialAdmmPlan`:
        the local convolution model, ``op`` a ``SpatialConvolutionOperator``).
    prior : str or Prior, optional
        The u split's prior (:mod:`recon.priors`): ``"tv"`` (default) and ``"tv-iso"``
        (the fused numba passes on NumPy), ``"tgv"``, ``"wavelet"`` or ``"dncnn"`` (or a
        :class:`~recon.priors.Prior`), which run the generic kernel set
        (``recon.solvers.xp_admm.XpAdmmPlan``) on any backend with u = x; ``tv`` is
        then that prior's weight (the wavelet's l1 weight; the denoiser's noise level
        relative to the iterate's scale). ``params['prior']`` records it.

    Returns
    -------
    SolveResult
        ``history.objective[k]`` = 1/2 ||D M x_k - b||^2 + tau TV(x_k) + l1 ||x_k||_1
        for the iterate entering iteration k (x_0 = 0); ``history.extra['mu']`` the
        penalties used; ``params`` as every ADMM's
        (:func:`~recon.solvers.admm_loop.run_admm`: ``iterations``, the maximum,
        ``iterations_used``, ...).

    Raises
    ------
    DivergenceError
        NaN/inf or an objective 100x that of the zero image.
    ReconInputError
        Not a convolution operator (without a ``plan``), a ``plan`` made for another
        operator, ``penalty`` not an :class:`AdmmPenalty`, or invalid parameters.

    Examples
    --------
    A point behind a small PSF, in the scaled problem (unit-sum PSF, measurement of
    order 1); :func:`recon.reconstruct` does the scaling and chooses the weight:

    >>> import numpy as np
    >>> from recon.operators import ConvolutionOperator
    >>> psf = np.zeros((16, 16), np.float32); psf[7:9, 6:10] = 0.125
    >>> op = ConvolutionOperator(psf)
    >>> x = np.zeros(op.shape_in, np.float32); x[14, 18] = 1.0
    >>> res = admm(op, op.forward(x), iterations=50, tv=1e-4)
    >>> res.x.shape, np.unravel_index(np.argmax(res.x), res.x.shape)
    ((32, 32), (np.int64(14), np.int64(18)))
    >>> res.params["iterations"], res.params["iterations_used"] <= 50
    (50, True)
    """
    if plan is None:
        plan = AdmmPlan.of(op)
    elif plan.op is not op:
        raise ReconInputError("the ADMM plan was made for another operator; make it with "
                              "the plan's of(op)")
    iterations = as_int(iterations, "iterations", 1)
    tv = nonneg_weight(tv, "TV")
    l1 = nonneg_weight(l1, "l1")
    penalty = check_penalty_settings(penalty)
    prior = prior_of(prior)
    plan = plan_for_prior(plan, b, prior)
    res = run_admm(plan, b, plan.zeros(penalty.initial(), tv > 0), iterations=iterations,
                   tv=tv, l1=l1, penalty=penalty, stop=stop)
    return record_prior(res, prior)


def plan_for_prior(plan: AdmmPlan, like, prior):
    """The plan that runs ``prior``'s u split on the arrays of ``like``.

    Parameters
    ----------
    plan : AdmmPlan
        The host plan of the operator (spectra, the anisotropic-TV kernels).
    like : array
        An array of the backend the solve runs on (the measurement, or any array of
        that library and device).
    prior : Prior
        :func:`recon.priors.prior_of`'s.

    Returns
    -------
    AdmmPlan or XpAdmmPlan
        ``plan`` itself for TV on NumPy; its :meth:`AdmmPlan.isotropic_view` (the
        fused numba passes) for isotropic TV on NumPy; otherwise the generic kernel
        set (``recon.solvers.xp_admm.XpAdmmPlan``) with the prior, on ``like``'s
        backend. One choice for :func:`admm` and the live reconstructor.
    """
    if prior.name not in ("tv", "tv-iso") or not isinstance(like, np.ndarray):
        from .xp_admm import XpAdmmPlan

        return XpAdmmPlan(plan, like, prior=prior)
    return plan.isotropic_view() if prior.name == "tv-iso" else plan


def record_prior(res: SolveResult, prior) -> SolveResult:
    """``res`` with ``params["prior"]`` set to ``prior.record()`` for a prior other
    than anisotropic TV (whose record is its absence, as before priors existed)."""
    if prior.name != "tv":
        res.params["prior"] = prior.record()
    return res
