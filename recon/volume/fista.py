"""3D FISTA for volume reconstruction from one image (Kuo 2020, Algorithm 1, App. A.1).

Minimises ``1/2 ||A v - b||^2 + tv TV3(v) + l1 ||v||_1`` subject to ``v >= 0``
(Eq. A.3 with Psi the 3D finite differences and/or the identity, "native
sparsity"), with ``A`` the 3D model of Eq. 4.4
(:class:`~recon.volume.operator.VolumeConvolutionOperator`). TV uses the
Haar-shift approximation of App. A.1 along z, y and x; the l1 term its exact
prox (soft threshold) after it; non-negativity last (for l1 + non-negativity the
composition is the exact prox).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ReconInputError
from ..operators import LinearOperator
from ..solvers.accelerated import accelerated_loop
from ..solvers.common import DEFAULT_ITERATIONS, Monitor, SolveResult, check_measurement
from ..solvers.gradient import prox_threshold
from ..validate import as_int, nonneg_weight, positive
from . import _kernels3d
from .operator import VolumeConvolutionOperator


def volume_tv(v: np.ndarray) -> float:
    """Anisotropic 3D TV of a volume (n_z, P0, P1): sum of |forward differences|.

    Laterally circular (the padded grid of Eq. 3.4), not circular in depth (the
    first and last planes are not neighbours), as in :func:`fista3d`'s prox.
    float64 accumulation.
    """
    v = np.asarray(v, np.float32)
    tv = 0.0
    for k in range(v.shape[0]):  # plane by plane: temporaries of one plane, not a volume
        p = v[k]
        if k + 1 < v.shape[0]:
            tv += np.abs(v[k + 1] - p).sum(dtype=np.float64)
        for axis in (0, 1):
            tv += np.abs(np.roll(p, -1, axis=axis) - p).sum(dtype=np.float64)
    return float(tv)


def final_objective(op: LinearOperator, x: np.ndarray, b: np.ndarray, tv_w: float,
                    l1_w: float) -> tuple[float, float]:
    """Objective of Eq. 4.5 at a final estimate, and its squared data residual.

    ``0.5 ||A x - b||^2 + tv_w TV(x) + l1_w ||x||_1`` with :func:`volume_tv`; one
    forward model application.

    Parameters
    ----------
    op : LinearOperator
        The volume forward model.
    x : ndarray, float32, (n_z, P0, P1)
        The estimate.
    b : ndarray, float32, sensor shape
        The measurement.
    tv_w, l1_w : float
        Weights (0 leaves the term out).

    Returns
    -------
    objective, data_sq : float
    """
    r = op.forward(x) - b
    data_sq = float(np.vdot(r, r))
    final = 0.5 * data_sq
    if tv_w:
        final += tv_w * volume_tv(x)
    if l1_w:
        final += l1_w * float(np.abs(x).sum(dtype=np.float64))
    return final, data_sq


def fista3d(op: LinearOperator, b: np.ndarray, *, iterations: int = DEFAULT_ITERATIONS,
            tv: float = 0.0, l1: float = 0.0, nonneg: bool = True,
            step: float | None = None, step_scale: float = 1.0, restart: bool = True,
            lipschitz: float | None = None, stop=None) -> SolveResult:
    """FISTA on a volume with 3D TV (Haar shifts), l1 and non-negativity.

    Each iteration: ``grad = A^T (A y_k - b)`` (the fused data term: ``2 n_z + 2``
    real 2D FFTs at the padded shape, see
    :class:`~recon.volume.operator.VolumeConvolutionOperator`); then one fused
    numba pass (``recon.volume._kernels3d.proximal_step_3d``):
    ``x_{k+1} = max(S_{step l1}(TV-prox(y_k - step grad)), 0)`` with the Haar-shift
    TV prox of App. A.1 along z, y and x (threshold ``2 * 3 * step * tv`` on the
    half-differences, averaged over the 3 axes, as in 2D), ``t_{k+1} = (1 + sqrt(1 +
    4 t_k^2)) / 2`` and ``y_{k+1} = x_{k+1} + (t_k - 1) / t_{k+1} (x_{k+1} - x_k)``.
    With ``restart`` the momentum is reset when it points uphill (gradient restart,
    O'Donoghue & Candes 2015), as :func:`recon.solvers.fista` does in 2D.

    Parameters
    ----------
    op : VolumeConvolutionOperator or LinearOperator
        3D forward model with ``shape_in = (n_z, P0, P1)``.
    b : ndarray, shape ``op.shape_out``, float32
        Measurement, scaled so its values are O(1) (e.g. divided by its maximum,
        with the stack normalised by :func:`~recon.volume.normalize_psf_stack`). An
        array of another array-API backend (CuPy, PyTorch) runs the generic path
        ``recon.volume.xp_fista3d.fista3d_xp`` on its device and returns ``x``
        there (``op`` a :class:`~recon.volume.operator.VolumeConvolutionOperator`).
    iterations : int
        Maximum iterations (default :data:`~recon.solvers.common.DEFAULT_ITERATIONS`, the
        declared one).
    tv : float
        3D TV weight (default 0, as every solver's; 0 or None disables TV).
    l1 : float
        l1 weight (native sparsity; default 0; 0 or None disables it).
    nonneg : bool
        Project onto v >= 0.
    step : float, optional
        Gradient step; default ``step_scale / L``.
    step_scale : float
        Used when ``step`` is None; above 2 diverges (caught, see Raises).
    restart : bool
    lipschitz : float, optional
        Known L (skips the power iteration, :meth:`LinearOperator.lipschitz`).
    stop : callable, optional
        ``stop(history) -> bool`` after every iteration (automatic stopping), as for
        the 2D FISTA; ``iterations`` stays the maximum.

    Returns
    -------
    SolveResult
        ``x`` is the volume (n_z, P0, P1) float32 on the padded grid;
        ``history.objective[k]`` is evaluated at the extrapolated point y_k (free);
        ``final_objective`` is exact at the returned x; ``history.extra["restarts"]``;
        ``params`` with ``iterations`` (the maximum) and ``iterations_used``.

    Raises
    ------
    DivergenceError
        Objective NaN/inf or 100x that of the zero volume (e.g. a too-large step);
        carries the history and the last good estimate.
    ReconInputError
        Invalid parameters, a non-3D operator or a bad measurement.
    """
    iterations = as_int(iterations, "iterations", 1)
    if len(op.shape_in) != 3:
        raise ReconInputError(
            f"fista3d needs a volume operator (n_z, P0, P1), got input shape {op.shape_in}; "
            "use recon.solvers.fista for 2D"
        )
    tv_w = nonneg_weight(tv, "TV")
    l1_w = nonneg_weight(l1, "l1")
    if step is None:
        step_scale = positive(step_scale, "step_scale")
        if lipschitz is not None:
            lipschitz = positive(lipschitz, "lipschitz")
    else:
        step = positive(step, "step")
    too_large = step is not None or step_scale > 1
    hint = ("the step is too large: use step=None (1/L) or a step scale <= 1"
            if too_large else "check the PSF stack and measurement scaling"
            + (f", or use smaller TV / l1 weights than {tv_w:g} / {l1_w:g}"
               if tv_w > 0 or l1_w > 0 else ""))
    if not isinstance(b, np.ndarray):  # another backend: the array-API path
        from .xp_fista3d import fista3d_xp

        return fista3d_xp(op, b, iterations=iterations, tv=tv_w, l1=l1_w, nonneg=nonneg,
                          step=step, step_scale=step_scale, restart=restart,
                          lipschitz=lipschitz, stop=stop, hint=hint)
    b = check_measurement(b, op.shape_out)
    lip = None
    if step is None:
        if lipschitz is not None:
            lip = lipschitz
        elif not ((lip := op.lipschitz()) > 0 and math.isfinite(lip)):
            raise ReconInputError("forward model is zero (Lipschitz constant 0): check the PSFs")
        step = step_scale / lip
    thr = prox_threshold(step, tv_w, 3)
    l1thr = step * l1_w
    mon = Monitor(float(np.vdot(b, b)), "3D FISTA")
    fused = isinstance(op, VolumeConvolutionOperator)
    x = np.zeros(op.shape_in, np.float32)
    grad = np.empty_like(x)

    def data_term(y):
        if fused:
            loss, _ = op.data_term(y, b, out=grad)
        else:
            loss, g = op.data_term(y, b)
            np.copyto(grad, g)
        return loss, grad

    def prox_step(y, grad, x, y_next, beta):
        tv_y, l1_y, dot = _kernels3d.proximal_step_3d(y, grad, x, y_next, step, thr, l1thr,
                                                     beta, nonneg)
        return tv_w * tv_y + l1_w * l1_y, dot

    used, restarts = accelerated_loop(x, iterations=iterations, data_term=data_term,
                                      prox_step=prox_step, monitor=mon, restart=restart,
                                      stop=stop, hint=hint)
    final, data_sq = final_objective(op, x, b, tv_w, l1_w)
    mon.history.extra["restarts"] = restarts
    return SolveResult(x, mon.history, final, math.sqrt(data_sq) / mon.b_norm,
                       {"step": step, "lipschitz": lip, "tv": tv_w, "l1": l1_w,
                        "tv_threshold": thr, "l1_threshold": l1thr, "nonneg": nonneg,
                        "restart": restart, "iterations": iterations,
                        "iterations_used": used})
