"""Full-size hologram speed benchmark (docs/protocols.md, "Hologram speed budget").

Default: 960 x 540 SLM with 16 um pixels, 16x expansion (k = 4, grid 3840 x 2160),
frequency-constrained loss, 200 iterations; goal <= 90 s on a 2-core machine (other
goals in :data:`GOALS`).
Prints seconds per iteration as a ratio to one complex64 FFT at the grid size
measured in the same run (median of several), the measured FFTs per iteration,
the FFT share of the time and the peak memory (Python/numpy allocations traced by
:mod:`tracemalloc`, and the process' peak RSS)::

    python -m recon.cgh.benchmark            # full size
    python -m recon.cgh.benchmark --quick    # tiny smoke run
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
import tracemalloc

import numpy as np

from ..errors import ReconInputError
from ..fft import WORKERS, time_ffts
from .losses import IntensityLoss
from .optimize import optimize_hologram
from .protocol import load_bundled, prepare_target
from .scattering_display import ScatteringDisplay

__all__ = ["main", "run_benchmark"]

#: Goals (docs/protocols.md, "Hologram speed budget") for a 960 x 540 SLM, 200 iterations:
#: (expansion factor, loss) -> seconds per hologram on a 2-core CPU.
GOALS = {(16, "frequency"): 90.0, (16, "l2"): 60.0, (4, "frequency"): 20.0,
         (36, "frequency"): 240.0}


def _warm_up(loss: IntensityLoss) -> None:
    """Load (or compile) the numba kernels on a tiny problem so timing excludes it."""
    d = ScatteringDisplay((4, 6), 2, mask_seed=1)
    optimize_hologram(d, np.ones(d.grid_shape, np.float32), loss, 2)


def run_benchmark(slm_shape=(540, 960), k: int = 4, iterations: int = 200,
                  loss: str = "frequency", fft_repeats: int = 9) -> dict:
    """Time one hologram and the FFT floor in the same process.

    Parameters
    ----------
    slm_shape : (int, int)
        SLM pixels (rows, cols).
    k : int
        Mask pixels per SLM pixel (expansion ``k^2``).
    iterations : int
        Optimiser iterations.
    loss : {"frequency", "l2", "spatial"}
        Loss of the timed hologram.
    fft_repeats : int
        FFT timings for the median.

    Returns
    -------
    dict
        Settings, ``seconds`` (total), ``setup_seconds``, ``seconds_per_iteration``
        (mean and median), ``fft_seconds``, ``ratio`` (s/iteration over one FFT),
        ``ffts_per_iteration``, ``fft_share``, ``peak_traced_mb``, ``peak_rss_mb``.
    """
    losses = {"frequency": IntensityLoss.frequency, "l2": IntensityLoss.l2,
              "spatial": IntensityLoss.spatial}
    if loss not in losses:
        raise ReconInputError(f"loss must be one of {sorted(losses)}, got {loss!r}")
    lf = losses[loss]()
    _warm_up(lf)
    grid = (slm_shape[0] * k, slm_shape[1] * k)
    t_fft = time_ffts(grid, real=False, repeats=fft_repeats)  # one complex64 fft2
    target = prepare_target(load_bundled("astronaut"), grid)
    tracemalloc.start()
    t0 = time.perf_counter()
    display = ScatteringDisplay(slm_shape, k, mask_seed=0)
    res = optimize_hologram(display, target, lf, iterations, seed=1)
    total = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    secs = np.asarray(res.history.seconds)
    per_it = float(secs.mean())
    return {"slm_shape": list(slm_shape), "k": k, "grid": list(grid), "loss": loss,
            "iterations": res.iterations, "workers": WORKERS, "seconds": total,
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


def main(argv=None) -> int:
    """Run the benchmark and print the report; returns 0 (2 on bad input)."""
    p = argparse.ArgumentParser(prog="python -m recon.cgh.benchmark",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--slm", type=int, nargs=2, default=(540, 960), metavar=("ROWS", "COLS"))
    p.add_argument("--factor", type=int, default=16, help="expansion factor k^2 (16)")
    p.add_argument("--iterations", type=int, default=200)
    p.add_argument("--loss", default="frequency", choices=("frequency", "l2", "spatial"))
    p.add_argument("--fft-repeats", type=int, default=9)
    p.add_argument("--json", default=None, help="also write the report to this JSON file")
    p.add_argument("--quick", action="store_true", help="tiny smoke run (36 x 64 SLM, 10 it.)")
    args = p.parse_args(argv)
    slm, iters, reps = tuple(args.slm), args.iterations, args.fft_repeats
    if args.quick:
        slm, iters, reps = (36, 64), 10, 3
    k = int(round(args.factor ** 0.5))
    try:
        if k * k != args.factor or min(slm) < 1 or iters < 1 or reps < 1:
            raise ReconInputError("--factor must be a perfect square; --slm, --iterations and "
                                  "--fft-repeats must be positive")
        rep = run_benchmark(slm, k, iters, args.loss, reps)
    except ReconInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    goal = GOALS.get((args.factor, args.loss)) if slm == (540, 960) and iters == 200 else None
    print(f"grid {rep['grid'][0]} x {rep['grid'][1]} (SLM {slm[0]} x {slm[1]}, {args.factor}x), "
          f"{rep['loss']} loss, {rep['iterations']} iterations, {rep['workers']} workers")
    print(f"total {rep['seconds']:.1f} s (setup {rep['setup_seconds']:.1f} s); "
          f"{rep['seconds_per_iteration']:.3f} s/iteration "
          f"(median {rep['median_seconds_per_iteration']:.3f})")
    print(f"one complex64 FFT at the grid: {rep['fft_seconds'] * 1e3:.1f} ms (median of {reps}); "
          f"s/iteration = {rep['ratio']:.2f} FFTs")
    print(f"FFTs per iteration (complex equivalents): {rep['ffts_per_iteration']:.2f}; "
          f"FFT share of the time {100 * rep['fft_share']:.0f} %; backtracks {rep['backtracks']}")
    print(f"peak memory: {rep['peak_traced_mb']:.0f} MB traced (numpy/Python), "
          f"{rep['peak_rss_mb']:.0f} MB peak RSS")
    if goal is not None:
        verdict = "meets" if rep["seconds"] <= goal else "misses"
        print(f"goal <= {goal:.0f} s per hologram ({args.factor}x, {args.loss}): {verdict}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rep, fh, indent=1)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
