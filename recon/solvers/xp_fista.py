"""2D FISTA and gradient descent with TV, l1 and non-negativity on any array-API backend.

The proximal step of :func:`recon._kernels.proximal_step_2d` (the Haar-shift TV of
Kuo 2020, App. A.1; Kamilov, Bostan & Unser 2012, then max(., 0)) as whole-array
operations, along any number of axes (the 3D FISTA's too,
:mod:`recon.volume.xp_fista3d`); the loop is the one of every FISTA of the project
(:func:`recon.solvers.accelerated.accelerated_loop`).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ReconInputError
from ..operators import ConvolutionOperator
from ..xp_operators import XpConvolution
from .accelerated import accelerated_loop
from .common import SolveResult
from .xp_common import XpMonitor, check_measurement_xp, forward_difference, total, tv_circular

__all__ = ["accelerated_xp", "device_problem", "proximal_step", "tv_open"]


def tv_open(xp, y, open_axis: int | None = None) -> float:
    """Anisotropic TV of ``y``: |forward differences| along every axis, circular but
    along ``open_axis`` (a volume's depth: no wrap)."""
    return sum(total(xp, xp.abs(forward_difference(xp, y, ax, ax != open_axis)))
               for ax in range(y.ndim))


def proximal_step(xp, y, grad, x, step: float, thr: float, beta: float, nonneg: bool,
                  l1thr: float = 0.0, open_axis: int | None = None):
    """One accelerated proximal-gradient update: :func:`recon._kernels.proximal_step_2d`
    on an image, :func:`recon.volume._kernels3d.proximal_step_3d` on a volume
    (``open_axis=0``: depth pairs stop at the first and last planes).

    ``z = y - step grad``; the Haar-shift TV of App. A.1 along every axis (threshold
    ``thr`` on the half-differences, averaged over the ``ndim`` axes: each element
    moves by ``sum_axes [clip(d_k) - clip(d_{k-1})] / (2 ndim)``); the l1 soft
    threshold ``l1thr``; then ``max(., 0)`` with ``nonneg``.

    Returns
    -------
    x_new, y_next : arrays
    tv_y : float
        Anisotropic TV of ``y`` (:func:`tv_open`).
    dot : float
        ``<y - x_new, x_new - x>`` (gradient restart test).
    """
    z = y - step * grad
    x_new = z
    if thr > 0:
        corr = None
        for ax in range(z.ndim):
            fwd = forward_difference(xp, z, ax, ax != open_axis)
            bwd = xp.roll(fwd, 1, axis=ax)  # z - z[i-1]; zero first slice when open
            term = (xp.clip(0.5 * fwd, min=-thr, max=thr)
                    - xp.clip(0.5 * bwd, min=-thr, max=thr))
            corr = term if corr is None else corr + term
        x_new = z + corr / (2.0 * z.ndim)
    if l1thr > 0:
        x_new = x_new - xp.clip(x_new, min=-l1thr, max=l1thr)
    if nonneg:
        x_new = xp.clip(x_new, min=0.0)
    step_x = x_new - x
    return (x_new, x_new + beta * step_x, tv_open(xp, y, open_axis),
            total(xp, (y - x_new) * step_x))


def device_problem(op, b, op_type: type, xp_type: type, method: str):
    """The generic operator of ``op`` on ``b``'s device, its namespace and the checked
    measurement (:func:`~recon.solvers.xp_common.check_measurement_xp`).

    Raises
    ------
    ReconInputError
        ``op`` is not an ``op_type``, or a bad measurement.
    """
    if not isinstance(op, op_type):
        raise ReconInputError(f"{method} on another backend needs a {op_type.__name__}, got "
                              f"{type(op).__name__}; pass NumPy arrays")
    xop = xp_type(op, b)
    return xop, xop.xp, check_measurement_xp(b, op.shape_out)


def accelerated_xp(op, b, *, iterations: int, tv: float, nonneg: bool, step_scale: float,
                   momentum, restart: bool, method: str, lipschitz: float | None, l1: float,
                   stop, x0) -> SolveResult:
    """FISTA / gradient descent of :mod:`recon.solvers.gradient` on ``b``'s backend
    (parameters validated by the caller).

    Parameters
    ----------
    op : ConvolutionOperator
        NumPy forward model (moved to ``b``'s device).
    b : array (array API), float32, ``op.shape_out``
    lipschitz : float, optional
        Known L; else power iteration on the device, from the NumPy path's start.
    x0 : array, optional
        Starting point (any backend's array of ``op.shape_in``).
    Other parameters as :func:`recon.solvers.gradient.fista`.

    Returns
    -------
    SolveResult
        ``x`` on ``b``'s device.

    Raises
    ------
    DivergenceError, ReconInputError
        As :func:`recon.solvers.gradient.fista`.
    """
    xop, xp, b = device_problem(op, b, ConvolutionOperator, XpConvolution, method)
    lip = lipschitz if lipschitz is not None else xop.lipschitz()
    if not lip > 0:
        raise ReconInputError("forward model is zero (Lipschitz constant 0): check the PSF")
    step = step_scale / lip
    thr = 2.0 * 2 * step * tv  # recon.solvers.gradient.prox_threshold(step, tv, 2)
    bp = xop.pad(b)
    mon = XpMonitor(xp, total(xp, b * b), method)
    if x0 is None:
        x = xp.zeros(xop.shape_in, dtype=xp.float32, device=xop.device)
    else:
        x = xp.asarray(x0 if not isinstance(x0, np.ndarray) else xop.asarray(x0), copy=True,
                       dtype=xp.float32)
        if tuple(x.shape) != tuple(op.shape_in):
            raise ReconInputError(f"x0 has shape {tuple(x.shape)}, the model's object is "
                                  f"{tuple(op.shape_in)}")
    y = xp.asarray(x, copy=True)

    def data_term(v):
        r = xop.wp * xop.convolve_full(v) - bp
        grad = xop.correlate_full(xop.wp * r)
        if l1 > 0:
            grad = grad + l1
        return 0.5 * total(xp, r * r), grad

    def prox_step(v, grad, x_buf, y_next, beta):
        x_new, y_new, tv_y, dot = proximal_step(xp, v, grad, x_buf, step, thr, beta, nonneg)
        x_buf[...] = x_new
        y_next[...] = y_new
        return tv * tv_y + (l1 * total(xp, v) if l1 > 0 else 0.0), dot

    used, restarts = accelerated_loop(x, iterations=iterations, data_term=data_term,
                                      prox_step=prox_step, monitor=mon, momentum=momentum,
                                      restart=restart, stop=stop, y=y,
                                      hint="check the PSF and measurement scaling")
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    final = 0.5 * data_sq + tv * tv_circular(xp, x, (0, 1)) + l1 * total(xp, x)
    mon.history.extra["restarts"] = restarts
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm,
                       {"step": step, "lipschitz": lip, "tv": tv, "tv_threshold": thr,
                        "nonneg": nonneg, "momentum": momentum, "restart": restart,
                        "l1": l1, "iterations": iterations, "iterations_used": used,
                        "backend": xp.__name__})

