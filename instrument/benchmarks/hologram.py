"""Full-size hologram speed benchmark (docs/protocols.md, "Hologram speed budget").

Default: 960 x 540 SLM with 16 um pixels, 16x expansion (k = 4, grid 3840 x 2160),
frequency-constrained loss, 200 iterations; goal <= 90 s on a 2-core machine (other
goals in :data:`GOALS`).
Prints seconds per iteration as a ratio to one complex64 FFT at the grid size
measured in the same run (median of several), the measured FFTs per iteration,
the FFT share of the time and the peak memory (Python/numpy allocations traced by
:mod:`tracemalloc`, and the process' peak RSS); :func:`format_report` gives the
lines ``diffuserlab holo benchmark [--quick]`` prints.
"""

from __future__ import annotations

import math
import resource
import time
import timeit
import tracemalloc

import numpy as np

from recon.backend import NUMPY, Backend, to_device
from recon.cgh.losses import IntensityLoss
from recon.cgh.optimize import optimize_hologram
from recon.cgh.protocol import load_bundled, prepare_target
from recon.cgh.scattering_display import ScatteringDisplay
from recon.errors import ReconInputError
from recon.fft import WORKERS, time_ffts

__all__ = ["GOALS", "fft_seconds", "format_report", "goal_seconds", "run_benchmark"]

#: Goals (docs/protocols.md, "Hologram speed budget") for a 960 x 540 SLM, 200 iterations:
#: (expansion factor, loss) -> seconds per hologram on a 2-core CPU.
GOALS = {(16, "frequency"): 90.0, (16, "l2"): 60.0, (4, "frequency"): 20.0,
         (36, "frequency"): 240.0}


def _warm_up(loss: IntensityLoss, backend: Backend) -> None:
    """Load (or compile) the numba kernels, or the backend's kernels, on a tiny problem so
    timing excludes it."""
    d = ScatteringDisplay((4, 6), 2, mask_seed=1)
    optimize_hologram(d, to_device(np.ones(d.grid_shape, np.float32), backend), loss, 2)


def fft_seconds(grid, backend: Backend = NUMPY, repeats: int = 9) -> float:
    """Median seconds of one complex64 ``fft2`` at ``grid`` on ``backend``.

    The NumPy path times scipy.fft (:func:`recon.fft.time_ffts`); another backend its
    ``fft.fftn``, waiting for the result (one element read back) so a GPU's
    asynchronous launch is not mistaken for the transform.

    Parameters
    ----------
    grid : (int, int)
        Mask grid ``(G_y, G_x)``.
    backend : recon.backend.Backend
    repeats : int
        Timings for the median (after one untimed call that makes the plan).

    Returns
    -------
    float
        Seconds.
    """
    if backend.is_numpy:
        return time_ffts(grid, real=False, repeats=repeats)
    xp = backend.xp
    rng = np.random.default_rng(0)
    a = to_device(rng.random(grid, dtype=np.float32).astype(np.complex64), backend)

    def once():
        out = xp.fft.fftn(a, axes=(-2, -1), norm="ortho")
        float(xp.real(out[0, 0]))  # wait for it

    once()  # the plan
    return float(np.median(timeit.repeat(once, number=1, repeat=repeats)))


def run_benchmark(slm_shape=(540, 960), k: int = 4, steps: int = 200,
                  loss: str = "frequency", fft_repeats: int = 9,
                  backend: Backend = NUMPY) -> dict:
    """Time one hologram and the FFT floor in the same process, on one backend.

    Parameters
    ----------
    slm_shape : (int, int)
        SLM pixels (rows, cols).
    k : int
        Mask pixels per SLM pixel (expansion ``k^2``).
    steps : int
        Optimiser steps (its iterations; :func:`recon.cgh.optimize_hologram`'s
        ``steps``).
    loss : {"frequency", "l2", "spatial"}
        Loss of the timed hologram.
    fft_repeats : int
        FFT timings for the median.
    backend : recon.backend.Backend
        The NumPy path (default) or a generic one (:func:`recon.backend.resolve_device`,
        :func:`recon.backend.torch_cpu`): the target is put on its device and the
        optimiser runs there; the FFT floor is that device's (:func:`fft_seconds`).

    Returns
    -------
    dict
        Settings (``device`` included), ``seconds`` (total), ``setup_seconds``,
        ``seconds_per_iteration`` (mean and median), ``fft_seconds``, ``ratio``
        (s/iteration over one FFT), ``ffts_per_iteration``, ``fft_share`` (NaN on a
        generic path, whose FFTs are not timed one by one), ``peak_traced_mb`` (host
        allocations), ``peak_rss_mb``.
    """
    losses = {"frequency": IntensityLoss.frequency, "l2": IntensityLoss.l2,
              "spatial": IntensityLoss.spatial}
    if loss not in losses:
        raise ReconInputError(f"loss must be one of {sorted(losses)}, got {loss!r}")
    lf = losses[loss]()
    _warm_up(lf, backend)
    grid = (slm_shape[0] * k, slm_shape[1] * k)
    t_fft = fft_seconds(grid, backend, fft_repeats)  # one complex64 fft2
    target = prepare_target(load_bundled("astronaut"), grid)
    tracemalloc.start()
    t0 = time.perf_counter()
    display = ScatteringDisplay(slm_shape, k, mask_seed=0)
    res = optimize_hologram(display, to_device(target, backend), lf, steps, seed=1)
    total = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    secs = np.asarray(res.history.seconds)
    per_it = float(secs.mean())
    return {"slm_shape": list(slm_shape), "k": k, "grid": list(grid), "loss": loss,
            "iterations": res.iterations, "workers": WORKERS, "device": res.params["device"],
            "seconds": total,
            "setup_seconds": total - float(secs.sum()),
            "seconds_per_iteration": per_it,
            "median_seconds_per_iteration": float(np.median(secs)),
            "fft_seconds": t_fft, "ratio": per_it / t_fft,
            "ffts_per_iteration": res.ffts_per_iteration,
            "fft_share": float(np.sum(res.history.extra["fft_seconds"]) / secs.sum()),
            "backtracks": int(np.sum(res.history.extra["backtracks"])),
            "peak_traced_mb": peak / 2**20,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "stop_reason": res.stop_reason, "final_loss": res.loss}


def goal_seconds(factor: int, loss: str, slm_shape, iterations: int) -> float | None:
    """The goal of :data:`GOALS` for this run, or None (only the full-size 960 x 540,
    200-iteration runs have one)."""
    if tuple(slm_shape) != (540, 960) or iterations != 200:
        return None
    return GOALS.get((factor, loss))


def format_report(rep: dict, factor: int, fft_repeats: int, iterations: int) -> str:
    """The report of a :func:`run_benchmark` result, one finding per line.

    Parameters
    ----------
    rep : dict
        From :func:`run_benchmark`.
    factor : int
        Expansion factor ``k^2`` of the run.
    fft_repeats : int
        FFT timings the median was taken over.
    iterations : int
        Iterations asked for (the optimiser may stop earlier).

    Returns
    -------
    str
        Grid and settings, total and per-iteration seconds, the FFT floor and the
        ratio, FFTs per iteration and their share, peak memory and, for a full-size
        run with a goal (:func:`goal_seconds`), whether it meets it.
    """
    slm, loss = rep["slm_shape"], rep["loss"]
    lines = [
        f"grid {rep['grid'][0]} x {rep['grid'][1]} (SLM {slm[0]} x {slm[1]}, {factor}x), "
        f"{loss} loss, {rep['iterations']} iterations, on {rep.get('device', 'cpu (numpy)')}"
        f", {rep['workers']} CPU workers",
        f"total {rep['seconds']:.1f} s (setup {rep['setup_seconds']:.1f} s); "
        f"{rep['seconds_per_iteration']:.3f} s/iteration "
        f"(median {rep['median_seconds_per_iteration']:.3f})",
        f"one complex64 FFT at the grid: {rep['fft_seconds'] * 1e3:.1f} ms (median of "
        f"{fft_repeats}); s/iteration = {rep['ratio']:.2f} FFTs",
        f"FFTs per iteration (complex equivalents): {rep['ffts_per_iteration']:.2f}; "
        + (f"FFT share of the time {100 * rep['fft_share']:.0f} %" if math.isfinite(
            rep["fft_share"]) else "FFT share not timed (generic path)")
        + f"; backtracks {rep['backtracks']}",
        f"peak memory: {rep['peak_traced_mb']:.0f} MB traced (numpy/Python), "
        f"{rep['peak_rss_mb']:.0f} MB peak RSS",
    ]
    goal = goal_seconds(factor, loss, slm, iterations)
    if goal is not None:
        verdict = "meets" if rep["seconds"] <= goal else "misses"
        lines.append(f"goal <= {goal:.0f} s per hologram ({factor}x, {loss}): {verdict}")
    return "\n".join(lines)
