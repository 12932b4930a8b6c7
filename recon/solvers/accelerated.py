"""The accelerated proximal-gradient loop shared by every FISTA of the project.

One loop (:func:`accelerated_loop`) for the 2D FISTA and gradient descent
(:mod:`recon.solvers.gradient`), the 3D FISTA (:mod:`recon.volume.fista`) and the
joint object/background FISTA (:mod:`recon.spatial.background`). It owns what they
share -- the momentum sequence of FISTA (Kuo 2020, Algorithm 1; Beck & Teboulle
2009) or a constant momentum, the gradient restart (O'Donoghue & Candes 2015), the
per-iteration history and divergence check (:class:`~recon.solvers.common.Monitor`)
and automatic stopping -- and calls the solver's own data term and proximal step,
which are fused numba passes or plain numpy depending on the solver.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .common import History, Monitor

__all__ = ["accelerated_loop", "fista_momentum"]


def fista_momentum(t: float) -> tuple[float, float]:
    """FISTA's next ``t`` and momentum: ``t' = (1 + sqrt(1 + 4 t^2)) / 2``,
    ``beta = (t - 1) / t'`` (Kuo 2020, Algorithm 1; Beck & Teboulle 2009)."""
    t_next = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
    return t_next, (t - 1.0) / t_next


def accelerated_loop(x: np.ndarray, *, iterations: int,
                     data_term: Callable[[np.ndarray], tuple[float, np.ndarray]],
                     prox_step: Callable[..., tuple[float, float]], monitor: Monitor,
                     momentum: float | None = None, restart: bool = True,
                     stop: Callable[[History], bool] | None = None, hint: str = "",
                     y: np.ndarray | None = None, snapshot: np.ndarray | None = None,
                     observe: Callable[[int, np.ndarray], None] | None = None
                     ) -> tuple[int, list[int]]:
    """Run accelerated proximal-gradient iterations on ``x`` (updated in place).

    Iteration k, from the extrapolated point y_k::

        loss, grad = data_term(y_k)           # 1/2 ||A y_k - b||^2 and the gradient
        x_{k+1} = prox(y_k - step grad)        # by prox_step, in place in x
        y_{k+1} = x_{k+1} + beta_k (x_{k+1} - x_k)

    with beta_k = (t_k - 1) / t_{k+1}, t_{k+1} = (1 + sqrt(1 + 4 t_k^2)) / 2 (FISTA,
    t_0 = 1) or beta_k = ``momentum``. With ``restart``, when
    ``<y_k - x_{k+1}, x_{k+1} - x_k> > 0`` (the momentum points uphill) the
    extrapolation is dropped (y_{k+1} = x_{k+1}) and t restarts at 1.

    Parameters
    ----------
    x : ndarray, float32
        The starting iterate x_0; holds x_{k+1} after each iteration (the estimate on
        return).
    iterations : int
        Maximum number of iterations (>= 1, validated by the caller).
    data_term : callable
        ``data_term(y) -> (loss, grad)``: the data term 1/2 ||A y - b||^2 (its value
        gives the history's relative residual) and the gradient of the whole smooth
        part at ``y`` (the returned array may be reused between calls).
    prox_step : callable
        ``prox_step(y, grad, x, y_next, beta) -> (penalty, dot)``: writes
        x_{k+1} = prox(y - step grad) into ``x`` and y_{k+1} = x_{k+1} + beta
        (x_{k+1} - x_k) into ``y_next``; returns the objective's terms besides the
        data term at ``y`` (weighted TV, l1) and ``<y - x_{k+1}, x_{k+1} - x_k>``.
        Step and thresholds are the caller's (closed over).
    monitor : Monitor
        Records objective ``loss + penalty``, residual and time per iteration, and
        raises :class:`~recon.errors.DivergenceError` with the last good ``x``.
    momentum : float, optional
        Constant momentum in [0, 1) (gradient descent with Nesterov momentum); None
        (default) uses the FISTA sequence.
    restart : bool
        Gradient restart (see above).
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping).
    hint : str
        Appended to a divergence error's message.
    y : ndarray, optional
        Buffer for the extrapolated point (default a copy of ``x``; y_0 = x_0).
    snapshot : ndarray, optional
        What the monitor keeps as the last good estimate (default ``x``); a view of
        ``x`` when ``x`` joins several unknowns (the object part of object and
        background).
    observe : callable, optional
        ``observe(k, estimate)`` after iteration ``k`` (1-based), with the estimate
        x_k (``snapshot``; the live array: copy what you keep). A run observed at
        ``k`` holds what a run of ``k`` iterations returns (checkpoints of one solve,
        e.g. an early-stop fit, :mod:`recon.analysis.early_stop`).

    Returns
    -------
    used : int
        Iterations run (< ``iterations`` when ``stop`` ended the loop).
    restarts : list of int
        Iterations at which the momentum was restarted.

    Raises
    ------
    DivergenceError
        From ``monitor``: NaN/inf or an objective above its growth limit.
    """
    y = x.copy() if y is None else y
    snapshot = x if snapshot is None else snapshot
    if isinstance(y, np.ndarray):
        y_next = np.empty_like(y)
    else:  # another array-API backend (recon.solvers.xp_fista): same loop, that library's arrays
        from ..backend import array_namespace

        y_next = array_namespace(y).empty_like(y)
    t = 1.0
    restarts: list[int] = []
    for k in range(iterations):
        monitor.start()
        loss, grad = data_term(y)
        if momentum is None:  # FISTA sequence (Algorithm 1)
            t_next, beta = fista_momentum(t)
        else:
            beta = momentum
        penalty, dot = prox_step(y, grad, x, y_next, beta)
        if restart and dot > 0.0:
            y_next[...] = x
            t_next = 1.0
            restarts.append(k)
        if momentum is None:
            t = t_next
        y, y_next = y_next, y
        monitor.record(loss + penalty, 2.0 * loss, x=snapshot, hint=hint)
        if observe is not None:
            observe(k + 1, snapshot)
        if stop is not None and stop(monitor.history):
            return k + 1, restarts
    return iterations, restarts
