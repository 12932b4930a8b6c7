"""Joint object and background FISTA (Kuo 2020, Eq. 6.2) on any array-API backend.

:func:`recon.spatial.fista_background` given a measurement of another backend runs
:func:`fista_background_xp`: the same problem,

    min_{y, g} 1/2 ||b - (A y + g)||^2 + tau ||y||_1,  y >= 0, g >= 0, g low-pass,

the same loop (:func:`recon.solvers.accelerated.accelerated_loop`), step
``1 / (L_A + 1)``, prox ``max(v - step tau, 0)`` and Dykstra projection of the
background onto the lowest DCT coefficients, with the forward model on the device
(:func:`recon.spatial.xp_operator.device_operator`: the local convolution and PCA
models, or a convolution model). The joint variable is one flat array whose two
parts are written whole each iteration (the standard promises no views).
"""

from __future__ import annotations

import math

from ..solvers.accelerated import accelerated_loop
from ..solvers.xp_common import XpMonitor, check_measurement_xp, total
from .joint import joint_lipschitz, joint_result, low_frequency
from .xp_operator import device_operator

__all__ = ["fista_background_xp"]


class _ObjectMonitor(XpMonitor):
    """:class:`~recon.solvers.xp_common.XpMonitor` of the joint variable that keeps
    only its object part as the last good estimate."""

    def __init__(self, xp, b_norm_sq: float, parts):
        super().__init__(xp, b_norm_sq, "FISTA with background")
        self.parts = parts

    def record(self, objective, data_sq, x=None, hint=""):
        super().record(objective, data_sq, None if x is None else self.parts(x)[0], hint)


def fista_background_xp(op, b, *, iterations: int, l1: float, n_low: int, restart: bool,
                        lipschitz: float | None, estimate_background: bool, stop=None):
    """:func:`recon.spatial.fista_background` on ``b``'s backend (parameters validated).

    Parameters
    ----------
    op : SpatialConvolutionOperator, ConvolutionOperator or VolumeConvolutionOperator
        The NumPy forward model, moved to ``b``'s device.
    b : array (array API), float32, ``op.shape_out``
        Measurement scaled to O(1), on the target device.
    iterations, l1, n_low, restart, estimate_background, stop
        As :func:`recon.spatial.fista_background`.
    lipschitz : float, optional
        Known L of ``A^T A``; else the power iteration on the device (from the NumPy
        path's random start).

    Returns
    -------
    SolveResult
        ``x`` (``op.shape_in``), ``params["background"]`` (sensor shape) and
        ``params["background_dct"]`` on ``b``'s device; the rest as the NumPy path's.

    Raises
    ------
    ReconInputError
        Bad measurement, a 3D sensor image, a zero forward model, an operator with no
        generic form.
    DivergenceError
        Objective NaN/inf or 100x that of the zero estimate (``last_good`` the object,
        on the host).
    """
    xop = device_operator(op, b)
    xp = xop.xp
    b = check_measurement_xp(b, tuple(op.shape_out))
    low = low_frequency(b, n_low)
    lip_a = joint_lipschitz(xop, lipschitz)
    step = 1.0 / (lip_a + 1.0)
    shape_in, shape_out = tuple(op.shape_in), tuple(b.shape)
    n = math.prod(shape_in)

    def parts(v):
        return xp.reshape(v[:n], shape_in), xp.reshape(v[n:], shape_out)

    def joint(x, g):
        return xp.concat([xp.reshape(x, (-1,)), xp.reshape(g, (-1,))])

    mon = _ObjectMonitor(xp, total(xp, b * b), parts)
    zeros = xp.zeros(shape_out, dtype=xp.float32, device=xop.device)
    g = (low.project_nonneg(xp.maximum(low.project(b), 0.0)) if estimate_background
         else zeros)
    v = joint(xp.zeros(shape_in, dtype=xp.float32, device=xop.device), g)

    def data_term(v):
        y, gy = parts(v)
        resid = xop.forward(y) + gy - b  # A y + g - b: both gradients from it
        return 0.5 * total(xp, resid * resid), (xop.adjoint(resid), resid)

    def prox_step(v, grads, v_new, v_next, beta):
        (y, gy), (x, g) = parts(v), parts(v_new)
        grad, resid = grads
        x_new = xp.maximum(y - step * grad - step * l1, 0.0)
        g_new = low.project_nonneg(gy - step * resid) if estimate_background else g
        dot = total(xp, (y - x_new) * (x_new - x)) + total(xp, (gy - g_new) * (g_new - g))
        v_next[...] = joint(x_new + beta * (x_new - x), g_new + beta * (g_new - g))
        v_new[...] = joint(x_new, g_new)
        return l1 * total(xp, xp.abs(y)), dot

    used, restarts = accelerated_loop(v, iterations=iterations, data_term=data_term,
                                      prox_step=prox_step, monitor=mon, restart=restart,
                                      stop=stop, y=xp.asarray(v, copy=True))
    x, g = parts(v)
    x, g = xp.asarray(x, copy=True), xp.asarray(g, copy=True)
    resid = xop.forward(x) + g - b
    return joint_result(x, g, mon, total(xp, resid * resid), total(xp, x), low,
                        {"step": step, "lipschitz": lip_a, "l1": l1, "n_low": int(n_low),
                         "restart": restart, "iterations": iterations,
                         "iterations_used": used, "backend": xp.__name__}, restarts)
