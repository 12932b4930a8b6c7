"""The hologram optimiser's iteration (Algorithm 1, App. A.4), shared by both engines.

Projected gradient with Nesterov momentum, a backtracking step and momentum restarts,
as :mod:`recon.cgh.optimize`'s docstring derives it. The arithmetic on arrays goes
through the engine (``extrapolate``, ``descend``, ``inner``, ``fields``, ``value``,
``value_and_grad``), so the same loop runs the NumPy path's :class:`_Engine` (numba
kernels, buffers written in place) and the generic
:class:`recon.cgh.xp_optimize.XpEngine` (any array-API backend, new arrays).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..backend import to_numpy
from ..errors import DivergenceError
from ..solvers.common import History
from .hologram import HologramResult

__all__ = ["iterate"]


def iterate(eng, s, iterations: int, *, slm: str, mu: float, step_growth: float,
             max_backtracks: int, marks: set, callback, t_start: float) -> HologramResult:
    """Run Algorithm 1 from ``s`` with either engine.

    Parameters
    ----------
    eng : recon.cgh.optimize._Engine or recon.cgh.xp_optimize.XpEngine
        The loss, gradient and array operations (NumPy path or generic path).
    s : array
        complex64 ``slm_shape`` start, on the engine's device.
    iterations : int
        Most iterations.
    slm : {"phase", "complex"}
        The projection (:func:`recon.cgh.hologram.project`).
    mu : float
        First step (``step_scale / k^2``); halved by the backtracking.
    step_growth : float
        Factor on the step after each iteration.
    max_backtracks : int
        Halvings per iteration before the run stops as converged.
    marks : set of int
        Iterations whose field is copied to ``checkpoints``.
    callback : callable or None
        ``callback(iteration, field, loss)`` (field on the device); True stops.
    t_start : float
        ``time.perf_counter()`` at the call's start (for ``seconds``).

    Returns
    -------
    HologramResult
        Field and phase on the host (NumPy), history, stop reason; ``params`` holds
        only ``final_step`` (the caller fills the rest).

    Raises
    ------
    DivergenceError
        The loss became NaN/inf (history and the last good field attached).
    """
    zs, zp, zw = eng.new_fields(), eng.new_fields(), eng.new_fields()
    zs = eng.fields(s, zs)
    zp = eng.copy_fields(zs, zp)
    loss_s = eng.value(zs, eng.power(s))
    s_prev = eng.copy(s)
    grad = eng.new_grad(s)
    t = 1.0
    hist = History(extra={"step": [], "backtracks": [], "ffts": [], "restarts": [],
                          "fft_seconds": []})
    result = HologramResult(field=s, phase=None, loss=loss_s, history=hist, seconds=0.0)
    reason = "iterations"
    tol = 1e-6
    for it in range(1, iterations + 1):
        t0 = time.perf_counter()
        ffts0, fsec0 = eng.ffts, eng.fft_seconds
        t_next = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
        beta = (t - 1.0) / t_next
        w = eng.extrapolate(s, s_prev, beta)
        loss_w, grad = eng.value_and_grad(1.0 + beta, zs, -beta, zp, zw, w, eng.power(w), grad)
        if not math.isfinite(loss_w):
            raise DivergenceError(f"hologram loss became {loss_w} at iteration {it}; check the "
                                  "target for extreme values", history=hist.as_dict(),
                                  last_good=to_numpy(s))
        backtracks = 0
        while True:
            s_new = eng.descend(w, mu, grad, slm)
            zp = eng.fields(s_new, zp)  # z(s_{k-1}) is no longer needed
            loss_new = eng.value(zp, eng.power(s_new))
            d = s_new - w
            bound = loss_w + eng.inner(grad, d) + eng.inner(d, d) / (2.0 * mu)
            accepted = loss_new <= bound + tol * abs(loss_w)
            if accepted or backtracks == max_backtracks:
                break
            mu *= 0.5
            backtracks += 1
        if not accepted:
            reason = "converged (no decrease at float32 precision)"
            break
        if loss_new > loss_s:
            t_next = 1.0
            hist.extra["restarts"].append(it)
        s_prev, s = s, s_new
        zs, zp = zp, zs
        loss_s, t = loss_new, t_next
        hist.extra["step"].append(mu)
        hist.extra["backtracks"].append(backtracks)
        mu *= step_growth
        hist.extra["ffts"].append(eng.ffts - ffts0)
        hist.extra["fft_seconds"].append(eng.fft_seconds - fsec0)
        hist.objective.append(loss_s)
        hist.data_residual.append(math.sqrt(max(loss_s, 0.0) / eng.norm0))
        hist.seconds.append(time.perf_counter() - t0)
        if it in marks:
            result.checkpoints[it] = np.array(to_numpy(s), copy=True)
            result.checkpoint_seconds[it] = time.perf_counter() - t_start
        if callback is not None and callback(it, s, loss_s):
            reason = "stopped by callback"
            break
    n_it = len(hist.objective)
    result.field = np.asarray(to_numpy(s))
    result.phase = np.angle(result.field).astype(np.float32)
    result.loss = loss_s
    result.iterations = n_it
    result.ffts_per_iteration = float(np.mean(hist.extra["ffts"])) if n_it else 0.0
    result.stop_reason = reason
    result.seconds = time.perf_counter() - t_start
    result.params = {"final_step": mu}
    return result
