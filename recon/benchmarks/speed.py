"""Speed: seconds per iteration as a ratio to the FFT floor, on the real sample.

The FFT floor (:func:`recon.fft.fft_pair_seconds`, one rfft2 + irfft2 at the padded
shape) is measured in the same process, sampled repeatedly and interleaved with the
method runs, because the machine is shared and its speed drifts: every run of a
method is bracketed by two floor samples and its median time per iteration divided
by their mean (a paired ratio); the reported ratio is the median over runs (the
unpaired ratio of all-sample medians is kept in the JSON). GD, FISTA and ADMM need
two FFT pairs per iteration, Wiener one pair per solve.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ..fft import fft_pair_seconds
from ..solvers import SOLVERS
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


def _measure(bin_factor: int, runs: int, iterations: int, wiener_solves: int,
             weights: dict[str, float]) -> dict:
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
    }


def run_speed(quick: bool = False, out: Path | None = None,
              weights: dict[str, float] | None = None) -> dict:
    """Median seconds per iteration and ratio to the FFT floor at bin 4 and bin 2.

    Parameters
    ----------
    quick : bool
        Fewer runs and iterations (for tests/CI; figures are noisier).
    out : Path, optional
        Directory for ``speed.json``.
    weights : dict, optional
        Per-method weights (only TV on/off matters for the speed); default
        :data:`recon.benchmarks.DEFAULT_WEIGHTS`.

    Returns
    -------
    dict
        ``{"bins": {"4": {...}, "2": {...}}, "goals": ..., "references": ...}``; each
        bin has ``fft_floor_seconds`` and per method ``seconds_per_iteration``,
        ``ratio``, ``goal``, ``meets_goal``.
    """
    w = dict(DEFAULT_WEIGHTS, **(weights or {}))
    settings = {4: (2, 8, 15), 2: (2, 5, 15)} if quick else {4: (11, 25, 33), 2: (9, 12, 18)}
    result = {"quick": quick, "goals": GOALS, "references": REFERENCES, "bins": {}}
    for bf, (runs, iters, wsolves) in settings.items():
        result["bins"][str(bf)] = _measure(bf, runs, iters, wsolves, w)
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
            rows.append([m, fmt(d["weight"], "g"), f"{d['seconds_per_iteration'] * 1e3:.2f} ms",
                         f"{d['ratio']:.2f}x", d["samples"], goal])
        lines.append(format_table(["method", "weight", "s/iter", "/floor", "n", "goal"], rows))
    lines.append("reference (published, not run here): " + "; ".join(
        f"{k} ~{v:.0f}x" for k, v in result["references"].items()))
    return "\n".join(lines)
