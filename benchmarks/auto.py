"""The default reconstruction (automatic TV weight) against the oracle fixed weight,
over a suite of scenes of every kind, and its speed against accuracy.

Scenes (:data:`SUITE`, :mod:`benchmarks.auto_scenes`): sparse points and beads,
smooth shapes, four natural photographs, dense texture (brick, gravel), printed text
and a bar chart, line patterns (a Siemens star and gratings), a star field, a dark
scene at 300 and a bright one at 30000 peak photo-electrons (the others 3000), each
rendered through the measured tutorial PSF at bin 2 and reconstructed at bin 4 (model
mismatch: finer rendering grid, binned PSF), with Poisson and read noise (3 e-) and a
dark level in the raw that a dark frame with its own read noise removes.

Per scene: ``method="auto"`` exactly as :func:`recon.reconstruct` runs it
(:func:`recon.auto.solve_channel`: noise model fitted to the frame, the held-out path
of :mod:`recon.auto.weight`); the oracle: ADMM at fixed TV weights with the same
iteration cap (every half decade from 1e-5 to 1e-2 and no TV, then the quarter-decade
weights either side of the best: a grid of factor 1.8 where it counts), the best by
PSNR against the ground truth; the shortfall; the default's wall time over one
fixed-weight solve's, in wall and CPU time (medians over ``timing_repeats - 1`` pairs
of runs taken in turn of each pair's ratio, so a slow spell of the shared machine
falls on both, :func:`cost_in_turn`). PSNR and SSIM are gain-fitted
on the sensor field of view.

Speed against accuracy (:func:`plot_budget`): on :data:`FULL` ``budget_scenes`` the
default runs again with ``seconds`` set to 1-3x the fixed solve's time.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, write_json
from recon.auto import ChannelProblem, solve_channel
from recon.errors import DivergenceError, ReconInputError
from recon.fft import fft_pair_seconds
from recon.metrics import psnr, ssim
from recon.options import ReconOptions
from recon.solvers import admm

from .auto_scenes import render_case

__all__ = ["FULL", "GOAL_MEAN_DB", "GOAL_WORST_DB", "QUICK", "SUITE", "auto_table",
           "cost_in_turn", "cost_record", "cost_summary", "goal_summary", "plot_budget",
           "run_auto", "run_case", "timed"]

log = logging.getLogger(__name__)

#: (name, kind, peak photo-electrons) of the scene suite.
SUITE = (("points", "points", 3000.0), ("beads", "beads", 3000.0),
         ("shapes", "shapes", 3000.0), ("camera", "photo:camera", 3000.0),
         ("astronaut", "photo:astronaut", 3000.0), ("coffee", "photo:coffee", 3000.0),
         ("chelsea", "photo:chelsea", 3000.0), ("brick", "photo:brick", 3000.0),
         ("gravel", "photo:gravel", 3000.0), ("text", "text", 3000.0),
         ("page", "photo:page", 3000.0), ("lines", "lines", 3000.0),
         ("stars", "photo:hubble_deep_field", 3000.0),
         ("dark camera", "photo:camera", 300.0), ("bright coffee", "photo:coffee", 30000.0))

FULL = {"suite": SUITE, "coarse_bin": 4, "iterations": 200, "timing_repeats": 4,
        "read_noise_e": 3.0, "dark_e": 100.0,
        "grid": (0.0, 1e-5, 3.16e-5, 1e-4, 3.16e-4, 1e-3, 3.16e-3, 1e-2), "refine": 10 ** 0.25,
        "budget_scenes": ("beads", "camera", "astronaut", "brick"),
        "budget_factors": (1.0, 2.0, 3.0)}
QUICK = {"suite": (("camera", "photo:camera", 3000.0), ("beads", "beads", 3000.0)),
         "coarse_bin": 8, "iterations": 60, "timing_repeats": 1, "read_noise_e": 3.0,
         "dark_e": 100.0, "grid": (0.0, 1e-4, 1e-3), "refine": 10 ** 0.5,
         "budget_scenes": ("camera",), "budget_factors": (1.5,)}
#: Goals: mean shortfall against the oracle, and every scene's (dB).
GOAL_MEAN_DB, GOAL_WORST_DB = 0.5, 1.0
#: Goal: the default's wall time at most this multiple of one fixed-weight solve's.
GOAL_TIME_RATIO = 4.0


def _fixed(case, tv: float, iterations: int) -> dict:
    try:
        r, dt, cpu = timed(lambda: admm(case.op, case.b, iterations=iterations, tv=tv))
    except DivergenceError as exc:
        return {"tv": tv, "psnr": None, "diverged": str(exc)}
    x = r.x[case.op.crop]
    return {"tv": tv, "psnr": psnr(x, case.truth), "ssim": ssim(x, case.truth),
            "seconds": dt, "cpu_seconds": cpu}


def _oracle(case, cfg: dict) -> tuple[list, dict | None]:
    """The grid, then the weights ``refine`` x either side of its best."""
    it = cfg["iterations"]
    grid = [_fixed(case, tv, it) for tv in cfg["grid"]]
    ok = [g for g in grid if g["psnr"] is not None]
    if not ok:
        return grid, None
    best = max(ok, key=lambda g: g["psnr"])
    if best["tv"] > 0:
        grid += [_fixed(case, best["tv"] * f, it) for f in (cfg["refine"], 1 / cfg["refine"])]
    ok = [g for g in grid if g["psnr"] is not None]
    return grid, max(ok, key=lambda g: g["psnr"])


def _auto(case, cfg: dict, seconds: float | None = None, fft_pair_s: float | None = None
          ) -> dict:
    scale = float(np.max(np.abs(case.raw_e)))
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res, rec = solve_channel(
            ChannelProblem(case.op, case.b, case.raw_e, scale),
            ReconOptions.from_defaults(iterations=cfg["iterations"], tv="auto", l1=0.0,
                                       seconds=seconds), fft_pair_s=fft_pair_s)
    except (DivergenceError, ReconInputError) as exc:
        res, rec = None, {"error": str(exc)}
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    if res is None:
        return {"psnr": None, "error": rec["error"], "seconds": dt, "cpu_seconds": cpu}
    x = res.x[case.op.crop]
    w = rec.get("weight") or {}
    return {"psnr": psnr(x, case.truth), "ssim": ssim(x, case.truth), "seconds": dt,
            "cpu_seconds": cpu, "method": rec["method"]["method"], "tv": rec["tv"],
            "iterations_used": rec["iterations_used"], "stop_reason": w.get("stop_reason"),
            "candidates": len(w.get("path", [])),
            "candidates_settled": w.get("candidates_settled"),
            "chosen_settled": next((p["converged"] for p in w.get("path", [])
                                    if p["weight"] == w.get("weight")), None),
            "blank": bool(np.max(x) <= 0)}


def cost_in_turn(auto: dict, grid: list[dict], repeats: int, fixed, rerun) -> dict:
    """The default's time over one fixed-weight solve's, taken in turn.

    With ``repeats`` > 1, ``repeats - 1`` pairs run one after the other, a fixed solve
    (``fixed()``) then the default (``rerun()``), so a slow spell of the shared machine
    hits both; the default's first run (``auto``, not in turn) is dropped. The ratio is
    the median over the pairs of each pair's ratio (a ratio of medians mixed pairs taken
    minutes apart: the same 3D case gave 2.5x-4.7x that way, 3.4-3.8x pair by pair), in
    wall time and in the process's CPU time (``time.process_time``: every thread's, so
    the work done, which the machine's other programs hardly change). Without repeats
    the fixed time is the median of the grid's own solves.

    Parameters
    ----------
    auto : dict
        The default's record (``seconds``, ``cpu_seconds``); its ``seconds`` become the
        median of the runs in turn, ``seconds_runs`` those runs (s).
    grid : list of dict
        The oracle grid's records (``seconds``, ``cpu_seconds``; absent or None for a
        diverged one).
    repeats : int
        ``timing_repeats`` of the configuration.
    fixed, rerun : callable
        ``() -> dict`` with ``seconds`` and ``cpu_seconds``: one fixed solve at the
        oracle's weight, one run of the default.

    Returns
    -------
    dict
        ``fixed_seconds`` (median fixed-solve time, s; NaN when none finished) and
        ``fixed_seconds_runs``; ``ratio`` and ``cpu_ratio`` (the default over one fixed
        solve, wall and CPU time) with ``ratio_runs`` and ``cpu_ratio_runs`` (per pair;
        one value without repeats).
    """
    def median_ratio(a: list, f: list) -> tuple[float, list]:
        runs = [x / y for x, y in zip(a, f, strict=True) if x and y]
        return (float(np.median(runs)) if runs else math.nan), runs

    if repeats > 1:
        pairs = [(fixed(), rerun()) for _ in range(repeats - 1)]
        fixed_runs, auto_runs = [f for f, _ in pairs], [a for _, a in pairs]
        ratio, ratio_runs = median_ratio([a.get("seconds") for a in auto_runs],
                                         [f.get("seconds") for f in fixed_runs])
        cpu, cpu_runs = median_ratio([a.get("cpu_seconds") for a in auto_runs],
                                     [f.get("cpu_seconds") for f in fixed_runs])
    else:
        fixed_runs, auto_runs = [g for g in grid if g.get("seconds")], [auto]
        one = float(np.median([g["seconds"] for g in fixed_runs])) if fixed_runs else math.nan
        one_cpu = (float(np.median([g["cpu_seconds"] for g in fixed_runs]))
                   if fixed_runs else math.nan)
        ratio, ratio_runs = auto["seconds"] / one, [auto["seconds"] / one]
        cpu, cpu_runs = auto["cpu_seconds"] / one_cpu, [auto["cpu_seconds"] / one_cpu]
    auto_s = [a["seconds"] for a in auto_runs]
    fixed_s = [f["seconds"] for f in fixed_runs if f.get("seconds")] or [math.nan]
    auto["seconds"], auto["seconds_runs"] = float(np.median(auto_s)), auto_s
    return {"fixed_seconds": float(np.median(fixed_s)), "fixed_seconds_runs": fixed_s,
            "ratio": ratio, "ratio_runs": ratio_runs, "cpu_ratio": cpu,
            "cpu_ratio_runs": cpu_runs}


def cost_record(cost: dict) -> dict:
    """A case's cost fields from :func:`cost_in_turn`'s result: ``fixed_seconds`` and its
    runs, ``auto_cost_ratio`` (wall) and ``auto_cost_ratio_cpu`` with their per-pair
    runs."""
    return {"fixed_seconds": cost["fixed_seconds"],
            "fixed_seconds_runs": cost["fixed_seconds_runs"],
            "auto_cost_ratio": cost["ratio"], "auto_cost_ratio_runs": cost["ratio_runs"],
            "auto_cost_ratio_cpu": cost["cpu_ratio"],
            "auto_cost_ratio_cpu_runs": cost["cpu_ratio_runs"]}


def timed(fn) -> tuple[object, float, float]:
    """Run ``fn()``.

    Returns
    -------
    (object, float, float)
        Its result, its wall time and the process's CPU time (every thread's), s.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def cost_summary(cases: list[dict]) -> dict:
    """The suite's time ratios (wall and CPU, median and max) and the time goal
    (:data:`GOAL_TIME_RATIO`, judged on wall time)."""
    cost = [c["auto_cost_ratio"] for c in cases]
    cpu = [c["auto_cost_ratio_cpu"] for c in cases]
    return {"cost_ratio_median": float(np.median(cost)), "cost_ratio_max": float(np.max(cost)),
            "cost_ratio_cpu_median": float(np.median(cpu)),
            "cost_ratio_cpu_max": float(np.max(cpu)),
            "meets_time_goal": bool(max(cost) <= GOAL_TIME_RATIO)}


def run_case(name: str, kind: str, photons: float, cfg: dict, seed: int = 0) -> dict:
    """One scene: the oracle grid, the default, its cost and (``budget_scenes``) its
    accuracy at time budgets."""
    case = render_case(kind, photons, coarse_bin=cfg["coarse_bin"], seed=seed,
                       read_noise_e=cfg.get("read_noise_e", 3.0), dark_e=cfg.get("dark_e", 0))
    grid, oracle = _oracle(case, cfg)
    auto = _auto(case, cfg)
    cost = cost_in_turn(
        auto, grid, cfg.get("timing_repeats", 1),
        lambda: _fixed(case, oracle["tv"] if oracle else 0.0, cfg["iterations"]),
        lambda: _auto(case, cfg))
    one_fixed = cost["fixed_seconds"]
    out = {"scene": name, "kind": kind, "photons": photons, "snr_db": case.sim.snr_db,
           "grid": grid, "oracle": oracle, "auto": auto,
           "auto_shortfall_db": (oracle["psnr"] - auto["psnr"]
                                 if oracle and auto.get("psnr") is not None else None),
           **cost_record(cost)}
    if name in cfg.get("budget_scenes", ()):
        pair = fft_pair_seconds(case.op.padded_shape)
        out["budgets"] = []
        for f in cfg["budget_factors"]:
            b = _auto(case, cfg, seconds=f * one_fixed, fft_pair_s=pair)
            out["budgets"].append({"budget_factor": f, "seconds_asked": f * one_fixed,
                                   "seconds": b["seconds"], "psnr": b["psnr"],
                                   "tv": b.get("tv"), "method": b.get("method"),
                                   "time_ratio": b["seconds"] / one_fixed,
                                   "shortfall_db": (oracle["psnr"] - b["psnr"]
                                                    if oracle and b["psnr"] is not None
                                                    else None)})
    log.info("%s: oracle %s dB at %s, default %s dB at %s, time x%.2f", name,
             fmt(oracle and oracle["psnr"]), fmt(oracle and oracle["tv"], ".2g"),
             fmt(auto.get("psnr")), fmt(auto.get("tv"), ".2g"), out["auto_cost_ratio"])
    return out


def goal_summary(shortfalls: list, failures: list) -> dict:
    """Mean and worst shortfall against the oracle (dB) and whether the goals
    (:data:`GOAL_MEAN_DB`, :data:`GOAL_WORST_DB`, no failures) are met."""
    summary = {"mean_shortfall_db": float(np.mean(shortfalls)) if shortfalls else None,
               "worst_shortfall_db": float(np.max(shortfalls)) if shortfalls else None,
               "failures": failures}
    summary["meets_goals"] = bool(shortfalls and summary["mean_shortfall_db"] <= GOAL_MEAN_DB
                                  and summary["worst_shortfall_db"] <= GOAL_WORST_DB
                                  and not failures)
    return summary


def setup_record(cfg: dict) -> dict:
    """A benchmark configuration as JSON (tuples as lists) with the goals."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()} | {
        "goals_db": {"mean": GOAL_MEAN_DB, "worst": GOAL_WORST_DB},
        "goal_time_ratio": GOAL_TIME_RATIO}


def run_auto(quick: bool = False, out: Path | None = None) -> dict:
    """The default against the oracle over the scene suite.

    Returns
    -------
    dict
        ``cases`` (list of :func:`run_case` records), ``summary`` (mean and worst
        shortfall, time ratios, failures, goals met), ``setup``. With ``out``:
        ``auto.json`` and the chart ``auto_speed_accuracy.png`` there.
    """
    cfg = QUICK if quick else FULL
    t0 = time.perf_counter()
    cases = [run_case(name, kind, ph, cfg) for name, kind, ph in cfg["suite"]]
    short = [c["auto_shortfall_db"] for c in cases if c["auto_shortfall_db"] is not None]
    failures = [c["scene"] for c in cases
                if c["auto"].get("psnr") is None or c["auto"].get("blank")]
    budgets = [b for c in cases for b in c.get("budgets", [])]
    summary = goal_summary(short, failures) | {
        "scenes_over_1db": [c["scene"] for c in cases
                            if (c["auto_shortfall_db"] or 0) > GOAL_WORST_DB],
        **cost_summary(cases),
        "budget_overrun_max": (max(b["seconds"] / b["seconds_asked"] for b in budgets)
                               if budgets else None)}
    result = {"quick": quick, "setup": setup_record(cfg), "cases": cases, "summary": summary,
              "wall_seconds": time.perf_counter() - t0}
    if out is not None:
        write_json(Path(out) / "auto.json", result)
        plot_budget(result, Path(out) / "auto_speed_accuracy.png")
    return result


def plot_budget(result: dict, path: Path) -> Path:
    """Speed against accuracy: each budget scene's shortfall against the oracle at
    each time budget and without one, over the time in fixed-weight solves."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    for c in result["cases"]:
        if not c.get("budgets"):
            continue
        pts = [(b["time_ratio"], b["shortfall_db"]) for b in c["budgets"]
               if b["shortfall_db"] is not None]
        pts.append((c["auto_cost_ratio"], c["auto_shortfall_db"]))
        pts.sort()
        line, = ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=c["scene"])
        ax.plot([c["auto_cost_ratio"]], [c["auto_shortfall_db"]], "s", ms=9, mfc="none",
                color=line.get_color())
    ax.axhline(0.0, color="k", lw=1, label="oracle weight (fixed, same cap)")
    ax.axhline(GOAL_WORST_DB, color="r", ls="--", lw=1, label=f"goal: {GOAL_WORST_DB:g} dB")
    ax.axvline(GOAL_TIME_RATIO, color="grey", ls=":", lw=1,
               label=f"goal: {GOAL_TIME_RATIO:g}x one fixed solve")
    ax.set_xlabel("wall time / one fixed-weight ADMM solve (same iteration cap)")
    ax.set_ylabel("shortfall against the oracle weight (dB)")
    top = max([1.5] + [b["shortfall_db"] for c in result["cases"]
                       for b in c.get("budgets", []) if b["shortfall_db"] is not None])
    ax.set_ylim(min(-1.0, ax.get_ylim()[0]), min(top + 0.5, 15))
    ax.set_title("default (automatic weight) at time budgets of 1-3x a fixed solve, "
                 "and without (squares)", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def auto_table(result: dict) -> str:
    """Text table of :func:`run_auto`: one row per scene, then the budgets."""
    rows = []
    for c in result["cases"]:
        a, o = c["auto"], c["oracle"] or {}
        rows.append([c["scene"], f"{c['photons']:g}", fmt(o.get("psnr")), fmt(o.get("tv"), ".2g"),
                     fmt(a.get("psnr")), fmt(a.get("ssim"), ".3f"), fmt(a.get("tv"), ".2g"),
                     a.get("iterations_used", "-"),
                     f"{a.get('candidates_settled', '-')}/{a.get('candidates', '-')}",
                     fmt(c["auto_shortfall_db"]), fmt(c["auto_cost_ratio"]),
                     fmt(c.get("auto_cost_ratio_cpu"))])
    s, st = result["summary"], result["setup"]
    lines = [f"default (automatic TV weight) vs oracle fixed weight: ADMM, max "
             f"{st['iterations']} iterations, bin {st['coarse_bin']}",
             format_table(["scene", "e-", "oracle", "w", "auto", "SSIM", "w", "its", "settled",
                           "short", "time x", "cpu x"], rows),
             f"auto below oracle: mean {fmt(s['mean_shortfall_db'])} dB (goal "
             f"{GOAL_MEAN_DB}), worst {fmt(s['worst_shortfall_db'])} dB (goal "
             f"{GOAL_WORST_DB}; over it: {', '.join(s.get('scenes_over_1db', [])) or 'none'});"
             f" time x{fmt(s['cost_ratio_median'])} median, x{fmt(s['cost_ratio_max'])} max of "
             f"one fixed solve (goal {GOAL_TIME_RATIO:g}; CPU time x"
             f"{fmt(s.get('cost_ratio_cpu_median'))} median, x{fmt(s.get('cost_ratio_cpu_max'))}"
             f" max); failures: "
             f"{', '.join(s['failures']) or 'none'}"]
    brows = [[c["scene"], fmt(b["seconds_asked"]), fmt(b["seconds"]), fmt(b["time_ratio"]),
              b.get("method") or "-", fmt(b["psnr"]), fmt(b["shortfall_db"])]
             for c in result["cases"] for b in c.get("budgets", [])]
    if brows:
        over = s.get("budget_overrun_max")
        lines += ["time budgets (--seconds):",
                  format_table(["scene", "asked s", "took s", "time x", "method", "PSNR",
                                "short"], brows),
                  f"largest time taken over time asked: "
                  f"{fmt(over) if over is not None and math.isfinite(over) else '-'}"]
    return "\n".join(lines)
