"""Accelerated (proximal) gradient solvers: GD with Nesterov momentum, and FISTA.

Both minimise 1/2 ||A x - b||^2 + tau TV(x) subject to x >= 0 (Eq. 2.5), with TV
handled by the Haar-shift approximation of App. A.1 (Kamilov, Bostan & Unser
2012) and the non-negativity projection after it (Sec. 2.3). The step is 1/L with
L from power iteration.
"""

from __future__ import annotations

import math

import numpy as np

from .. import _kernels
from ..errors import ReconInputError
from ..operators import LinearOperator
from ..validate import as_int, finite_float, nonneg_weight, positive
from .accelerated import accelerated_loop
from .common import (
    DEFAULT_ITERATIONS,
    Monitor,
    SolveResult,
    anisotropic_tv,
    check_measurement,
)


def prox_threshold(step: float, tau: float, ndim: int) -> float:
    """Threshold on the half-differences of App. A.1 for a step of tau*TV.

    Averaging the per-axis Haar shrinkage over ``ndim`` axes shrinks each axis by
    1/ndim; thr = 2 * ndim * step * tau makes the update match the subgradient
    step of anisotropic TV in the small-threshold limit.
    """
    return 2.0 * ndim * step * tau


def _accelerated(op: LinearOperator, b: np.ndarray, iterations: int, tv: float,
                 nonneg: bool, step_scale: float, momentum, restart: bool,
                 method: str, lipschitz: float | None = None, l1: float = 0.0,
                 stop=None, x0: np.ndarray | None = None, observe=None) -> SolveResult:
    iterations = as_int(iterations, "iterations", 1)
    tv = nonneg_weight(tv, "TV")
    l1 = nonneg_weight(l1, "l1")
    if l1 > 0 and not nonneg:
        raise ReconInputError("the l1 weight here needs nonneg=True (l1 on x >= 0 is linear)")
    step_scale = positive(step_scale, "step_scale")
    if len(op.shape_in) != 2:
        raise ReconInputError(f"{method} supports 2D objects here, got {op.shape_in}")
    if lipschitz is not None:
        lipschitz = positive(lipschitz, "lipschitz")
    if not isinstance(b, np.ndarray):  # another backend: the array-API path
        if observe is not None:
            raise ReconInputError("observe takes NumPy solves only; run on the CPU "
                                  "(device='cpu') to observe the iterations")
        from .xp_fista import accelerated_xp

        return accelerated_xp(op, b, iterations=iterations, tv=tv, nonneg=nonneg,
                              step_scale=step_scale, momentum=momentum, restart=restart,
                              method=method, lipschitz=lipschitz, l1=l1, stop=stop, x0=x0)
    b = check_measurement(b, op.shape_out)
    if lipschitz is not None:
        lip = lipschitz
    elif not (lip := op.lipschitz()) > 0:
        raise ReconInputError("forward model is zero (Lipschitz constant 0): check the PSF")
    step = step_scale / lip
    thr = prox_threshold(step, tv, 2)
    mon = Monitor(float(np.vdot(b, b)), method,)
    hint = ("the step is too large: lower the step scale (<= 1 is always stable)"
            if step_scale > 1 else "check the PSF and measurement scaling"
            + (f", or use a smaller TV weight than {tv:g}" if tv > 0 else ""))
    if x0 is None:
        x = np.zeros(op.shape_in, np.float32)
    else:
        x = np.array(x0, np.float32, copy=True, order="C")
        if x.shape != tuple(op.shape_in):
            raise ReconInputError(f"x0 has shape {x.shape}, the model's object is "
                                  f"{tuple(op.shape_in)}")

    def data_term(y):
        loss, grad = op.data_term(y, b)
        if l1 > 0:  # on x >= 0, l1 ||x||_1 = l1 sum(x): a constant gradient
            grad += np.float32(l1)
        return loss, grad

    def prox_step(y, grad, x, y_next, beta):
        l1_y = l1 * float(y.sum(dtype=np.float64)) if l1 > 0 else 0.0
        tv_y, dot = _kernels.proximal_step_2d(y, grad, x, y_next, step, thr, beta, nonneg)
        return tv * tv_y + l1_y, dot

    used, restarts = accelerated_loop(x, iterations=iterations, data_term=data_term,
                                      prox_step=prox_step, monitor=mon, momentum=momentum,
                                      restart=restart, stop=stop, hint=hint, observe=observe)
    r = op.forward(x) - b
    data_sq = float(np.vdot(r, r))
    final = 0.5 * data_sq + tv * anisotropic_tv(x) + l1 * float(x.sum(dtype=np.float64))
    mon.history.extra["restarts"] = restarts
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm,
                       {"step": step, "lipschitz": lip, "tv": tv, "tv_threshold": thr,
                        "nonneg": nonneg, "momentum": momentum, "restart": restart,
                        "l1": l1, "iterations": iterations, "iterations_used": used})


def fista(op: LinearOperator, b: np.ndarray, *, iterations: int = DEFAULT_ITERATIONS,
          tv: float = 0.0, nonneg: bool = True, step_scale: float = 1.0, restart: bool = True,
          lipschitz: float | None = None, l1: float = 0.0, stop=None,
          x0: np.ndarray | None = None, observe=None) -> SolveResult:
    """FISTA (Kuo 2020, Algorithm 1; Beck & Teboulle 2009) with non-negativity and TV.

    Each iteration: grad = A^T (A y_k - b) (4 FFTs, fused crop); x_{k+1} = prox(y_k -
    step grad) with the Haar-shift TV of App. A.1 and max(., 0);
    t_{k+1} = (1 + sqrt(1 + 4 t_k^2)) / 2; y_{k+1} = x_{k+1} + (t_k - 1)/t_{k+1} (x_{k+1} - x_k).
    With ``restart`` the momentum is reset when it points uphill (gradient restart,
    O'Donoghue & Candes 2015), which removes FISTA's ripples at no cost.

    Parameters
    ----------
    op : LinearOperator
        2D forward model, e.g. :class:`recon.operators.ConvolutionOperator`.
    b : ndarray, shape ``op.shape_out``, float32
        Measurement (scaled so its values are O(1), see :func:`recon.reconstruct`). An
        array of another array-API backend (CuPy, PyTorch) runs the generic path
        ``recon.solvers.xp_fista.accelerated_xp`` on its device (``op`` a
        :class:`~recon.operators.ConvolutionOperator`).
    iterations : int
        Maximum iterations (default :data:`~recon.solvers.common.DEFAULT_ITERATIONS`, the
        declared one).
    tv : float
        TV weight tau (default 0, as every solver's; 0 disables TV).
    nonneg : bool
        Project onto x >= 0.
    step_scale : float
        Step = step_scale / L; values above 2 diverge (caught, see Raises).
    restart : bool
    lipschitz : float, optional
        Known L (skips the power iteration).
    l1 : float
        l1 weight (sparse scenes); with x >= 0 it adds the constant l1 to the gradient.
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping).
    x0 : ndarray, shape ``op.shape_in``, optional
        Starting point (warm start; default zero), momentum restarted.
    observe : callable, optional
        ``observe(k, x)`` after iteration ``k`` (1-based) with the iterate x_k (float32,
        ``op.shape_in``, the solver's own array: copy what you keep); what a solve of
        ``k`` iterations would return (without ``stop``). NumPy arrays only.

    Returns
    -------
    SolveResult
        ``history.objective[k]`` is evaluated at the extrapolated point y_k where the
        gradient is computed (free); ``final_objective`` is exact at the returned x.

    Raises
    ------
    DivergenceError
        Objective NaN/inf or 100x that of the zero image (e.g. an over-large step).
    ReconInputError
        Invalid parameters.

    Examples
    --------
    Two points behind a small PSF, in the scaled problem (unit-sum PSF):

    >>> import numpy as np
    >>> from recon.operators import ConvolutionOperator
    >>> psf = np.zeros((16, 16), np.float32); psf[6:10, 7:9] = 0.125
    >>> op = ConvolutionOperator(psf)
    >>> x = np.zeros(op.shape_in, np.float32); x[12, 13] = 1.0; x[20, 17] = 0.5
    >>> res = fista(op, op.forward(x), iterations=100)
    >>> sorted(zip(*np.unravel_index(np.argsort(res.x.ravel())[-2:], res.x.shape)))
    [(np.int64(12), np.int64(13)), (np.int64(20), np.int64(17))]
    >>> res.final_relative_residual < 0.05
    True
    """
    return _accelerated(op, b, iterations, tv, nonneg, step_scale, None, restart, "FISTA",
                        lipschitz, l1, stop, x0, observe)


def gradient_descent(op: LinearOperator, b: np.ndarray, *,
                     iterations: int = DEFAULT_ITERATIONS,
                     tv: float = 0.0, nonneg: bool = True, momentum: float = 0.9,
                     step_scale: float = 1.0, lipschitz: float | None = None,
                     l1: float = 0.0, stop=None) -> SolveResult:
    """Projected gradient descent with constant Nesterov momentum.

    y_{k+1} = x_{k+1} + momentum (x_{k+1} - x_k), x_{k+1} = prox(y_k - grad/L), the
    same prox as :func:`fista` (TV optional, non-negativity). Without the FISTA
    sequence and restart; kept as the simple baseline of the published tutorials.

    Parameters and returns as :func:`fista`; ``momentum`` in [0, 1).
    """
    momentum = finite_float(momentum, "momentum", lo=0.0)
    if not momentum < 1.0:
        raise ReconInputError(f"momentum must be in [0, 1), got {momentum}")
    return _accelerated(op, b, iterations, tv, nonneg, step_scale, momentum, False,
                        "gradient descent", lipschitz, l1, stop)
