"""The automatic 3D weight against the oracle weight, and where objects land.

Run with ``diffuserlab benchmark recon --only volume_auto [--quick] [--out DIR]``.

Scenes (:mod:`instrument.benchmarks.volume_auto_scenes`): one bead or one textured disc per
plane through the real tutorial PSF scaled per depth, the far planes' sources 3x, 10x
or 30x dimmer than the nearest (and the PSF's own light model dims them further),
rendered on a 2x finer grid with Poisson and read noise at 300, 3000 and 30000 peak
photo-electrons, reconstructed at bin 8 (150 x 200, 6 planes): model mismatch
throughout, never the inverse crime.

Per case: 3D ADMM at every weight of a TV grid (the oracle is the best by volume PSNR
after one gain fit, known to within the grid's factor of ~3) and the automatic choice
exactly as :func:`recon.reconstruct` runs it for a :class:`recon.PsfStack`
(:func:`recon.auto.volume.auto_volume`:
noise model fitted to the frame, the held-out path, the watched final solve, every
plane kept). Reported: auto's shortfall against the oracle (mean and worst; goals
:data:`benchmarks.auto.GOAL_MEAN_DB`, ``GOAL_WORST_DB``: the 2D goals), and for
every object whether it sits
at its depth (+-1 plane) and its brightness (its light within +-1 plane of its depth
over the truth's, relative to the nearest object's).

:func:`rule_study` re-measures the path's choice rule for 3D (the 2D rule's bound was
measured on 2D scenes only): it records the held-out path once per case, solves at
every path weight, and applies each candidate rule to the same path.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, machine_record, write_json
from instrument.benchmarks.volume_auto_scenes import VolumeCase, render_volume_case
from recon.auto.noise import estimate_noise
from recon.auto.volume import VOLUME_RULES, auto_volume
from recon.auto.weight import PathRule, admm_auto
from recon.errors import DivergenceError
from recon.volume import VolumeAdmmPlan, admm3d, fista3d

from .auto import (
    GOAL_MEAN_DB,
    GOAL_TIME_RATIO,
    GOAL_WORST_DB,
    cost_in_turn,
    cost_record,
    cost_summary,
    goal_summary,
    setup_record,
    timed,
)
from .volume_accuracy import volume_psnr

FULL = {"scenes": (("beads", 3.0), ("beads", 30.0), ("extended", 3.0), ("extended", 10.0),
                   ("extended", 30.0), ("beads", 10.0)),
        "photons": (300.0, 3000.0, 30000.0), "n_planes": 6, "coarse_bin": 8,
        "iterations": 200, "timing_repeats": 4,
        "grid": (0.0, 1e-7, 3e-7, 1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3)}
QUICK = {"scenes": (("beads", 10.0),), "photons": (3000.0,), "n_planes": 4, "coarse_bin": 8,
         "iterations": 40, "grid": (0.0, 1e-6, 1e-5)}
#: The four cases the docs quote (``python -m benchmarks.volume_auto --subset``):
#: beads with far planes 10x dimmer at 3000 e- and 30x dimmer at 300 e-, textured discs
#: 10x dimmer at 3000 e- and 3x dimmer at 30000 e-; FULL's grid and iterations.
SUBSET = FULL | {"cases": (("beads", 10.0, 3000.0), ("extended", 10.0, 3000.0),
                           ("beads", 30.0, 300.0), ("extended", 3.0, 30000.0))}


def object_metrics(case: VolumeCase, volume: np.ndarray) -> list[dict]:
    """Where each object of ``case`` lands in ``volume`` and how bright it is.

    Parameters
    ----------
    case : VolumeCase
    volume : ndarray, (n_z, rows, cols)
        The sensor field of view of a reconstruction.

    Returns
    -------
    list of dict
        Per object, within its footprint (its disc widened by 2 px): ``plane``
        (true), ``depth_plane`` (the light-weighted mean plane: an extended object's
        light spreads over planes whose PSFs barely differ, where the plane of most
        light is a coin toss), ``peak_plane`` (that plane of most light),
        ``within_one_plane`` (``depth_plane`` within 1 of the truth), ``brightness``
        (light within +-1 plane of the true plane, over the truth's, divided by the
        same ratio of the nearest object: 1 is right).
    """
    v = np.asarray(volume, np.float64)
    yy, xx = np.mgrid[0:v.shape[1], 0:v.shape[2]]
    out, ratios = [], []
    for o in case.objects:
        k = o["plane"]
        mask = np.hypot(yy - o["centre"][0], xx - o["centre"][1]) <= o["radius_px"] + 2
        e = np.maximum(v[:, mask].sum(axis=1), 0)
        t = float(case.truth[k][mask].sum())
        ratios.append(float(e[max(0, k - 1):k + 2].sum()) / t if t > 0 else 0.0)
        depth = float(np.dot(e, np.arange(e.size)) / e.sum()) if e.sum() > 0 else -1.0
        out.append({"plane": k, "depth_plane": depth,
                    "peak_plane": int(np.argmax(e)) if e.sum() > 0 else -1,
                    "within_one_plane": bool(depth >= 0 and abs(depth - k) <= 1)})
    ref = ratios[0] if ratios[0] > 0 else 1.0
    for o, r in zip(out, ratios, strict=True):
        o["brightness"] = r / ref
    return out


def _fov(case: VolumeCase, x: np.ndarray) -> np.ndarray:
    return x[(slice(None), *case.op.crop)]


def _fixed(case: VolumeCase, tv: float, iterations: int) -> dict:
    try:
        r, dt, cpu = timed(lambda: admm3d(case.op, case.b, iterations=iterations, tv=tv))
    except DivergenceError as exc:
        return {"tv": tv, "psnr": None, "diverged": str(exc)[:200]}
    return {"tv": tv, "psnr": volume_psnr(_fov(case, r.x), case.truth), "seconds": dt,
            "cpu_seconds": cpu}


def _noise(case: VolumeCase):
    return estimate_noise(case.raw_e).scaled(float(np.abs(case.raw_e).max()))


def run_case(kind: str, dim: float, photons: float, cfg: dict, seed: int = 0) -> dict:
    """One scene at one photon count: the oracle grid and auto."""
    case = render_volume_case(kind, photons, n_planes=cfg["n_planes"], dim=dim,
                              coarse_bin=cfg["coarse_bin"], seed=seed)
    it = cfg["iterations"]
    grid = [_fixed(case, tv, it) for tv in cfg["grid"]]
    ok = [g for g in grid if g["psnr"] is not None]
    oracle = max(ok, key=lambda g: g["psnr"]) if ok else None
    auto = _auto(case, it)
    cost = cost_in_turn(
        auto, grid, cfg.get("timing_repeats", 1),
        lambda: _fixed(case, oracle["tv"] if oracle else 0.0, it), lambda: _auto(case, it))
    return {"scene": kind, "dim": dim, "photons": photons, "snr_db": case.info["snr_db"],
            "grid": grid, "oracle": oracle, "auto": auto, **cost_record(cost),
            "auto_shortfall_db": (oracle["psnr"] - auto["psnr"]
                                  if oracle and auto.get("psnr") is not None else None)}


def _auto(case: VolumeCase, iterations: int) -> dict:
    """The default on one case, exactly as :func:`recon.reconstruct` runs it."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res, rec = auto_volume("admm", case.op, case.b, noise=_noise(case),
                               iterations=iterations, plan_of=VolumeAdmmPlan.of,
                               fista=fista3d)
    except DivergenceError as exc:
        res, rec = None, {"error": str(exc)[:200]}
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    if res is None:
        return {"psnr": None, "error": rec["error"], "seconds": dt, "cpu_seconds": cpu}
    vol = _fov(case, res.x)
    return {"psnr": volume_psnr(vol, case.truth), "tv": rec["weight"],
            "iterations_used": int(res.params["iterations_used"]),
            "planes_kept": rec["planes_kept"], "planes_without_evidence": rec["drop"]["planes"],
            "objects": object_metrics(case, vol), "seconds": dt, "cpu_seconds": cpu}


def run_volume_auto(quick: bool = False, out: Path | None = None, *,
                    subset: bool = False) -> dict:
    """Auto vs the oracle over the 3D scene x photon grid.

    Parameters
    ----------
    quick : bool
        The small :data:`QUICK` configuration (tests).
    out : Path, optional
        Folder for ``volume_auto.json`` (``volume_auto_subset.json`` with ``subset``).
    subset : bool
        Only the four :data:`SUBSET` cases the docs quote.

    Returns
    -------
    dict
        ``cases`` (:func:`run_case` records), ``summary`` (mean and worst shortfall,
        the default's time over one fixed-weight solve's (median and max, goal
        :data:`benchmarks.auto.GOAL_TIME_RATIO`), objects off their depth,
        failures), ``setup``.
    """
    cfg = QUICK if quick else SUBSET if subset else FULL
    t0 = time.perf_counter()
    todo = cfg.get("cases") or [(kind, dim, ph) for kind, dim in cfg["scenes"]
                                for ph in cfg["photons"]]
    cases = [run_case(kind, dim, ph, cfg) for kind, dim, ph in todo]
    short = [c["auto_shortfall_db"] for c in cases if c["auto_shortfall_db"] is not None]
    objs = [o for c in cases for o in c["auto"].get("objects", [])]
    failures = [f"{c['scene']}/{c['dim']:g}@{c['photons']:g}" for c in cases
                if c["auto"].get("psnr") is None]
    summary = goal_summary(short, failures) | {
        "objects": len(objs), "objects_off_depth": sum(not o["within_one_plane"] for o in objs),
        **cost_summary(cases)}
    result = {"quick": quick, "subset": subset, "machine": machine_record(),
              "setup": setup_record(cfg) | {
                  "rule": {k: vars(r) for k, r in VOLUME_RULES.items()}},
              "cases": cases, "summary": summary, "wall_seconds": time.perf_counter() - t0}
    if out is not None:
        name = "volume_auto_subset.json" if subset else "volume_auto.json"
        write_json(Path(out) / name, result)
    return result


def volume_auto_table(result: dict) -> str:
    """Text table of :func:`run_volume_auto`: one row per case."""
    rows = []
    for c in result["cases"]:
        a, o = c["auto"], c["oracle"] or {}
        objs = a.get("objects", [])
        rows.append([c["scene"], f"{c['dim']:g}x", f"{c['photons']:g}", fmt(o.get("psnr")),
                     fmt(o.get("tv"), "g"), fmt(a.get("psnr")), fmt(a.get("tv"), ".2g"),
                     fmt(c["auto_shortfall_db"]), fmt(c.get("auto_cost_ratio"), ".1f"),
                     fmt(c.get("auto_cost_ratio_cpu"), ".1f"),
                     f"{sum(x['within_one_plane'] for x in objs)}/{len(objs)}",
                     " ".join(f"{x['brightness']:.2f}" for x in objs)])
    s, st = result["summary"], result["setup"]
    return "\n".join([
        f"automatic 3D TV weight vs oracle (best of {st['grid']}): 3D ADMM, "
        f"{st['iterations']} iterations, {st['n_planes']} planes at bin {st['coarse_bin']}",
        format_table(["scene", "dim", "photons", "oracle", "w", "auto", "w", "short",
                      "time x", "cpu x", "at depth", "brightness (nearest = 1)"], rows),
        f"auto below oracle: mean {fmt(s['mean_shortfall_db'])} dB (goal {GOAL_MEAN_DB}), "
        f"worst {fmt(s['worst_shortfall_db'])} dB (goal {GOAL_WORST_DB}); objects off their "
        f"depth (> 1 plane): {s['objects_off_depth']} of {s['objects']}; failures: "
        f"{', '.join(s['failures']) or 'none'}",
        f"time over one fixed-weight solve (runs in turn, median of the pairs' ratios): "
        f"median {fmt(s.get('cost_ratio_median'), '.1f')}x, max "
        f"{fmt(s.get('cost_ratio_max'), '.1f')}x (goal {GOAL_TIME_RATIO:g}x); CPU time median "
        f"{fmt(s.get('cost_ratio_cpu_median'), '.1f')}x, max "
        f"{fmt(s.get('cost_ratio_cpu_max'), '.1f')}x"])


def _apply_rule(path: list, se_rule: float, bound: float) -> float:
    """The weight a rule chooses on a recorded held-out path (as admm_auto does)."""
    best = min(range(len(path)), key=lambda i: path[i]["holdout_error"])
    lim = path[best]["holdout_error"] + se_rule * path[best]["standard_error"]
    k = next(i for i, p in enumerate(path) if p["holdout_error"] <= lim)
    return min(path[k]["weight"], bound * path[best]["weight"])


def rule_study(cfg: dict | None = None, rules=((1.0, math.inf), (1.0, 2.0), (1.0, 4.0),
                                               (1.0, 8.0), (0.5, math.inf), (0.5, 8.0),
                                               (1.5, math.inf), (0.0, 1.0)),
               span: PathRule | None = None) -> dict:
    """The 3D path's choice rules on the same held-out paths.

    Per case: the held-out path over ``span`` (default
    :data:`recon.auto.volume.VOLUME_RULES` ``"tv"``; path only), 3D ADMM at every path
    weight (``cfg["iterations"]``), and for each rule
    ``(se_rule, max_above_minimum)`` the PSNR at the path weight nearest its choice
    against the best path weight.

    Returns
    -------
    dict
        ``cases`` (path weights, held-out errors, PSNRs), ``rules`` (per rule: mean
        and worst shortfall in dB).
    """
    cfg = cfg or FULL
    span = span or VOLUME_RULES["tv"]
    out = []
    for kind, dim in cfg["scenes"]:
        for ph in cfg["photons"]:
            case = render_volume_case(kind, ph, n_planes=cfg["n_planes"], dim=dim,
                                      coarse_bin=cfg["coarse_bin"])
            noise = _noise(case)
            _, choice = admm_auto(case.op, case.b, iterations=cfg["iterations"],
                                  noise_energy=noise.energy(case.b), path_only=True,
                                  plan_of=VolumeAdmmPlan.of, rule=span)
            path = choice.path
            psnrs = [_fixed(case, p["weight"], cfg["iterations"])["psnr"] for p in path]
            out.append({"scene": kind, "dim": dim, "photons": ph, "path": path,
                        "psnr": psnrs})
    table = {}
    for se, bound in rules:
        short = []
        for c in out:
            w = _apply_rule(c["path"], se, bound)
            i = min(range(len(c["path"])),
                    key=lambda j: abs(math.log(c["path"][j]["weight"] / w)))
            ok = [p for p in c["psnr"] if p is not None]
            short.append(max(ok) - c["psnr"][i] if c["psnr"][i] is not None else math.inf)
        table[f"se {se:g}, bound {bound:g}"] = {"mean_db": float(np.mean(short)),
                                                "worst_db": float(np.max(short))}
    return {"cases": out, "rules": table, "span": vars(span)}


def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.volume_auto [--subset] [--quick] [--out DIR]``: run
    the benchmark, print its table and write its JSON to ``DIR``."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m benchmarks.volume_auto",
                                     description=main.__doc__)
    parser.add_argument("--subset", action="store_true",
                        help="only the four cases the docs quote (about 12 minutes)")
    parser.add_argument("--quick", action="store_true", help="the small test configuration")
    parser.add_argument("--out", type=Path, default=Path("out/benchmarks"),
                        help="folder for the JSON (default: out/benchmarks)")
    args = parser.parse_args(argv)
    result = run_volume_auto(args.quick, args.out, subset=args.subset)
    print(volume_auto_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
