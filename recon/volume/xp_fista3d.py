"""3D FISTA with 3D TV, l1 and non-negativity on any array-API backend.

:func:`recon.volume.fista3d` (Kuo 2020, Algorithm 1 / App. A.1 on the model of
Eq. 4.4) for a measurement on another backend: the project's one accelerated loop
(:func:`recon.solvers.accelerated.accelerated_loop`), the volume operator on the
device (:class:`recon.xp_operators.XpVolumeConvolution`, all planes in one batched
FFT) and the generic proximal step of the 2D FISTA
(:func:`recon.solvers.xp_fista.proximal_step`) along z, y and x with depth pairs that
do not wrap, then the l1 soft threshold and max(., 0), as the fused numba pass
:func:`recon.volume._kernels3d.proximal_step_3d` does.
"""

from __future__ import annotations

import math

from ..errors import ReconInputError
from ..solvers.accelerated import accelerated_loop
from ..solvers.common import SolveResult
from ..solvers.gradient import prox_threshold
from ..solvers.xp_common import XpMonitor, total
from ..solvers.xp_fista import device_problem, proximal_step, tv_open
from ..xp_operators import XpVolumeConvolution
from .operator import VolumeConvolutionOperator

__all__ = ["fista3d_xp", "memory_bytes"]


def memory_bytes(n_z: int, padded_shape: tuple[int, int]) -> int:
    """Peak device memory of :func:`fista3d_xp` in bytes (an estimate with margin).

    Volumes of ``(n_z, P0, P1)`` float32: x, y, y_next, the gradient and about six
    temporaries of the proximal step; complex half-spectra: the PSF spectra and the
    batched spectra of the data term (twice the bytes of half a volume each).
    """
    vol = 4 * n_z * padded_shape[0] * padded_shape[1]
    spectra = 4 * vol * (padded_shape[1] // 2 + 1) / padded_shape[1] * 2
    return int(10 * vol + spectra)


def fista3d_xp(op, b, *, iterations: int, tv: float, l1: float, nonneg: bool,
               step: float | None, step_scale: float, restart: bool,
               lipschitz: float | None, stop=None, hint: str = "") -> SolveResult:
    """:func:`recon.volume.fista3d` on ``b``'s backend (parameters validated there).

    Parameters
    ----------
    op : VolumeConvolutionOperator
        The NumPy model (spectra and weights moved to ``b``'s device).
    b : array (array API), float32, ``op.shape_out``
        Scaled measurement on the target device.
    iterations : int
    tv, l1 : float
        3D TV and l1 weights (>= 0).
    nonneg : bool
    step : float, optional
        Gradient step; None: ``step_scale / L``.
    step_scale : float
    restart : bool
    lipschitz : float, optional
        Known L; else power iteration on the device, from the NumPy path's start.
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration.
    hint : str
        Appended to a divergence error's message.

    Returns
    -------
    SolveResult
        ``x`` (n_z, P0, P1) float32 on ``b``'s device; history, objective and
        parameters as the NumPy path's.

    Raises
    ------
    DivergenceError, ReconInputError
        As :func:`recon.volume.fista3d`; an operator that is not a
        :class:`~recon.volume.operator.VolumeConvolutionOperator`.
    """
    xop, xp, b = device_problem(op, b, VolumeConvolutionOperator, XpVolumeConvolution,
                                "3D FISTA")
    lip = None
    if step is None:
        lip = lipschitz if lipschitz is not None else xop.lipschitz()
        if not (lip > 0 and math.isfinite(lip)):
            raise ReconInputError("forward model is zero (Lipschitz constant 0): check the PSFs")
        step = step_scale / lip
    thr = prox_threshold(step, tv, 3)
    l1thr = step * l1
    mon = XpMonitor(xp, total(xp, b * b), "3D FISTA")
    x = xp.zeros(op.shape_in, dtype=xp.float32, device=xop.device)

    def prox_step(y, grad, x_buf, y_next, beta):
        x_new, y_new, tv_y, dot = proximal_step(xp, y, grad, x_buf, step, thr, beta, nonneg,
                                                l1thr=l1thr, open_axis=0)
        l1_y = total(xp, xp.abs(y)) if l1 > 0 else 0.0
        x_buf[...] = x_new
        y_next[...] = y_new
        return tv * tv_y + l1 * l1_y, dot

    used, restarts = accelerated_loop(x, iterations=iterations,
                                      data_term=lambda y: xop.data_term(y, b),
                                      prox_step=prox_step, monitor=mon, restart=restart,
                                      stop=stop, y=xp.asarray(x, copy=True), hint=hint)
    r = xop.forward(x) - b
    data_sq = total(xp, r * r)
    final = 0.5 * data_sq
    if tv:
        final += tv * tv_open(xp, x, open_axis=0)
    if l1:
        final += l1 * total(xp, xp.abs(x))
    mon.history.extra["restarts"] = restarts
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm,
                       {"step": step, "lipschitz": lip, "tv": tv, "l1": l1,
                        "tv_threshold": thr, "l1_threshold": l1thr, "nonneg": nonneg,
                        "restart": restart, "iterations": iterations,
                        "iterations_used": used, "backend": xp.__name__})
