r"""3D ADMM for volume reconstruction from one image (Kuo 2020, Eq. 4.5, App. A.3).

Minimises ``1/2 ||D M x - b||^2 + tv TV3(x) + l1 ||x||_1`` subject to ``x >= 0``
(Eq. A.3/A.4 with Psi the 3D finite differences, the identity "native sparsity",
or both), with ``A = D M`` the 3D model of Eq. 4.4: ``M x = F^-1 sum_z H_z F x_z`` the
uncropped sum over depth of 2D circular convolutions on the padded grid (one
plane) and ``D = diag(w) C`` the (weighted) crop, which is diagonal.

Splitting (Eq. 4.5): ``v = M x`` (one padded plane; the crop is handled by the
per-pixel v-update), ``u = Psi x`` (3D TV), ``w = x`` (non-negativity). The l1
term rides on the identity split ``w``: Eq. 4.5 with Psi = I would add a second
split ``u = x`` identical to ``w = x``; merged, the w-update is the exact prox of
``l1 ||w||_1 + 1_+(w)``, ``w = max(t - l1 / mu3, 0)``, with one volume less. TV and
l1 together therefore use both splits.

Depth boundary: the z differences do not wrap (as :func:`~recon.volume.fista3d`
and :func:`~recon.volume.volume_tv`), and the x-update is still exact: at each
lateral frequency the n_z x n_z system is ``mu1 conj(h) h^T + mu2 (L_z + d_lat I) +
mu3 I`` with ``L_z`` tridiagonal, solved by one Thomas sweep plus Sherman-Morrison
for the rank-one data term (``M^H M`` at one lateral frequency is ``conj(h) h^T``,
``h = (H_z(f))_z``): O(n_z) per frequency, no 3D FFT along z needed.

The loop is the one of every ADMM (:func:`recon.solvers.admm_loop.run_admm`: stopping
rule, residual balancing, history); this module is the volume's plan and state and,
for NumPy arrays, its kernel set (:class:`NumbaKernels3D`, the fused passes of
``recon.volume._admm_kernels3d``). Other array-API backends run the generic kernel
set with the volume's plan (``recon.volume.xp_admm3d.XpVolumeAdmmPlan``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.fft as sfft
from numba import get_num_threads

from ..errors import ReconInputError
from ..fft import WORKERS, rfftn
from ..priors import prior_of
from ..solvers.admm import difference_power
from ..solvers.admm_loop import DEFAULT_ITERATIONS, AdmmPlanBase, SplitStep, run_admm
from ..solvers.common import Monitor, SolveResult, check_measurement
from ..solvers.penalty import AdmmPenalty, check_penalty_settings, rescale_duals
from ..validate import as_int, nonneg_weight
from . import _admm_kernels3d as _k
from .fista import final_objective
from .operator import VolumeConvolutionOperator


def solve_x_update(spec: np.ndarray, psf_spectra: np.ndarray, d_lat: np.ndarray,
                   mu: tuple[float, float, float], use_tv: bool) -> np.ndarray:
    """Solve the x-update of App. A.3 at every lateral frequency, in place.

    ``(mu1 conj(h) h^T + mu2 (L_z + d_lat I) + mu3 I) X = R + mu1 conj(h) Qv`` per
    frequency (see ``recon.volume._admm_kernels3d.admm_xupdate_3d``; ``mu2``
    is dropped when ``use_tv`` is False).

    Parameters
    ----------
    spec : ndarray, complex64, shape (n_z + 1, F0, F1), C-contiguous
        In: R (planes 0..n_z-1) and Qv (plane n_z); out: X and ``h^T X``.
    psf_spectra : ndarray, complex64, shape (n_z, F0, F1)
    d_lat : ndarray, float32, shape (F0, F1)
    mu : (mu1, mu2, mu3)
    use_tv : bool

    Returns
    -------
    ndarray
        ``spec``.
    """
    mu1, mu2, mu3 = (float(m) for m in mu)
    _k.admm_xupdate_3d(spec, psf_spectra, d_lat, mu1, mu2 if use_tv else 0.0, mu3,
                       4 * get_num_threads())
    return spec


@dataclass
class VolumeAdmmPlan(AdmmPlanBase):
    """What 3D ADMM precomputes from the operator (the 3D counterpart of
    :class:`recon.solvers.admm.AdmmPlan`, with the same interface for the automatic
    weight, :func:`recon.auto.weight.admm_auto`: ``zeros``, ``warm``, ``run``,
    ``objective``, and ``kernels`` for the loop).

    Attributes
    ----------
    op : VolumeConvolutionOperator
    shape : (P0, P1)
        ``op.padded_shape``.
    wp : ndarray, float32, (P0, P1)
        Sensor weights zero-padded to the lateral object domain.
    d_lat : ndarray, float32, (P0, P1 // 2 + 1)
        Lateral ``|F Psi|^2`` (:func:`recon.solvers.admm.difference_power`).
    """

    label: ClassVar[str] = "3D ADMM"
    hint: ClassVar[str] = "try method fista3d or smaller TV / l1 weights"
    #: mu3 is balanced without TV too (measured:
    #: :func:`~recon.solvers.penalty.tie_nonneg_penalty`).
    tie_nonneg: ClassVar[bool] = False
    signed: ClassVar[bool] = True  # nonneg=False drops x >= 0 from the w split

    op: VolumeConvolutionOperator
    shape: tuple[int, int]
    wp: np.ndarray
    d_lat: np.ndarray

    @classmethod
    def of(cls, op: VolumeConvolutionOperator) -> VolumeAdmmPlan:
        """Precompute for ``op``.

        Raises
        ------
        ReconInputError
            ``op`` is not a :class:`VolumeConvolutionOperator`.
        """
        if not isinstance(op, VolumeConvolutionOperator):
            raise ReconInputError(
                "admm3d needs a VolumeConvolutionOperator (its PSF spectra give the "
                "per-frequency x-update); use fista3d for other volume operators")
        wp = np.zeros(op.padded_shape, np.float32)
        wp[op.crop] = op.sensor_weights
        return cls(op, op.padded_shape, wp, difference_power(op.padded_shape))

    def zeros(self, mu, use_tv: bool) -> VolumeAdmmState:
        """The cold start (x_0 = 0, every q zero), penalties ``mu``."""
        nz = self.op.n_z
        shape_in = self.op.shape_in
        tv_shape = shape_in if use_tv else (1, 1, 1)  # never indexed without TV
        return VolumeAdmmState(np.zeros((nz + 1, *self.shape), np.float32),
                               np.zeros(self.shape, np.float32),
                               np.zeros(shape_in, np.float32),
                               *(np.zeros(tv_shape, np.float32) for _ in range(3)),
                               tuple(float(m) for m in mu), bool(use_tv))

    def warm(self, x: np.ndarray | None, mu, use_tv: bool) -> VolumeAdmmState:
        """A state at the primal ``x`` (n_z, P0, P1) with zero duals (q_i = G_i x)."""
        state = self.zeros(mu, use_tv)
        if x is None:
            return state
        x = np.asarray(x, np.float32)
        state.stack[:-1] = x
        state.stack[-1] = self.op.convolve_full(x)
        state.qv[...] = state.stack[-1]
        np.maximum(x, 0, out=state.qw)
        if use_tv:
            state.quz[:-1] = x[1:] - x[:-1]  # no wrap in depth: the last plane has none
            state.quy[...] = np.roll(x, -1, axis=1) - x
            state.qux[...] = np.roll(x, -1, axis=2) - x
        return state

    def kernels(self, b: np.ndarray, state: VolumeAdmmState, *, tv: float, l1: float,
                nonneg: bool = True, balancing: bool = True) -> NumbaKernels3D:
        """The kernel set of one solve on NumPy arrays (:class:`NumbaKernels3D`), for
        :func:`~recon.solvers.admm_loop.run_admm`; ``balancing`` False allocates no
        dual volumes."""
        return NumbaKernels3D(self, b, state, tv=tv, l1=l1, nonneg=nonneg,
                              balancing=balancing)

    def ffts_per_iteration(self) -> dict:
        """Real 2D FFTs of one iteration at the padded shape: ``n_z + 1`` of each."""
        n = self.op.n_z + 1
        return {"rfft2": n, "irfft2": n}

    def objective(self, b: np.ndarray, x: np.ndarray, *, tv: float, l1: float,
                  b_norm: float) -> tuple[float, float]:
        """Objective of Eq. 4.5 at ``x`` and its relative data residual against ``b``."""
        final, data_sq = final_objective(self.op, x, b, tv, l1)
        return final, math.sqrt(data_sq) / b_norm


@dataclass
class VolumeAdmmState:
    """The 3D ADMM iterate, carried from one solve (
    :func:`~recon.solvers.admm_loop.run_admm`) to the next.

    In q-form (q_i = z_i - a_i) the state is the primal ``x``, ``M x`` and one q per
    split, plus the penalties; float32 on the padded grid.

    Attributes
    ----------
    stack : ndarray, (n_z + 1, P0, P1)
        ``[x planes, M x]`` (one array: one batched FFT per iteration).
    qv : ndarray, (P0, P1)
        q of the crop split v = M x.
    qw : ndarray, (n_z, P0, P1)
        q of the identity split w = x (non-negativity, l1).
    quz, quy, qux : ndarray, (n_z, P0, P1)
        q of the 3D TV splits (forward differences along z, y, x); (1, 1, 1)
        placeholders without TV.
    mu : (mu1, mu2, mu3)
    use_tv : bool
    """

    stack: np.ndarray
    qv: np.ndarray
    qw: np.ndarray
    quz: np.ndarray
    quy: np.ndarray
    qux: np.ndarray
    mu: tuple[float, float, float]
    use_tv: bool

    @property
    def x(self) -> np.ndarray:
        """The primal volume (before the non-negativity clip), a view."""
        return self.stack[:-1]

    @property
    def mx(self) -> np.ndarray:
        """``M x``: the uncropped sum over depth of the convolved planes, a view."""
        return self.stack[-1]


class NumbaKernels3D:
    """The 3D ADMM's kernel set on NumPy arrays
    (:class:`~recon.solvers.admm_loop.AdmmKernels`): three fused numba passes and
    ``n_z + 1`` rfft2 + irfft2 per iteration.

    :meth:`splits` runs ``recon.volume._admm_kernels3d.admm_split_plane`` (v, the crop
    split on the padded plane) and ``recon.volume._admm_kernels3d.admm_split_volume``
    (w: non-negativity and l1; u: 3D TV, soft thresholds of the z, y, x forward
    differences); :meth:`x_update` forms R = mu2 Psi^T q_u + mu3 q_w over x
    (``recon.volume._admm_kernels3d.admm_rhs_3d``), transforms [R, q_v] in one
    batch, solves per lateral frequency (:func:`solve_x_update`) and transforms back.

    Parameters
    ----------
    plan : VolumeAdmmPlan
    b : ndarray, float32, ``plan.op.shape_out``
        Scaled, weighted measurement (checked).
    state : VolumeAdmmState
        Updated in place.
    tv, l1 : float
        Weights (validated, >= 0).
    nonneg : bool
    balancing : bool
        Allocate the dual volumes the balancing passes store (released when
        balancing ends, :meth:`end_balancing`).

    Raises
    ------
    ReconInputError
        A bad measurement.
    """

    def __init__(self, plan: VolumeAdmmPlan, b: np.ndarray, state: VolumeAdmmState, *,
                 tv: float, l1: float, nonneg: bool = True, balancing: bool = True):
        op = plan.op
        self.b = check_measurement(b, op.shape_out)
        self.bp = np.zeros(plan.shape, np.float32)
        self.bp[op.crop] = self.b
        self.plan, self.state = plan, state
        self.tv, self.l1, self.nonneg = float(tv), float(l1), bool(nonneg)
        self.monitor = Monitor(float(np.vdot(self.b, self.b)), plan.label)
        self.report = {"ffts_per_iteration": plan.ffts_per_iteration()}
        self._rows = np.zeros((op.n_z * plan.shape[0], 10))  # per-row sums of the volume pass
        self.end_balancing()
        if balancing:
            self.av = np.zeros(plan.shape, np.float32)
            self.aw = np.zeros(op.shape_in, np.float32)
            if state.use_tv:
                self.auz, self.auy, self.aux = (np.zeros(op.shape_in, np.float32)
                                                for _ in range(3))

    def splits(self, mode: int) -> SplitStep:
        """The v pass on the plane and the fused u and w pass on the volume."""
        st = self.state
        mu1, mu2, mu3 = st.mu
        nz = self.plan.op.n_z
        sv = _k.admm_split_plane(st.stack[nz], st.qv, self.bp, self.plan.wp, mu1, mode,
                                 self.av)
        su = _k.admm_split_volume(st.stack[:nz], st.quz, st.quy, st.qux, st.qw,
                                  self.l1 / mu3, self.tv / mu2 if st.use_tv else 0.0,
                                  st.use_tv, self.nonneg, mode, self.auz, self.auy, self.aux,
                                  self.aw, self._rows)
        balance = (sv[1:], su[2:6] if st.use_tv else None, su[6:10]) if mode == 2 else None
        return SplitStep(sv[0], (self.tv * su[0], self.l1 * su[1]), balance)

    def set_penalties(self, old: tuple, new: tuple) -> None:
        """Rescale the q's by the stored duals; the state adopts ``new``."""
        st = self.state
        splits = [(st.qv, self.av, old[0], new[0]), (st.qw, self.aw, old[2], new[2])]
        if st.use_tv:
            splits += [(q, a, old[1], new[1]) for q, a in ((st.quz, self.auz),
                                                           (st.quy, self.auy),
                                                           (st.qux, self.aux))]
        rescale_duals(splits)
        st.mu = tuple(new)

    def end_balancing(self) -> None:
        """Drop the stored duals (never indexed in mode 0: placeholders)."""
        dummy = np.zeros((1, 1, 1), np.float32)
        self.av = np.zeros((1, 1), np.float32)
        self.aw = self.auz = self.auy = self.aux = dummy

    def x_update(self) -> None:
        """R over x, q_v over M x, one batched rfft2, the per-frequency solve, one
        batched irfft2 (a new stack)."""
        st, plan = self.state, self.plan
        nz = plan.op.n_z
        mu1, mu2, mu3 = st.mu
        stack = st.stack
        _k.admm_rhs_3d(st.quz, st.quy, st.qux, st.qw, stack[:nz], mu2, mu3, st.use_tv)
        np.copyto(stack[nz], st.qv)
        spec = rfftn(stack)
        del stack
        solve_x_update(spec, plan.op.spectra, plan.d_lat, st.mu, st.use_tv)
        # the state stays whole (the old stack) until the new one exists
        st.stack = sfft.irfftn(spec, s=plan.shape, axes=(-2, -1), workers=WORKERS,
                               overwrite_x=True)

    def iterate(self) -> np.ndarray:
        """The current x (a view of the stack)."""
        return self.state.x

    def estimate(self) -> np.ndarray:
        """max(x, 0) with ``nonneg`` (the estimate is the non-negative split), else a
        copy of x; C-contiguous."""
        x = self.state.x
        return np.ascontiguousarray(np.maximum(x, 0) if self.nonneg else x)


def admm3d(op: VolumeConvolutionOperator, b: np.ndarray, *,
           iterations: int = DEFAULT_ITERATIONS, tv: float = 0.0, l1: float = 0.0,
           nonneg: bool = True, penalty: AdmmPenalty | None = None, stop=None,
           prior=None) -> SolveResult:
    r"""ADMM on a volume with 3D TV, l1 and non-negativity (Eq. 4.5, App. A.3).

    Per iteration, in scaled-dual q-form (q_i = z_i - a_i kept between
    iterations, as :func:`recon.solvers.admm`), with G_v = M, G_u = Psi, G_w = I:

    1. splits (fused passes): a_i = G_i x - q_i; z_i = prox_i(G_i x + a_i);
       q_i = z_i - a_i, with prox_v(t) = (w b + mu1 t) / (w^2 + mu1) per pixel of
       the padded plane (w, b zero off the sensor), prox_u = soft(., tv / mu2) on the
       z, y, x forward differences, prox_w = max(soft(., l1 / mu3), 0);
    2. ``R = mu2 Psi^T q_u + mu3 q_w`` (fused pass, written over x);
    3. one batched rfft2 of the ``n_z + 1`` planes [R, q_v];
    4. per lateral frequency, ``X = (mu1 conj(h) h^T + mu2 Psi^H Psi + mu3 I)^{-1}
       (R + mu1 conj(h) Qv)`` exactly (tridiagonal Thomas solve across depth +
       Sherman-Morrison, :func:`solve_x_update`), and ``h^T X``, the spectrum of M x;
    5. one batched irfft2 of the ``n_z + 1`` planes gives x and M x.

    FFTs per iteration: ``n_z + 1`` rfft2 and ``n_z + 1`` irfft2 at the padded
    shape -- the same as one FISTA data term and exactly what
    :func:`~recon.volume.fft_floor_seconds` times.

    The loop, its residual balancing and its stopping rule are those of every ADMM
    (:func:`recon.solvers.admm_loop.run_admm`; Boyd et al. 2011, Sec. 3.4.1, with the
    normalised residuals of Wohlberg 2017): every ``balance_every`` iterations, for
    each split, r_i = ||G_i x - z_i|| / max(||G_i x||, ||z_i||), s_i = ||z_i -
    z_i^prev|| / ||a_i||; mu_i is multiplied by ``balance_factor`` when r_i > ratio s_i
    and divided when s_i > ratio r_i, within :data:`recon.solvers.admm.MU_RANGE`, the
    scaled duals rescaled; it stops after ``balance_until`` of the iterations. Unlike
    the 2D ADMM, mu3 is balanced without TV too (the tie of
    :func:`~recon.solvers.penalty.tie_nonneg_penalty` damped the 3D fit: measured
    there).

    Memory (float32 volumes of ``op.shape_in``): the stacked [x, M x] buffer and the
    complex spectrum stack (about one volume each), q_w, and with TV q_uz, q_uy,
    q_ux; with balancing one stored dual per split volume (released when balancing
    ends); plus one snapshot (:class:`~recon.solvers.common.Monitor`). With TV and
    balancing: 11 volumes + the operator. The FFT outputs are new arrays each
    iteration (scipy.fft has no ``out=``); the heap recycles them
    (:func:`recon.fft.retain_freed_memory`).

    Parameters
    ----------
    op : VolumeConvolutionOperator
        3D forward model, ``shape_in = (n_z, P0, P1)``; sensor weights (erasure
        masks) enter the v-update.
    b : ndarray, shape ``op.shape_out``, float32
        Measurement (pre-weighted), scaled to O(1), with the stack normalised by
        :func:`~recon.volume.normalize_psf_stack`.
        An array of another array-API backend (CuPy, PyTorch) runs the same loop
        with the generic kernel set on its device
        (``recon.volume.xp_admm3d.XpVolumeAdmmPlan``).
    iterations : int
        Maximum iterations (default :data:`~recon.solvers.common.DEFAULT_ITERATIONS`).
    tv : float
        3D TV weight (default 0, as every solver's; 0 or None removes the u split).
    l1 : float
        l1 weight (native sparsity, on the w split; default 0).
    nonneg : bool
        Constrain x >= 0 (the w split).
    penalty : AdmmPenalty, optional
        The initial penalties ``mu`` of the v, u and w splits (default
        :data:`recon.solvers.penalty.DEFAULT_MU`) and the residual balancing settings
        (see above), as for the 2D ADMM (:class:`recon.solvers.AdmmPenalty`).
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping), as for
        the 2D ADMM.
    prior : str or Prior, optional
        The u split's prior (:mod:`recon.priors`): 3D TV (default) or a prior on the
        volume itself, plane by plane (``"wavelet"``, ``"dncnn"``), which runs the
        generic kernel set (``recon.volume.xp_admm3d.XpVolumeAdmmPlan``; u = x, no
        coupling between planes in the x-update); ``tv`` is then its weight.

    Returns
    -------
    SolveResult
        ``x``: the volume (n_z, P0, P1) float32 (max(x, 0) with ``nonneg``);
        ``history.objective[k]`` = 1/2 ||D M x_k - b||^2 + tv TV(x_k) + l1 ||x_k+||_1
        for the iterate entering iteration k (x_0 = 0; x_k+ = max(x_k, 0) with
        ``nonneg``, else x_k); ``final_objective`` exact at the returned x;
        ``history.extra['mu']`` the penalties used; ``params`` as every ADMM's
        (:func:`~recon.solvers.admm_loop.run_admm`).

    Raises
    ------
    DivergenceError
        NaN/inf or an objective 100x that of the zero volume.
    ReconInputError
        Not a volume operator, a bad measurement or invalid parameters.
    """
    plan = VolumeAdmmPlan.of(op)
    iterations = as_int(iterations, "iterations", 1)
    tv_w = nonneg_weight(tv, "TV")
    l1_w = nonneg_weight(l1, "l1")
    penalty = check_penalty_settings(penalty)
    prior = prior_of(prior)
    if prior.name != "tv" or not isinstance(b, np.ndarray):  # the generic kernel set
        from .xp_admm3d import XpVolumeAdmmPlan

        plan = XpVolumeAdmmPlan(plan, b, prior=prior)
    res = run_admm(plan, b, plan.zeros(penalty.initial(), tv_w > 0), iterations=iterations,
                   tv=tv_w, l1=l1_w, nonneg=nonneg, penalty=penalty, stop=stop)
    if prior.name != "tv":
        res.params["prior"] = prior.record()
    return res
