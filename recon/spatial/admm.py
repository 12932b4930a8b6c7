"""ADMM for the spatially varying models: the x-update linearized, preconditioned by
the convolution that bounds the model.

The 2D ADMM of :mod:`recon.solvers.admm` (the splitting of Eq. 4.5 / App. A.3:
v = M x for the crop, u = Psi x for TV, w = x for non-negativity and l1) converges in
a few hundred iterations because its x-update, the minimiser of

    mu1/2 ||M x - q_v||^2 + mu2/2 ||Psi x - q_u||^2 + mu3/2 ||x - q_w||^2,

is a diagonal solve in Fourier space when M is one convolution. For the local
convolution model (Eq. 5.5, M = sum_k H_k diag(alpha_k)) that system is not diagonal
in any basis. Here the x-update is one step of the subproblem's gradient,
preconditioned by the diagonal system nearest to it:

    x+ = x - P^-1 g,  g = mu1 M^T (M x - q_v) + mu2 Psi^T (Psi x - q_u) + mu3 (x - q_w),
    P = mu1 rho + mu2 |F Psi|^2 + mu3,  rho = max_i |F h_i|^2,

``h_i`` the model's PSF at node ``i`` (the node's kernel in the local model, its rank-k
approximation in the PCA model, whose weights are interpolated between the nodes
likewise). This is linearized
("generalized") ADMM: the x-update minimises the augmented Lagrangian plus
1/2 ||x - x_k||^2 over the metric P - Q, Q the subproblem's own Hessian; it
converges when P dominates Q (Deng & Yin 2016, J. Sci. Comput. 66). ``rho`` is
chosen to dominate: the PSF anywhere is a bilinear blend of the node PSFs (weights
alpha_i >= 0 summing to one), and per frequency |sum_i alpha_i H_i|^2 <=
sum_i alpha_i |H_i|^2 <= max_i |H_i|^2; that holds for weights that vary slowly, a
heuristic rather than a bound for every object, and the solver's divergence guard
stops a run that grows. With
one kernel, P = Q and the step is the exact x-update: the iterates of
:func:`recon.solvers.admm` (tested). The closer the kernels are to one another --
PSFs of a far scene divided by their brightness (:func:`recon.spatial.caustic_grid`,
Eq. 5.1) -- the closer P is to Q and the closer the convergence to the convolution
model's ADMM.

Cost per iteration: ``M^T`` (1 rfft2 + ``K`` irfft2), the preconditioned step (1 rfft2
+ 1 irfft2) and ``M x`` (``K`` rfft2 + 1 irfft2): ``2K + 4`` transforms, FISTA's
``2K + 2`` plus two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ReconInputError
from ..fft import irfftn, rfftn
from ..solvers.admm import AdmmPlan, AdmmState, admm, difference_power
from ..solvers.admm_loop import DEFAULT_ITERATIONS
from ..solvers.common import SolveResult
from . import _kernels as _spatial_kernels
from .operator import SpatialConvolutionOperator

__all__ = ["SpatialAdmmPlan", "spatial_admm"]


@dataclass
class SpatialAdmmPlan(AdmmPlan):
    """:class:`~recon.solvers.admm.AdmmPlan` of a 2D spatially varying model.

    Attributes
    ----------
    op : SpatialConvolutionOperator
        2D (``op.volume`` False).
    h_pow : ndarray, float32, (P0, P1 // 2 + 1)
        ``rho`` of the module docstring: the preconditioner's kernel power.
    """

    rhs_in_split = False  # the linearized x-update forms its own gradient

    @classmethod
    def of(cls, op: SpatialConvolutionOperator) -> SpatialAdmmPlan:
        """Precompute for ``op``.

        Raises
        ------
        ReconInputError
            Not a 2D :class:`~recon.spatial.SpatialConvolutionOperator`.
        """
        if not isinstance(op, SpatialConvolutionOperator) or op.volume:
            raise ReconInputError("spatial ADMM needs a 2D SpatialConvolutionOperator (the "
                                  "local convolution or PCA model of one PSF grid); for one "
                                  "PSF use recon.solvers.admm")
        wp = np.zeros(op.padded_shape, np.float32)
        wp[op.crop] = op.sensor_weights
        # the model's PSF at each node: sum_j c_j[node] F k_j (one kernel per node for
        # the local model; the rank-k approximation for PCA)
        coef = np.stack([c.ravel() for c in op.coefficients])  # (K, nodes)
        h_pow = np.zeros(op.spectra.shape[1:], np.float32)
        for node in range(coef.shape[1]):
            used = np.flatnonzero(coef[:, node])
            if used.size == 1:
                h = op.spectra[used[0]] * coef[used[0], node]
            else:
                h = np.tensordot(coef[used, node], op.spectra[used], axes=1)
            np.maximum(h_pow, h.real ** 2 + h.imag ** 2, out=h_pow)
        return cls(op, op.padded_shape, wp, h_pow, difference_power(op.padded_shape))

    def x_update(self, state: AdmmState, x: np.ndarray, mx: np.ndarray, mu
                 ) -> tuple[np.ndarray, np.ndarray]:
        """One preconditioned gradient step on the x-subproblem (module docstring).

        Parameters
        ----------
        state : AdmmState
            The q's and ``inv_den`` (= 1 / P); ``stacked[1]`` is used as scratch.
        x, mx : ndarray, float32, ``shape``
            The current iterate and ``M x`` (uncropped).
        mu : (mu1, mu2, mu3)

        Returns
        -------
        (x, mx) : new arrays, float32, ``shape``
        """
        mu1, mu2, mu3 = mu
        residual = np.subtract(mx, state.stacked[0], out=state.stacked[1])
        g = self.op.correlate_full(residual)
        _spatial_kernels.linearized_gradient_2d(x, state.qux, state.quy, state.qw, g, mu1,
                                                mu2, mu3, state.use_tv)
        step = rfftn(g)
        step *= state.inv_den
        x = x - irfftn(step, self.shape)
        return x, self.op.convolve_full(x)

    def ffts_per_iteration(self) -> dict:
        """Real 2D FFTs of one iteration at the padded shape (module docstring):
        ``K + 2`` rfft2 and ``K + 2`` irfft2, ``K`` the model's kernels."""
        k = int(self.op.spectra.shape[0])
        return {"rfft2": k + 2, "irfft2": k + 2}

    def device_parts(self, like):
        """The generic operator and x-update on ``like``'s backend, for
        ``recon.solvers.xp_admm.XpAdmmPlan`` (a measurement of another backend).

        Returns
        -------
        (XpSpatialConvolution, recon.spatial.xp_admm.linearized_x_update)
        """
        from .xp_admm import linearized_x_update
        from .xp_operator import XpSpatialConvolution

        return XpSpatialConvolution(self.op, like), linearized_x_update


def spatial_admm(op: SpatialConvolutionOperator, b: np.ndarray, *,
                 iterations: int = DEFAULT_ITERATIONS, tv: float = 0.0, l1: float = 0.0,
                 **options) -> SolveResult:
    """ADMM with TV, l1 and non-negativity for a 2D spatially varying model.

    :func:`recon.solvers.admm` with the linearized x-update of this module
    (:class:`SpatialAdmmPlan`): same splits, residual balancing, automatic stopping
    (``stop``) and result.

    Parameters
    ----------
    op : SpatialConvolutionOperator
        2D local convolution (Eq. 5.3-5.5) or PCA (Eq. 5.6-5.7) model, kernels scaled
        so the reference PSF has unit sum (:func:`recon.spatial.local_convolution_operator`).
    b : ndarray, float32, ``op.shape_out``
        Measurement, multiplied by the sensor weights, divided by its maximum. An
        array of another array-API backend (CuPy, PyTorch: on its device) runs the
        generic path (``recon.spatial.xp_admm``) and returns ``x`` on that device.
    iterations : int
    tv, l1 : float
        Weights (scaled problem), >= 0; default 0, as every solver's.
    **options
        ``penalty`` (:class:`~recon.solvers.AdmmPenalty`) and ``stop``: as
        :func:`recon.solvers.admm`.

    Returns
    -------
    SolveResult
        ``x`` on the padded object grid (``op.shape_in``), non-negative.

    Raises
    ------
    ReconInputError
        Not a 2D spatially varying model, or the parameter errors of
        :func:`recon.solvers.admm`.
    DivergenceError
        NaN/inf or an objective 100x that of the zero image.
    """
    return admm(op, b, iterations=iterations, tv=tv, l1=l1, plan=SpatialAdmmPlan.of(op),
                **options)
