"""Streamed 3D FISTA: the volume problem of Eq. 4.4-4.5 in bounded memory (Kuo 2020, Ch. 4).

The in-memory 3D solvers (:func:`recon.volume.fista3d`, :func:`recon.volume.admm3d`)
hold whole padded volumes: at the seed's 2048 x 2048 x 128 that is 8.6 GB per
volume and 50 GB or more in all. The forward model is a sum over planes of 2D
convolutions, so :func:`slab_fista` keeps the planes in slabs
(:class:`recon.volume.slab.VolumeSlab`): each plane is padded and transformed on the
fly, the PSF spectra are held once as complex64 half-spectra, the iterates ``x``,
``y`` and ``v = y - step grad`` are kept on the sensor's field of view (3 volumes
instead of FISTA's 5 on the padded grid: ``y`` is updated in place), and per
iteration only sensor-sized images cross between the slabs and the loop: each
slab's partial image up, the weighted residual down, and three boundary planes for
the 3D TV. The slabs may live in this process (:class:`LocalSlabs`) or in dask
workers (:mod:`instrument.processing.volume_shards`); the arithmetic is the same.

Peak memory of one process holding every slab is :func:`streamed_memory_bytes`
(printed before a solve by ``recon3d``, checked against the measured peak resident
set by ``diffuserlab benchmark volume-scale``).
"""

from __future__ import annotations

import math
import resource
import sys
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReconInputError
from ..fft import fft_pair_seconds
from ..operators import checked_sensor_weights, padded_grid
from ..solvers.accelerated import fista_momentum
from ..solvers.common import DEFAULT_ITERATIONS, Monitor, SolveResult, check_measurement
from ..solvers.gradient import prox_threshold
from ..validate import as_int, nonneg_weight, positive
from .operator import CHUNK_BYTES
from .slab import SUPPORTS, VolumeSlab

__all__ = ["PATH_SENSOR_IMAGES", "LocalSlabs", "StreamedModel", "final_objective",
           "gather_estimate", "peak_rss_bytes", "plan_slabs", "slab_fista",
           "streamed_fft_floor_seconds", "streamed_fista3d", "streamed_memory_bytes"]

#: Sensor-sized float32 images the automatic weight's path holds in the loop's process
#: beside the solve's own (:mod:`recon.volume.streamed_auto`): the fit pixels' weights
#: and measurement, the kept and held-out masks (one byte a pixel each, 1/2 together),
#: the prediction of ``x`` and, while a candidate is scored, the weighted prediction,
#: its difference from the measurement and that difference squared in float64 (2).
PATH_SENSOR_IMAGES = 7.5


def plan_slabs(n_z: int, n_slabs: int) -> list[tuple[int, int]]:
    """Split ``n_z`` planes into ``n_slabs`` contiguous slabs of near-equal size.

    Returns
    -------
    list of (start, stop)

    Raises
    ------
    ReconInputError
        ``n_slabs`` not in [1, n_z].
    """
    n_slabs = as_int(n_slabs, "slabs", 1)
    if n_slabs > n_z:
        raise ReconInputError(f"{n_slabs} slabs for {n_z} planes: give at most one slab per "
                              "plane")
    edges = np.linspace(0, n_z, n_slabs + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def streamed_memory_bytes(sensor_shape: tuple[int, int], n_z: int, *,
                          support: str = "sensor", chunk_bytes: int = CHUNK_BYTES,
                          path_copies: int = 0) -> dict[str, int]:
    """Bytes of arrays one process holds at the peak of :func:`slab_fista` on ``n_z``
    planes (all of one process's slabs together; a dask worker's slab: its planes),
    or of the automatic weight's path over them (``path_copies``).

    Parameters
    ----------
    sensor_shape : (rows, cols)
    n_z : int
        Planes held (the whole stack, or one worker's slab).
    support : {"sensor", "padded"}
        Lateral grid of the iterates.
    chunk_bytes : int
    path_copies : int
        Copies of the iterates the automatic weight's path keeps at its peak
        (:func:`recon.volume.streamed_auto.path_copies`: 4 with the volume's rule);
        0 for a fixed weight.

    Returns
    -------
    dict
        ``psf_spectra`` (n_z complex64 half-spectra of the padded grid), ``iterates``
        (x, y, v), ``chunk_buffers`` (per chunk of planes: the padded input, its
        rfft2, the conjugate products and their irfft2), ``plane_buffers`` (the summed
        and the residual spectrum, the padded residual and the summed image's
        irfft2), ``sensor_images`` (measurement, weights, partial and summed images,
        residuals and the three boundary planes of each kind, 12 in all); with
        ``path_copies``, ``path_copies`` (those copies, float32 volumes on the
        iterates' grid) and ``path_sensor_images`` (:data:`PATH_SENSOR_IMAGES`; in
        the loop's process); and ``total``. For 2048 x 2048 and 128 planes (padded
        4096 x 4096): spectra 8.6e9, iterates 6.4e9, total ~15.5e9 bytes; the
        automatic weight's path adds 4 copies, 8.6e9 (total ~24.2e9).
    """
    p0, p1 = padded_grid(tuple(sensor_shape))[0]
    if support not in SUPPORTS:
        raise ReconInputError(f"support {support!r}: use one of {', '.join(SUPPORTS)}")
    lat = sensor_shape if support == "sensor" else (p0, p1)
    spec_plane = 8 * p0 * (p1 // 2 + 1)
    real_plane = 4 * p0 * p1
    per = max(1, min(n_z, chunk_bytes // spec_plane))
    est = {
        "psf_spectra": n_z * spec_plane,
        "iterates": 3 * 4 * n_z * lat[0] * lat[1],
        "chunk_buffers": per * (2 * spec_plane + 2 * real_plane),
        "plane_buffers": 2 * spec_plane + 2 * real_plane,
        "sensor_images": 12 * 4 * sensor_shape[0] * sensor_shape[1],
    }
    if path_copies:
        est["path_copies"] = int(path_copies) * 4 * n_z * lat[0] * lat[1]
        est["path_sensor_images"] = int(PATH_SENSOR_IMAGES * 4 * sensor_shape[0]
                                        * sensor_shape[1])
    est["total"] = sum(est.values())
    return est


def peak_rss_bytes() -> int:
    """This process's peak resident set size so far, bytes (``getrusage``)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def streamed_fft_floor_seconds(padded_shape: tuple[int, int], n_z: int,
                               repeats: int = 5) -> float:
    """The FFT floor of one streamed iteration: ``n_z + 1`` rfft2 + irfft2 pairs, one
    plane at a time, at the padded shape.

    The median of ``repeats`` timed pairs of one plane (:func:`recon.fft.fft_pair_seconds`)
    times ``n_z + 1``: the planes' rfft2 and irfft2 and one pair for the summed
    image and the residual. Unlike :func:`recon.volume.fft_floor_seconds` it never
    holds more than one plane (at 4096 x 4096 x 128 the batched floor would need 17 GB).

    Returns
    -------
    float
        Seconds.
    """
    if n_z < 1:
        raise ReconInputError("streamed_fft_floor_seconds needs n_z >= 1")
    return (n_z + 1) * fft_pair_seconds(tuple(padded_shape), repeats=repeats)


@dataclass
class StreamedModel:
    """What a streamed solve's record needs of its model (the spectra live in the slabs).

    Stands in for :class:`~recon.volume.VolumeConvolutionOperator` as
    ``recon.result.Reconstruction.operator`` of a streamed reconstruction.

    Attributes
    ----------
    n_z : int
    sensor_shape, padded_shape : (int, int)
    crop : (slice, slice)
        The sensor in the padded grid (the iterates of ``support="sensor"`` are the
        crop itself: ``crop`` of ``lateral_shape`` is then the whole plane).
    support : str
    slabs : list of (start, stop)
    depths : list of float, optional
    memory : dict
        :func:`streamed_memory_bytes` of the plan.
    """

    n_z: int
    sensor_shape: tuple[int, int]
    padded_shape: tuple[int, int]
    crop: tuple[slice, slice]
    support: str
    slabs: list
    depths: list | None = None
    memory: dict = field(default_factory=dict)
    streamed: bool = True

    @property
    def estimate_crop(self) -> tuple[slice, slice]:
        """The sensor window in the iterates' planes."""
        return (slice(None), slice(None)) if self.support == "sensor" else self.crop


class LocalSlabs:
    """Slabs in this process: :func:`slab_fista`'s group with nothing to move.

    Parameters
    ----------
    slabs : list of VolumeSlab
        Contiguous, in depth order.

    Attributes
    ----------
    bytes_moved : list of int
        Per slab, bytes sent to or received from it (always 0 here; the dask group,
        :class:`instrument.processing.volume_shards.ShardedSlabs`, counts its messages).
    """

    def __init__(self, slabs: list[VolumeSlab]):
        self.slabs = list(slabs)
        self.bytes_moved = [0] * len(self.slabs)

    def __len__(self) -> int:
        return len(self.slabs)

    def call(self, method: str, args: list[tuple] | None = None) -> list:
        """``[getattr(slab, method)(*a) for slab, a]``: one result per slab."""
        args = args if args is not None else [()] * len(self.slabs)
        return [getattr(s, method)(*a) for s, a in zip(self.slabs, args, strict=True)]

    def gather(self, out: np.ndarray | None, which: str = "x") -> np.ndarray:
        """The estimate: each slab's ``x`` (or saved copy ``which``) copied into ``out``
        (n_z, L0, L1); the single slab's array itself when ``out`` is None."""
        if out is None:
            return self.slabs[0].estimate(which)
        start = 0
        for s in self.slabs:
            out[start:start + s.n_planes] = s.estimate(which)
            start += s.n_planes
        return out


def slab_fista(group, b: np.ndarray, *, sensor_weights=None, iterations: int = DEFAULT_ITERATIONS,
               tv: float = 0.0, l1: float = 0.0, nonneg: bool = True,
               step: float | None = None, step_scale: float = 1.0,
               lipschitz: float | None = None, restart: bool = True, stop=None,
               on_iteration=None, gather: bool = True, t: float = 1.0,
               final: bool = True) -> SolveResult:
    """3D FISTA over plane slabs: :func:`recon.volume.fista3d`'s iteration, streamed.

    Each iteration: every slab returns its partial image of ``A y``; the loop sums
    them, forms the loss and the weighted residual ``r = w (w A y - b)``; every slab
    computes ``v = y - step A^T r`` for its planes and returns its boundary planes;
    every slab applies the Haar-shift 3D TV prox (App. A.1), the l1 soft threshold
    and non-negativity with its neighbours' boundary planes, and the momentum step
    (FISTA's sequence, gradient restart as in :func:`recon.volume.fista3d`). With
    the same step the iterates equal :func:`~recon.volume.fista3d`'s on the same
    model (``support="padded"``) up to float32 rounding.

    Parameters
    ----------
    group : LocalSlabs or instrument.processing.volume_shards.ShardedSlabs
        The slabs, contiguous in depth order, ``call(method, args)`` per slab.
    b : ndarray, float32, sensor shape
        The scaled measurement (pre-weighted, as for :func:`~recon.volume.fista3d`).
    sensor_weights : ndarray, sensor shape, optional
        The slabs' sensor weights (the same on every slab).
    iterations : int
        Maximum iterations (default :data:`~recon.solvers.common.DEFAULT_ITERATIONS`).
    tv, l1 : float
        3D TV and l1 weights (>= 0).
    nonneg : bool
    step : float, optional
        Default ``step_scale / L`` with ``L`` given or the bound
        ``max(w)^2 max_f sum_z |H_z(f)|^2`` (no FFTs; exact for the uncropped model,
        safe for the cropped one).
    step_scale : float
    lipschitz : float, optional
    restart : bool
    stop : callable, optional
        ``stop(history) -> bool`` after each iteration.
    on_iteration : callable, optional
        ``on_iteration(k)`` after iteration ``k`` (progress; a test's fault injection).
    gather : bool
        Bring the estimate into this process (``SolveResult.x``); False leaves it in
        the slabs (``x`` is None).
    t : float
        FISTA's momentum sequence at the start (1: a fresh start; the ``t`` a former
        run returned, with the slabs' ``x`` and ``y`` as it left them: its
        continuation, iterate for iterate -- the automatic weight's path runs a
        solve in windows, :mod:`recon.volume.streamed_auto`).
    final : bool
        Evaluate the objective and residual at the returned ``x`` (one forward
        model); False reports the last iteration's from the history instead.

    Returns
    -------
    SolveResult
        ``x`` (n_z, L0, L1) float32 on the slabs' lateral grid; the history as
        :func:`~recon.volume.fista3d`'s (objective at ``y_k``), ``final_objective``
        exact at ``x``; ``params`` with the step, weights, ``slabs``,
        ``bytes_moved_per_iteration`` (per slab, mean over iterations),
        ``iterations_used`` and ``t`` (the momentum sequence where it stopped). No
        snapshot of the estimate is kept for a divergence error (it would cost a
        volume): ``DivergenceError.last_good`` is None.

    Raises
    ------
    DivergenceError
        Objective NaN/inf or 100x that of the zero volume.
    ReconInputError
        Bad parameters or measurement.
    """
    iterations = as_int(iterations, "iterations", 1)
    tv_w, l1_w = nonneg_weight(tv, "TV"), nonneg_weight(l1, "l1")
    n = len(group)
    b = check_measurement(b, b.shape if isinstance(b, np.ndarray) else np.shape(b))
    w = checked_sensor_weights(sensor_weights, b.shape)
    lip = lipschitz
    if step is None:
        step_scale = positive(step_scale, "step_scale")
        if lip is None:
            power = None
            for p in group.call("power_spectrum"):
                power = p if power is None else power + p
            lip = float(power.max()) * float(w.max()) ** 2
            del power
        lip = positive(lip, "lipschitz")
        step = step_scale / lip
    else:
        step = positive(step, "step")
    thr = prox_threshold(step, tv_w, 3)
    l1thr = step * l1_w
    mon = Monitor(float(np.vdot(b, b)), "streamed 3D FISTA")
    hint = ("the step is too large: use step=None (1/L) or a step scale <= 1"
            if step_scale > 1 else "check the PSF stack and measurement scaling")
    moved0 = list(group.bytes_moved)
    t, used, restarts = positive(t, "t"), iterations, []
    for k in range(iterations):
        mon.start()
        loss, r = _residual(group.call("forward", [("y",)] * n), b, w)
        bounds = group.call("gradient_step", [(r, step, i > 0, i + 1 < n) for i in range(n)])
        t_next, beta = fista_momentum(t)
        args = [(bounds[i - 1][1] if i > 0 else None,
                 bounds[i + 1][0] if i + 1 < n else None,
                 bounds[i + 1][2] if i + 1 < n else None,
                 thr, l1thr, beta, nonneg) for i in range(n)]
        del bounds
        parts = group.call("prox", args)
        del args
        tv_y, l1_y, dot = (sum(p[j] for p in parts) for j in range(3))
        if restart and dot > 0.0:
            group.call("restart")
            t_next = 1.0
            restarts.append(k)
        t = t_next
        mon.record(loss + tv_w * tv_y + l1_w * l1_y, 2.0 * loss, hint=hint)
        if on_iteration is not None:
            on_iteration(k)
        if stop is not None and stop(mon.history):
            used = k + 1
            break
    moved = [(m - m0) / used for m, m0 in zip(group.bytes_moved, moved0, strict=True)]
    if final:
        final, data_sq = final_objective(group, b, w, tv_w, l1_w)
        relative = math.sqrt(data_sq) / mon.b_norm
    else:
        final, relative = mon.history.objective[-1], mon.history.data_residual[-1]
    mon.history.extra["restarts"] = restarts
    x = gather_estimate(group) if gather else None
    return SolveResult(x, mon.history, final, relative,
                       {"step": step, "lipschitz": lip, "tv": tv_w, "l1": l1_w,
                        "tv_threshold": thr, "l1_threshold": l1thr, "nonneg": nonneg,
                        "restart": restart, "iterations": iterations,
                        "iterations_used": used, "slabs": n,
                        "bytes_moved_per_iteration": moved, "t": t})


def gather_estimate(group, which: str = "x") -> np.ndarray:
    """The slabs' estimate ``which`` (``"x"`` or a saved copy's name) in this process.

    Returns
    -------
    ndarray, float32, (n_z, L0, L1)
        A new volume; with a single slab here (:class:`LocalSlabs`), the slab's own
        array (no copy).
    """
    shapes = group.call("estimate_shape")
    return group.gather(None if len(group) == 1 else np.empty(
        (sum(s[0] for s in shapes), *shapes[0][1:]), np.float32), which)


def _residual(partials: list, b: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    """Loss 1/2 ||w A y - b||^2 and ``w (w A y - b)`` from the slabs' partial images."""
    ay = partials[0]
    for p in partials[1:]:
        ay = ay + p
    d = w * ay - b
    return 0.5 * float(np.vdot(d.ravel(), d.ravel()).real), (w * d).astype(np.float32)


def final_objective(group, b: np.ndarray, w: np.ndarray, tv_w: float, l1_w: float,
                    which: str = "x") -> tuple[float, float]:
    """Objective of Eq. 4.5 at an estimate held in the slabs, and its squared data
    residual (:func:`recon.volume.fista.final_objective` over slabs).

    Parameters
    ----------
    group : LocalSlabs or instrument.processing.volume_shards.ShardedSlabs
    b : ndarray, float32, sensor shape
        The measurement the estimate was fitted to.
    w : ndarray, float32, sensor shape
        Its sensor weights.
    tv_w, l1_w : float
        Weights (0 leaves the term out).
    which : str
        The estimate: ``"x"`` or a copy the slabs saved
        (:meth:`recon.volume.slab.VolumeSlab.save`).

    Returns
    -------
    objective, data_sq : float
    """
    n = len(group)
    loss, _ = _residual(group.call("forward", [(which,)] * n), b, w)
    data_sq = 2.0 * loss
    final = loss
    if tv_w or l1_w:
        firsts = group.call("first_plane", [(which,)] * n)
        pens = group.call("penalty", [(which, firsts[i + 1] if i + 1 < n else None)
                                      for i in range(n)])
        final += tv_w * sum(p[0] for p in pens) + l1_w * sum(p[1] for p in pens)
    return final, data_sq


def streamed_fista3d(psf_stack, b: np.ndarray, *, psf_scale: float = 1.0, slabs: int = 1,
                     support: str = "sensor", sensor_weights=None,
                     padded_shape: tuple[int, int] | None = None,
                     chunk_bytes: int = CHUNK_BYTES, **solver) -> SolveResult:
    """:func:`slab_fista` with the slabs in this process.

    Parameters
    ----------
    psf_stack : array-like, shape (n_z, rows, cols)
        PSF stack (NumPy, or a Zarr array chunked by plane: read one chunk of planes
        at a time, never whole).
    b : ndarray, float32, (rows, cols)
        Scaled measurement.
    psf_scale : float
        Divisor of the stack (:func:`recon.volume.normalize_psf_stack`'s scale).
    slabs : int
        Slabs to split the planes into (1: one slab; more only to check the split).
    support : {"sensor", "padded"}
    sensor_weights : ndarray, optional
    padded_shape : (P0, P1), optional
    chunk_bytes : int
    **solver
        :func:`slab_fista`'s keywords (iterations, tv, l1, nonneg, step, ...).

    Returns
    -------
    SolveResult
    """
    n_z = psf_stack.shape[0]
    group = LocalSlabs([VolumeSlab(psf_stack, a, z, psf_scale, padded_shape=padded_shape,
                                   sensor_weights=sensor_weights, support=support,
                                   chunk_bytes=chunk_bytes)
                        for a, z in plan_slabs(n_z, slabs)])
    return slab_fista(group, b, sensor_weights=sensor_weights, **solver)
