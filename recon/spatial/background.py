"""Joint object and background estimation (Kuo 2020, Eq. 6.2).

    min_{y, g} 1/2 ||b - (A y + g)||^2 + tau ||y||_1
    s.t. y >= 0, g >= 0, D g = 0 outside the lowest n x n DCT coefficients,

solved with FISTA jointly over ``y`` and ``g`` (Sec. 6.2: "We jointly solve for y
and g using FISTA ... initialize the estimated background with a low-pass filtered
version of the raw data"). ``A`` is any forward model with ``forward`` /
``adjoint`` / ``data_term`` / ``lipschitz`` (2D or 3D: the local convolution model
of :mod:`recon.spatial.operator`, or the convolution models). The background
lives in the span of the ``n x n`` lowest orthonormal DCT-II basis images (``g =
By c Bx^T``, an isometry from the coefficients ``c``); its constraint set, that
span intersected with ``g >= 0``, is projected on by Dykstra's alternating
projections, ending on the span so ``D g = 0`` outside the support holds exactly.
The object's prox is the exact one of l1 plus non-negativity,
``max(v - step tau, 0)``. The step is ``1 / (L_A + 1)``: the joint operator
``[A, I]`` has ``||A y + g||^2 <= (L_A + 1)(||y||^2 + ||g||^2)``.
"""

from __future__ import annotations

import math

import numpy as np

from ..operators import LinearOperator
from ..solvers.accelerated import accelerated_loop
from ..solvers.common import DEFAULT_ITERATIONS, Monitor, SolveResult, check_measurement
from ..validate import as_int, nonneg_weight, positive
from .joint import LowFrequency, dct_basis, joint_lipschitz, joint_result, low_frequency

__all__ = ["dct_basis", "fista_background", "lowpass_background"]


def lowpass_background(b: np.ndarray, n_low: int = 5) -> np.ndarray:
    """The raw frame's projection on its ``n_low x n_low`` lowest DCT coefficients,
    clipped at 0: the background's initial value in :func:`fista_background`.

    Parameters
    ----------
    b : ndarray, (rows, cols)
    n_low : int

    Returns
    -------
    ndarray, float32, (rows, cols)
    """
    b = np.asarray(b, np.float32)
    return np.maximum(LowFrequency(b.shape, n_low).project(b), 0.0)


def fista_background(op: LinearOperator, b: np.ndarray, *, iterations: int = DEFAULT_ITERATIONS,
                     l1: float = 0.0, n_low: int = 5, restart: bool = True,
                     lipschitz: float | None = None, estimate_background: bool = True,
                     stop=None) -> SolveResult:
    """FISTA on Eq. 6.2: object (l1, non-negative) and a smooth non-negative background.

    Parameters
    ----------
    op : LinearOperator
        Forward model, 2D or 3D object (e.g.
        :func:`recon.spatial.local_convolution_operator`), kernels scaled as the
        solvers expect (unit-sum central PSF).
    b : ndarray, ``op.shape_out``, float32
        Measurement scaled to O(1) (divided by its maximum).
    iterations : int
        Maximum iterations (default :data:`~recon.solvers.common.DEFAULT_ITERATIONS`).
    l1 : float
        tau, the l1 weight (>= 0; default 0, as every solver's: Eq. 6.2's sparse
        object takes e.g. 1e-3, what :func:`recon.reconstruct` uses for a grid).
    n_low : int
        Background support: the ``n_low x n_low`` lowest DCT coefficients (5 in
        Sec. 6.2).
    restart : bool
        Gradient restart of the momentum (O'Donoghue & Candes 2015).
    lipschitz : float, optional
        Known L of ``A^T A`` (skips the power iteration).
    estimate_background : bool
        False keeps ``g = 0``: the same l1 FISTA without the background (for data
        whose background was removed otherwise, e.g. by
        :func:`recon.analysis.remove_background_dct`).
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping);
        ``iterations`` stays the maximum.

    Returns
    -------
    SolveResult
        ``x`` the object (``op.shape_in``); ``params["background"]`` the background
        (sensor shape, float32, in the measurement's units), also its DCT
        coefficients ``params["background_dct"]`` (n_low, n_low);
        ``history.objective`` per iteration (at the extrapolated point y_k, data term
        and l1 both); ``params`` with ``iterations`` (the maximum) and
        ``iterations_used``.

    Raises
    ------
    ReconInputError
        Bad measurement or parameters, or a zero forward model.
    DivergenceError
        Objective NaN/inf or 100x that of the zero estimate.
    """
    iterations = as_int(iterations, "iterations", 1)
    tau = nonneg_weight(l1, "l1")
    lipschitz = None if lipschitz is None else positive(lipschitz, "lipschitz")
    if not isinstance(b, np.ndarray):  # another backend: the array-API path
        from .xp_background import fista_background_xp

        return fista_background_xp(op, b, iterations=iterations, l1=tau, n_low=n_low,
                                   restart=restart, lipschitz=lipschitz, stop=stop,
                                   estimate_background=estimate_background)
    b = check_measurement(b, op.shape_out)
    low = low_frequency(b, n_low)
    lip_a = joint_lipschitz(op, lipschitz)
    step = 1.0 / (lip_a + 1.0)
    mon = Monitor(float(np.vdot(b, b)), "FISTA with background")
    g0 = (lowpass_background(b, n_low) if estimate_background
          else np.zeros(b.shape, np.float32))
    # the joint variable [object; background] in one buffer, viewed as its two parts
    n = math.prod(op.shape_in)
    joint = np.zeros(n + b.size, np.float32)

    def parts(v):
        return v[:n].reshape(op.shape_in), v[n:].reshape(b.shape)

    x, g = parts(joint)
    g[...] = low.project_nonneg(g0) if estimate_background else g0

    def data_term(v):
        y, gy = parts(v)
        resid = op.forward(y) + gy - b  # A y + g - b: both gradients from it
        return 0.5 * float(np.vdot(resid, resid)), (op.adjoint(resid), resid)

    def prox_step(v, grads, v_new, v_next, beta):
        (y, gy), (x, g), (y_next, gy_next) = parts(v), parts(v_new), parts(v_next)
        grad, resid = grads
        x_new = np.maximum(y - step * grad - step * tau, 0.0).astype(np.float32)
        g_new = low.project_nonneg(gy - step * resid) if estimate_background else g.copy()
        dot = float(np.vdot(y - x_new, x_new - x)) + float(np.vdot(gy - g_new, g_new - g))
        y_next[...] = x_new + beta * (x_new - x)
        gy_next[...] = g_new + beta * (g_new - g)
        x[...], g[...] = x_new, g_new
        return tau * float(np.abs(y).sum(dtype=np.float64)), dot

    used, restarts = accelerated_loop(joint, iterations=iterations, data_term=data_term,
                                      prox_step=prox_step, monitor=mon, restart=restart,
                                      stop=stop, snapshot=x)
    x, g = x.copy(), g.copy()
    resid = op.forward(x) + g - b
    data_sq = float(np.vdot(resid, resid))
    return joint_result(x, g, mon, data_sq, float(x.sum(dtype=np.float64)), low,
                        {"step": step, "lipschitz": lip_a, "l1": tau, "n_low": int(n_low),
                         "restart": restart, "iterations": iterations,
                         "iterations_used": used}, restarts)
