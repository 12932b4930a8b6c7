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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft
from numba import get_num_threads

from ..errors import ReconInputError
from ..fft import WORKERS, rfftn
from ..solvers.common import Monitor, SolveResult, check_measurement
from ..solvers.penalty import (
    AdmmPenalty,
    admm_result,
    check_penalty_settings,
    rescale_duals,
)
from ..validate import as_int, nonneg_weight
from . import _admm_kernels3d as _k
from .fista import final_objective
from .operator import VolumeConvolutionOperator

#: Default initial penalties (mu1, mu2, mu3) for the scaled problem (stack
#: normalised by :func:`~recon.volume.normalize_psf_stack`, |b| <= 1).
DEFAULT_MU = (2e-3, 2e-3, 2e-3)


def lateral_difference_power(padded_shape: tuple[int, int]) -> np.ndarray:
    """``|F Psi_lat|^2`` on the rfft grid: ``sum_a (2 - 2 cos(2 pi k_a / N_a))``, float32.

    The lateral part of ``Psi^T Psi`` for circular forward differences along y and x.
    """
    k0 = np.fft.fftfreq(padded_shape[0])[:, None]
    k1 = np.fft.rfftfreq(padded_shape[1])[None, :]
    return ((2 - 2 * np.cos(2 * np.pi * k0)) + (2 - 2 * np.cos(2 * np.pi * k1))).astype(
        np.float32)


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
class VolumeAdmmPlan:
    """What 3D ADMM precomputes from the operator (the 3D counterpart of
    :class:`recon.solvers.admm.AdmmPlan`, with the same interface for the automatic
    weight, :func:`recon.auto.weight.admm_auto`: ``zeros``, ``warm``, ``run``,
    ``objective``).

    Attributes
    ----------
    op : VolumeConvolutionOperator
    shape : (P0, P1)
        ``op.padded_shape``.
    wp : ndarray, float32, (P0, P1)
        Sensor weights zero-padded to the lateral object domain.
    d_lat : ndarray, float32, (P0, P1 // 2 + 1)
        Lateral ``|F Psi|^2`` (:func:`lateral_difference_power`).
    """

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
        return cls(op, op.padded_shape, wp, lateral_difference_power(op.padded_shape))

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

    def run(self, b: np.ndarray, state: VolumeAdmmState, *, iterations: int, tv: float,
            l1: float = 0.0, final: bool = True) -> SolveResult:
        """:func:`run_admm3d` from ``state`` (updated in place)."""
        return run_admm3d(self, b, state, iterations=iterations, tv=tv, l1=l1, final=final)

    def objective(self, b: np.ndarray, x: np.ndarray, *, tv: float, l1: float,
                  b_norm: float) -> tuple[float, float]:
        """Objective of Eq. 4.5 at ``x`` and its relative data residual against ``b``."""
        final, data_sq = final_objective(self.op, x, b, tv, l1)
        return final, math.sqrt(data_sq) / b_norm


@dataclass
class VolumeAdmmState:
    """The 3D ADMM iterate, carried from one call of :func:`run_admm3d` to the next.

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


def run_admm3d(plan: VolumeAdmmPlan, b: np.ndarray, state: VolumeAdmmState, *,
               iterations: int, tv: float, l1: float = 0.0, nonneg: bool = True,
               penalty: AdmmPenalty | None = None, final: bool = True) -> SolveResult:
    """Run ``iterations`` 3D ADMM iterations from ``state`` (updated in place).

    The loop of :func:`admm3d`, which validates the parameters and starts from
    :meth:`VolumeAdmmPlan.zeros`; the automatic weight continues a state along its
    path of weights (:func:`recon.auto.weight.admm_auto`). Balancing runs over the
    first ``balance_until`` of this call's iterations.

    Parameters
    ----------
    plan : VolumeAdmmPlan
    b : ndarray, float32, ``plan.op.shape_out``
    state : VolumeAdmmState
        ``state.use_tv`` must equal ``tv > 0``.
    iterations, tv, l1, nonneg, penalty
        As :func:`admm3d` (validated by the caller); the state's penalties are the
        initial ones (``penalty.mu`` is used only by :func:`admm3d`).
    final : bool
        Evaluate the returned estimate's objective and residual (one forward model);
        False reports the last iteration's from the history.

    Returns
    -------
    SolveResult
        As :func:`admm3d`.

    Raises
    ------
    DivergenceError
        NaN/inf or an objective 100x that of the zero volume.
    ReconInputError
        A bad measurement, or a state made for the other sign of ``tv``.
    """
    op = plan.op
    tv_w, l1_w = float(tv), float(l1)
    if state.use_tv != (tv_w > 0):
        raise ReconInputError(f"3D ADMM state was made for tv {'> 0' if state.use_tv else '= 0'}"
                              f" but tv={tv_w}; start from VolumeAdmmPlan.zeros(mu, tv > 0)")
    b = check_measurement(b, op.shape_out)
    penalty = check_penalty_settings(penalty)
    use_tv = state.use_tv
    mu1, mu2, mu3 = state.mu
    nz = op.n_z
    shape = plan.shape
    wp = plan.wp
    bp = np.zeros(shape, np.float32)
    bp[op.crop] = b
    d_lat = plan.d_lat
    spectra = op.spectra
    stack, qv, qw, quz, quy, qux = (state.stack, state.qv, state.qw, state.quz, state.quy,
                                    state.qux)
    dummy3 = np.zeros((1, 1, 1), np.float32)
    last_balance = penalty.last_balance(iterations)
    if last_balance > 0:
        av = np.zeros(shape, np.float32)
        aw = np.zeros(op.shape_in, np.float32)
        auz, auy, aux = ((np.zeros(op.shape_in, np.float32) for _ in range(3))
                         if use_tv else (dummy3, dummy3, dummy3))
    else:
        av = np.zeros((1, 1), np.float32)
        aw = auz = auy = aux = dummy3

    rows = np.zeros((nz * shape[0], 10))  # per-row sums of the volume split pass
    mon = Monitor(float(np.vdot(b, b)), "3D ADMM")
    hint = "try method fista3d or smaller TV / l1 weights"
    mus = [(mu1, mu2, mu3)]
    for k in range(iterations):
        mon.start()
        if k == last_balance and k > 0:  # balancing over: drop the stored duals
            av = np.zeros((1, 1), np.float32)
            aw = auz = auy = aux = dummy3
        mode = penalty.mode(k, last_balance)
        x, mx = stack[:nz], stack[nz]
        sv = _k.admm_split_plane(mx, qv, bp, wp, mu1, mode, av)
        su = _k.admm_split_volume(x, quz, quy, qux, qw, l1_w / mu3,
                                  tv_w / mu2 if use_tv else 0.0, use_tv, nonneg, mode,
                                  auz, auy, aux, aw, rows)
        data_sq, tv_x, l1_x = sv[0], su[0], su[1]
        if mode == 2:
            new = [penalty.balanced(mu1, *sv[1:]),
                   penalty.balanced(mu2, *su[2:6]) if use_tv else mu2,
                   penalty.balanced(mu3, *su[6:10])]
            if tuple(new) != (mu1, mu2, mu3):
                splits = [(qv, av, mu1, new[0]), (qw, aw, mu3, new[2])]
                if use_tv:
                    splits += [(q, a, mu2, new[1]) for q, a in ((quz, auz), (quy, auy),
                                                                (qux, aux))]
                rescale_duals(splits)
                mu1, mu2, mu3 = new
                mus.append((mu1, mu2, mu3))
        # objective of the iterate entering this iteration (before x is overwritten)
        objective = 0.5 * data_sq + tv_w * tv_x + l1_w * l1_x
        _k.admm_rhs_3d(quz, quy, qux, qw, x, mu2, mu3, use_tv)  # R over x
        np.copyto(mx, qv)
        spec = rfftn(stack)
        del x, mx
        stack = None  # let the allocator recycle it for the inverse transform
        solve_x_update(spec, spectra, d_lat, (mu1, mu2, mu3), use_tv)
        stack = sfft.irfftn(spec, s=shape, axes=(-2, -1), workers=WORKERS, overwrite_x=True)
        spec = None
        state.stack = stack  # the state stays whole even if the next iteration diverges
        mon.record(objective, data_sq, x=stack[:nz], hint=hint)
    state.mu = (mu1, mu2, mu3)
    x = stack[:nz]
    if nonneg:
        x = np.maximum(x, 0)  # the estimate is the non-negative split
    x = np.ascontiguousarray(x)
    if final:
        objective, data_sq = final_objective(op, x, b, tv_w, l1_w)
        relative = math.sqrt(data_sq) / mon.b_norm
    else:
        objective, relative = mon.history.objective[-1], mon.history.data_residual[-1]
    return admm_result(x, mon.history, objective, relative, tv=tv_w, l1=l1_w, mus=mus,
                       penalty=penalty, iterations=iterations, used=iterations,
                       nonneg=nonneg, ffts_per_iteration={"rfft2": nz + 1, "irfft2": nz + 1})


def admm3d(op: VolumeConvolutionOperator, b: np.ndarray, *, iterations: int = 100,
           tv: float = 0.0, l1: float = 0.0, nonneg: bool = True,
           penalty: AdmmPenalty | None = None) -> SolveResult:
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

    Residual balancing (Boyd et al. 2011, Sec. 3.4.1, with the normalised residuals
    of Wohlberg 2017, as the 2D ADMM): every ``balance_every`` iterations, for each
    split, r_i = ||G_i x - z_i|| / max(||G_i x||, ||z_i||), s_i = ||z_i - z_i^prev||
    / ||a_i||; mu_i is multiplied by ``balance_factor`` when r_i > ratio s_i and
    divided when s_i > ratio r_i, within :data:`recon.solvers.admm.MU_RANGE`, the
    scaled duals rescaled; it stops after ``balance_until`` of the iterations.

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
        An array of another array-API backend (CuPy, PyTorch) runs the generic path
        ``recon.volume.xp_admm3d.admm3d_xp`` on its device.
    iterations : int
    tv : float
        3D TV weight (default 0, as every solver's; 0 or None removes the u split).
    l1 : float
        l1 weight (native sparsity, on the w split; default 0).
    nonneg : bool
        Constrain x >= 0 (the w split).
    penalty : AdmmPenalty, optional
        The initial penalties ``mu`` of the v, u and w splits (default
        :data:`DEFAULT_MU`) and the residual balancing settings (see above), as for
        the 2D ADMM (:class:`recon.solvers.AdmmPenalty`).

    Returns
    -------
    SolveResult
        ``x``: the volume (n_z, P0, P1) float32 (max(x, 0) with ``nonneg``);
        ``history.objective[k]`` = 1/2 ||D M x_k - b||^2 + tv TV(x_k) + l1 ||x_k||_1
        for the iterate entering iteration k (x_0 = 0); ``final_objective`` exact
        at the returned x; ``history.extra['mu']`` the penalties used.

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
    if not isinstance(b, np.ndarray):  # another backend: the array-API path
        from .xp_admm3d import admm3d_xp

        return admm3d_xp(plan, b, iterations=iterations, tv=tv_w, l1=l1_w, nonneg=nonneg,
                         penalty=penalty, mu0=penalty.initial(DEFAULT_MU))
    b = check_measurement(b, op.shape_out)
    return run_admm3d(plan, b, plan.zeros(penalty.initial(DEFAULT_MU), tv_w > 0),
                      iterations=iterations, tv=tv_w, l1=l1_w, nonneg=nonneg, penalty=penalty)
