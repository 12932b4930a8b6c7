"""The image priors (TV, wavelet, DnCNN) on the scene suite: each prior at its oracle
weight, each prior's automatic weight, and the automatic prior, against the oracle TV
weight; PSNR/SSIM, time, and speed against accuracy.

Scenes: the natural and textured scenes of the scene suite (:data:`SCENES`: the four
photographs, brick and gravel, from :data:`benchmarks.auto.SUITE`) and, as a check
that the choice does not take a learned prior where TV suffices, a few others
(:data:`OTHERS`: beads, text, the camera at 300 photo-electrons), each rendered as
in :mod:`benchmarks.auto` (the measured
tutorial PSF at bin 2, reconstructed coarser: model mismatch; Poisson and read noise,
a dark level removed by a dark frame) and reconstructed at bin ``coarse_bin``.

Per scene and prior: ADMM at fixed weights on the prior's grid (:data:`FULL`), the
best by PSNR against the truth (the prior's oracle; TV's is the reference); the
prior's automatic weight (the held-out path, :func:`recon.auto.prior_path`); the
automatic prior (:func:`recon.auto.prior.choose_prior` over the three paths, the same
runs), with what it chose and why. Time: each result's wall time over the TV
default's (the automatic TV weight, ``prior="tv"``). The DnCNN runs in onnxruntime on
the CPU here.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, write_json
from recon.auto import ChannelProblem, noise_energy_of, prior_path, solve_channel
from recon.auto.prior import choose_prior
from recon.errors import DivergenceError
from recon.metrics import psnr, ssim
from recon.options import ReconOptions
from recon.priors import AUTO_PRIORS
from recon.solvers import admm

from .auto import SUITE, setup_record, timed
from .auto_scenes import render_case

__all__ = ["FULL", "GOAL_GAIN_DB", "GOAL_WORST_DB", "OTHERS", "QUICK", "SCENES",
           "plot_priors", "priors_table", "run_priors", "run_scene"]

log = logging.getLogger(__name__)

#: The natural and textured scenes of the suite (the goals are judged on these).
SCENES = ("camera", "astronaut", "coffee", "chelsea", "brick", "gravel")
#: Other kinds, reported beside them.
OTHERS = ("beads", "text", "dark camera")
_KINDS = {name: (kind, photons) for name, kind, photons in SUITE}

#: Goals: the automatic prior's mean PSNR at least this much above the oracle TV
#: weight's on :data:`SCENES`, and no scene below it by more than ``GOAL_WORST_DB``.
GOAL_GAIN_DB, GOAL_WORST_DB = 1.0, 0.5

FULL = {"scenes": SCENES, "others": OTHERS, "coarse_bin": 8, "iterations": 200,
        "read_noise_e": 3.0, "dark_e": 100.0,
        "grids": {"tv": (1e-5, 3.16e-5, 1e-4, 3.16e-4, 1e-3, 3.16e-3),
                  "wavelet": (3.16e-5, 1e-4, 3.16e-4, 1e-3),
                  "dncnn": (0.1, 0.15, 0.2, 0.25)}}
QUICK = {"scenes": ("camera",), "others": (), "coarse_bin": 16, "iterations": 30,
         "read_noise_e": 3.0, "dark_e": 100.0,
         "grids": {"tv": (1e-4, 1e-3), "wavelet": (3.16e-4,), "dncnn": (0.2,)}}


def _score(case, x) -> dict:
    x = x[case.op.crop]
    return {"psnr": psnr(x, case.truth), "ssim": ssim(x, case.truth)}


def _oracle(case, prior: str, grid, iterations: int) -> dict:
    """The prior's fixed weights; the best by PSNR."""
    rows = []
    for w in grid:
        try:
            r, dt, _ = timed(lambda w=w: admm(case.op, case.b, iterations=iterations, tv=w,
                                              prior=prior))
        except DivergenceError as exc:
            rows.append({"weight": w, "psnr": None, "diverged": str(exc)})
            continue
        rows.append({"weight": w, "seconds": dt, **_score(case, r.x)})
    ok = [r for r in rows if r["psnr"] is not None]
    return {"grid": rows, "best": max(ok, key=lambda r: r["psnr"]) if ok else None}


def run_scene(name: str, cfg: dict, seed: int = 0) -> dict:
    """One scene: every prior's oracle and automatic weight, the automatic prior."""
    kind, photons = _KINDS[name]
    case = render_case(kind, photons, coarse_bin=cfg["coarse_bin"], seed=seed,
                       read_noise_e=cfg["read_noise_e"], dark_e=cfg["dark_e"])
    it = cfg["iterations"]
    scale = float(np.max(np.abs(case.raw_e)))
    (default, _), t_default, _ = timed(lambda: solve_channel(
        ChannelProblem(case.op, case.b, case.raw_e, scale),
        ReconOptions.from_defaults(method="admm", iterations=it, tv="auto", l1=0.0)))
    t0 = time.perf_counter()
    _, energy = noise_energy_of(case.op, case.raw_e, scale)
    path = prior_path(case.op, case.b, iterations=it, noise_energy=energy)
    res, weight, choice = choose_prior(path)
    t_auto = time.perf_counter() - t0
    priors = {}
    for c in choice.candidates:
        p = c["prior"]
        r = choice.results.get(p)
        oracle = _oracle(case, p, cfg["grids"][p], it)
        priors[p] = {"oracle": oracle["best"], "grid": oracle["grid"],
                     "auto": dict(c, **(_score(case, r.x) if r is not None else {}),
                                  time_ratio=c["seconds"] / t_default)}
    ref = priors["tv"]["oracle"]["psnr"]
    auto = {"prior": choice.prior, "weight": weight.weight, "reason": choice.reason,
            "seconds": t_auto, "time_ratio": t_auto / t_default, **_score(case, res.x)}
    best = max(priors, key=lambda p: priors[p]["oracle"]["psnr"] if priors[p]["oracle"]
               else -np.inf)
    out = {"scene": name, "kind": kind, "photons": photons, "snr_db": case.sim.snr_db,
           "tv_default": {"seconds": t_default, **_score(case, default.x)},
           "priors": priors, "auto": auto, "best_prior": best,
           "gain_over_tv_oracle_db": auto["psnr"] - ref,
           "best_prior_gain_db": priors[best]["oracle"]["psnr"] - ref}
    log.info("%s: TV oracle %.2f dB; auto prior %s %.2f dB (x%.1f the TV default's time); "
             "best prior %s", name, ref, choice.prior, auto["psnr"], auto["time_ratio"], best)
    return out


def run_priors(quick: bool = False, out: Path | None = None) -> dict:
    """Every scene of the configuration; ``priors.json`` and ``priors_speed_accuracy.png``
    in ``out``."""
    cfg = QUICK if quick else FULL
    t0 = time.perf_counter()
    cases = [run_scene(n, cfg) for n in (*cfg["scenes"], *cfg["others"])]
    judged = [c for c in cases if c["scene"] in cfg["scenes"]]
    gains = [c["gain_over_tv_oracle_db"] for c in judged]
    summary = {
        "mean_gain_over_tv_oracle_db": float(np.mean(gains)),
        "worst_gain_over_tv_oracle_db": float(np.min(gains)),
        "meets_goals": bool(np.mean(gains) >= GOAL_GAIN_DB and min(gains) >= -GOAL_WORST_DB),
        "chosen": {c["scene"]: c["auto"]["prior"] for c in cases},
        "best": {c["scene"]: c["best_prior"] for c in cases},
        "chosen_is_best": sum(c["auto"]["prior"] == c["best_prior"] for c in cases),
        "time_ratio_median": {p: float(np.median([c["priors"][p]["auto"]["time_ratio"]
                                                  for c in cases if p in c["priors"]]))
                              for p in AUTO_PRIORS},
        "auto_time_ratio_median": float(np.median([c["auto"]["time_ratio"] for c in cases]))}
    result = {"quick": quick, "setup": setup_record(cfg) | {
        "goals": {"mean_gain_db": GOAL_GAIN_DB, "worst_db": -GOAL_WORST_DB}},
        "cases": cases, "summary": summary, "wall_seconds": time.perf_counter() - t0}
    if out is not None:
        write_json(Path(out) / "priors.json", result)
        plot_priors(result, Path(out) / "priors_speed_accuracy.png")
    return result


def plot_priors(result: dict, path: Path) -> Path:
    """Speed against accuracy: PSNR over the TV oracle's against wall time over the TV
    default's, per scene, for each prior's automatic weight and the automatic prior."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 4.8))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    marks = {"tv": "o", "wavelet": "s", "dncnn": "^"}
    for p, m in marks.items():
        pts = [(c["priors"][p]["auto"]["time_ratio"],
                c["priors"][p]["auto"]["psnr"] - c["priors"]["tv"]["oracle"]["psnr"])
               for c in result["cases"] if "psnr" in c["priors"].get(p, {}).get("auto", {})]
        ax.plot([q[0] for q in pts], [q[1] for q in pts], m, ms=7, mfc="none",
                label=f"{p}, automatic weight")
    pts = [(c["auto"]["time_ratio"], c["gain_over_tv_oracle_db"]) for c in result["cases"]]
    ax.plot([q[0] for q in pts], [q[1] for q in pts], "k*", ms=10, label="automatic prior")
    for c in result["cases"]:
        ax.annotate(c["scene"], (c["auto"]["time_ratio"], c["gain_over_tv_oracle_db"]),
                    fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.axhline(0.0, color="k", lw=1, label="oracle TV weight (fixed, same cap)")
    ax.axhline(GOAL_GAIN_DB, color="g", ls="--", lw=1, label=f"goal: +{GOAL_GAIN_DB:g} dB mean")
    ax.set_xscale("log")
    ax.set_xlabel("wall time / the TV default's (automatic TV weight)")
    ax.set_ylabel("PSNR - oracle TV weight's PSNR (dB)")
    st = result["setup"]
    ax.set_title(f"priors on the scene suite: ADMM, max {st['iterations']} iterations, "
                 f"bin {st['coarse_bin']}", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def priors_table(result: dict) -> str:
    """Text table of :func:`run_priors`: one row per scene."""
    rows = []
    for c in result["cases"]:
        pr = c["priors"]
        cells = [c["scene"]]
        for p in AUTO_PRIORS:
            o, a = (pr.get(p, {}).get("oracle") or {}), pr.get(p, {}).get("auto", {})
            cells += [fmt(o.get("psnr")), fmt(a.get("psnr")), fmt(a.get("time_ratio"), ".1f")]
        cells += [c["auto"]["prior"], fmt(c["auto"]["psnr"]), fmt(c["auto"]["ssim"], ".3f"),
                  fmt(c["gain_over_tv_oracle_db"]), fmt(c["auto"]["time_ratio"], ".1f"),
                  c["best_prior"]]
        rows.append(cells)
    head = ["scene"] + [f"{p} {k}" for p in AUTO_PRIORS for k in ("oracle", "auto", "time x")] + [
        "chosen", "PSNR", "SSIM", "vs TV oracle", "time x", "best"]
    s = result["summary"]
    return "\n".join([
        "priors: oracle weight and automatic weight per prior (PSNR dB; time over the TV "
        "default's), and the automatic prior",
        format_table(head, rows),
        f"automatic prior vs oracle TV on the natural and textured scenes: mean "
        f"{fmt(s['mean_gain_over_tv_oracle_db'])} dB (goal >= +{GOAL_GAIN_DB:g}), worst "
        f"{fmt(s['worst_gain_over_tv_oracle_db'])} dB (goal >= -{GOAL_WORST_DB:g}); chosen = "
        f"best prior in {s['chosen_is_best']} of {len(result['cases'])}"])
