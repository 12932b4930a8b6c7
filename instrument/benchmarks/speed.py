"""Speed: seconds per iteration as a ratio to the FFT floor, on the real sample.

The FFT floor (:func:`recon.fft.fft_pair_seconds`, one rfft2 + irfft2 at the padded
shape) is measured in the same process, sampled repeatedly and interleaved with the
method runs, because the machine is shared and its speed drifts: every run of a
method is bracketed by two floor samples and its median time per iteration divided
by their mean (a paired ratio); the reported ratio is the median over runs (the
unpaired ratio of all-sample medians is kept in the JSON). GD, FISTA and ADMM need
two FFT pairs per iteration, Wiener one pair per solve.

On a loaded machine the floor (compute-bound, its data in the cores' caches) slows
down more than a solver iteration (which streams a dozen arrays through memory), so
the paired median understates the ratio of a quiet machine. The JSON also holds
``ratio_low``, the 10th percentile of the iteration times over the 10th percentile
of the floor samples: the ratio of the least disturbed moments, an estimate of the
quiet machine's. Sizes: bin 4 and bin 2 of the tutorial sample, and bin 1 (the
full 1200 x 1600 sensor, padded 2400 x 3200) in a full run. Where LenslessPiCam is
installed (``pip install lensless``; not a dependency), a full run also times its
numpy ADMM on the same measurement at bins 4 and 2, interleaved with ours, and
reports our seconds per iteration over its.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from recon.fft import fft_pair_seconds
from recon.solvers import SOLVERS

from . import (
    DEFAULT_WEIGHTS,
    METHODS,
    fmt,
    format_table,
    load_sample,
    scaled_problem,
    solve,
    write_json,
)

#: Goals (ratio to the FFT floor) printed next to the figures.
GOALS: dict[str, float] = {"wiener": 1.5, "fista": 3.0, "admm": 3.0}
#: Published ratios of other implementations on this kind of machine (not run here).
REFERENCES: dict[str, float] = {"LenslessPiCam numpy ADMM": 6.0,
                                "DiffuserCam tutorial ADMM": 33.0}

#: Per bin factor: (runs, iterations per run, Wiener solves), quick and full.
SETTINGS = {True: {4: (2, 8, 15), 2: (2, 5, 15)},
            False: {4: (11, 25, 33), 2: (9, 12, 18), 1: (5, 6, 6)}}
#: Bins at which a full run times LenslessPiCam's ADMM beside ours.
LENSLESS_BINS = (4, 2)


def _lensless_admm(prep, b: np.ndarray, weight: float):
    """``run(iterations) -> seconds per iteration`` of LenslessPiCam's ADMM, or the
    reason it cannot run (str)."""
    try:
        from lensless import ADMM
    except ImportError as exc:
        return f"lensless not installed ({exc}); pip install lensless to compare"
    psf = np.asarray(prep.psf, np.float32)[None, :, :, None]
    rec = ADMM(psf / psf.sum(), dtype="float32", tau=weight)
    rec.set_data(np.ascontiguousarray(b, np.float32)[None, :, :, None])

    def run(iterations: int) -> float:
        t0 = time.perf_counter()
        rec.apply(n_iter=iterations, disp_iter=None, plot=False)
        return (time.perf_counter() - t0) / iterations
    run(2)  # warm-up
    return run


def _measure(bin_factor: int, runs: int, iterations: int, wiener_solves: int,
             weights: dict[str, float], lensless: bool = False) -> dict:
    prep = load_sample(bin_factor)
    op, b = scaled_problem(prep.psf, prep.raw)
    shape = op.padded_shape
    lip = op.lipschitz()
    floor: list[float] = []

    def sample_floor() -> float:
        floor.append(fft_pair_seconds(shape, repeats=5))
        return floor[-1]

    # weights: GD without TV (the tutorial baseline), the others with theirs
    used = {m: 0.0 if m == "gd" else weights[m] for m in METHODS}
    for m in METHODS:  # warm-up: JIT caches, FFT plans, page faults
        solve(m, op, b, 3, used[m], lipschitz=lip)
    other = _lensless_admm(prep, b, used["admm"]) if lensless else None
    theirs: list[float] = []
    ours_over: list[float] = []
    times: dict[str, list[float]] = {m: [] for m in METHODS}
    # the host is shared and its speed drifts over seconds: each run is bracketed by
    # floor samples and its ratio taken against their mean (paired ratios); the
    # reported ratio is the median over runs
    paired: dict[str, list[float]] = {m: [] for m in METHODS}
    per_run = max(1, math.ceil(wiener_solves / runs))
    t_start = time.perf_counter()
    for _ in range(runs):
        for m in METHODS:
            before = sample_floor()
            if not SOLVERS[m].iterative:
                run = [solve(m, op, b, 1, used[m]).history.seconds[0] for _ in range(per_run)]
            else:
                run = solve(m, op, b, iterations, used[m], lipschitz=lip).history.seconds
            after = sample_floor()
            times[m].extend(run)
            paired[m].append(float(np.median(run)) / (0.5 * (before + after)))
            if m == "admm" and callable(other):
                theirs.append(other(iterations) / after)
                ours_over.append(float(np.median(run)) / after / theirs[-1])
                sample_floor()
    floor_med = float(np.median(floor))
    methods = {}
    for m in METHODS:
        t = np.asarray(times[m])
        med = float(np.median(t))
        ratio = float(np.median(paired[m]))
        methods[m] = {
            "weight": used[m],
            "seconds_per_iteration": med,
            "seconds_p25": float(np.percentile(t, 25)),
            "seconds_p75": float(np.percentile(t, 75)),
            "samples": int(t.size),
            "ratio": ratio,
            "ratio_per_run": paired[m],
            "ratio_unpaired": med / floor_med,
            "ratio_low": float(np.percentile(t, 10) / np.percentile(floor, 10)),
            "goal": GOALS.get(m),
            "meets_goal": None if m not in GOALS else bool(ratio <= GOALS[m]),
        }
    return {
        "bin_factor": bin_factor,
        "sensor_shape": list(op.sensor_shape),
        "padded_shape": list(shape),
        "fft_floor_seconds": floor_med,
        "fft_floor_samples": [float(f) for f in floor],
        "fft_floor_spread": [float(np.min(floor)), float(np.max(floor))],
        "runs": runs,
        "iterations_per_run": iterations,
        "wall_seconds": time.perf_counter() - t_start,
        "methods": methods,
        **({} if other is None else {"lensless_admm": {"skipped": other} if isinstance(
            other, str) else {"ratio": float(np.median(theirs)),
                              "ours_over_lensless": float(np.median(ours_over)),
                              "ours_over_lensless_per_run": ours_over}}),
    }


def run_speed(quick: bool = False, out: Path | None = None,
              weights: dict[str, float] | None = None) -> dict:
    """Median seconds per iteration and ratio to the FFT floor at bins 4, 2 and 1.

    Parameters
    ----------
    quick : bool
        Fewer runs and iterations, bins 4 and 2 only, no LenslessPiCam (for
        tests/CI; figures are noisier).
    out : Path, optional
        Directory for ``speed.json``.
    weights : dict, optional
        Per-method weights (only TV on/off matters for the speed); default
        :data:`instrument.benchmarks.DEFAULT_WEIGHTS`.

    Returns
    -------
    dict
        ``{"bins": {"4": {...}, "2": {...}, "1": {...}}, "goals": ...,
        "references": ...}``; each bin has ``fft_floor_seconds``, per method
        ``seconds_per_iteration``, ``ratio``, ``ratio_low``, ``goal``,
        ``meets_goal``, and in a full run at bins 4 and 2 ``lensless_admm``
        (``ratio`` and ``ours_over_lensless``, or ``skipped`` with the reason).
    """
    w = dict(DEFAULT_WEIGHTS, **(weights or {}))
    result = {"quick": quick, "goals": GOALS, "references": REFERENCES, "bins": {}}
    for bf, (runs, iters, wsolves) in SETTINGS[quick].items():
        result["bins"][str(bf)] = _measure(bf, runs, iters, wsolves, w,
                                           lensless=not quick and bf in LENSLESS_BINS)
    if out is not None:
        write_json(Path(out) / "speed.json", result)
    return result


def speed_table(result: dict) -> str:
    """Text table of a :func:`run_speed` result."""
    lines = []
    for bf, r in result["bins"].items():
        s, p = r["sensor_shape"], r["padded_shape"]
        lines.append(f"speed, bin {bf}: sensor {s[0]}x{s[1]}, padded {p[0]}x{p[1]}, FFT floor "
                     f"{r['fft_floor_seconds'] * 1e3:.2f} ms (median of "
                     f"{len(r['fft_floor_samples'])} samples, range "
                     f"{r['fft_floor_spread'][0] * 1e3:.2f}-{r['fft_floor_spread'][1] * 1e3:.2f})")
        rows = []
        for m, d in r["methods"].items():
            goal = "" if d["goal"] is None else (
                f"<= {d['goal']:.1f}x " + ("ok" if d["meets_goal"] else "MISSED"))
            low = d.get("ratio_low")
            rows.append([m, fmt(d["weight"], "g"), f"{d['seconds_per_iteration'] * 1e3:.2f} ms",
                         f"{d['ratio']:.2f}x", "" if low is None else f"{low:.2f}x",
                         d["samples"], goal])
        lines.append(format_table(["method", "weight", "s/iter", "/floor", "/floor (p10)", "n",
                                   "goal"], rows))
        other = r.get("lensless_admm")
        if other is not None:
            lines.append("LenslessPiCam ADMM (same measurement, same run): " + (
                other["skipped"] if "skipped" in other else
                f"{other['ratio']:.2f}x the floor; our ADMM's time per iteration is "
                f"{other['ours_over_lensless']:.2f}x its"))
    lines.append("reference (published, not run here): " + "; ".join(
        f"{k} ~{v:.0f}x" for k, v in result["references"].items()))
    return "\n".join(lines)
