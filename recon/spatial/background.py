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
import scipy.fft as sfft

from ..errors import ReconInputError
from ..operators import LinearOperator
from ..solvers.accelerated import accelerated_loop
from ..solvers.common import Monitor, SolveResult, check_measurement
from ..validate import as_int, nonneg_weight, positive

__all__ = ["dct_basis", "fista_background", "lowpass_background"]


def dct_basis(length: int, n_low: int) -> np.ndarray:
    """The ``n_low`` lowest orthonormal DCT-II basis vectors of a length, (length, n_low).

    Columns are orthonormal, so ``B B^T`` projects onto their span and ``B^T x``
    are the DCT coefficients of :func:`scipy.fft.dct` (``norm="ortho"``).
    """
    eye = np.eye(length, n_low)
    return sfft.idct(eye, type=2, norm="ortho", axis=0)


class _LowFrequency:
    """The span of the ``n x n`` lowest DCT basis images of a (rows, cols) frame."""

    def __init__(self, shape, n_low: int):
        n_low = as_int(n_low, "background DCT size n_low", 1)
        if n_low > min(shape):
            raise ReconInputError(f"background DCT size {n_low} exceeds the sensor {shape}")
        self.by = dct_basis(shape[0], n_low).astype(np.float32)
        self.bx = dct_basis(shape[1], n_low).astype(np.float32)

    def coefficients(self, g):
        return self.by.T @ g @ self.bx

    def image(self, c):
        return (self.by @ c @ self.bx.T).astype(np.float32)

    def project(self, g):
        return self.image(self.coefficients(g))

    def project_nonneg(self, g, rounds: int = 8):
        """Dykstra's projection onto span & {g >= 0}; the result lies in the span."""
        x = g
        p = np.zeros_like(g)
        q = np.zeros_like(g)
        for _ in range(rounds):
            yk = np.maximum(x + p, 0.0)
            p = x + p - yk
            x = self.project(yk + q)
            q = yk + q - x
            if x.min() >= 0:
                break
        return x


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
    return np.maximum(_LowFrequency(b.shape, n_low).project(b), 0.0)


def fista_background(op: LinearOperator, b: np.ndarray, *, iterations: int = 100,
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
    b = check_measurement(b, op.shape_out)
    if len(b.shape) != 2:
        raise ReconInputError("the background model needs a 2D sensor image")
    low = _LowFrequency(b.shape, n_low)
    if lipschitz is not None:
        lip_a = positive(lipschitz, "lipschitz")
    elif not ((lip_a := op.lipschitz()) > 0 and math.isfinite(lip_a)):
        raise ReconInputError("forward model is zero (Lipschitz constant 0): check the PSFs")
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
    final = 0.5 * data_sq + tau * float(x.sum(dtype=np.float64))
    mon.history.extra["restarts"] = restarts
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm,
                       {"step": step, "lipschitz": lip_a, "l1": tau, "n_low": int(n_low),
                        "background": g, "background_dct": low.coefficients(g),
                        "restart": restart, "iterations": iterations,
                        "iterations_used": used})
