"""Stability: where each method breaks as noise grows and pixels are erased.

Two sweeps on one simulated scene (real PSF rendered at bin 2, reconstructed at bin
4, see :mod:`benchmarks.accuracy`): peak photons from high to very low (read
noise fixed), and the erased fraction of sensor pixels (Eq. 3.10) from 0 to 0.95 at
a fixed photon count. Every method runs a fixed iteration budget with its weight
(from the accuracy sweep, or :data:`instrument.benchmarks.DEFAULT_WEIGHTS`); with
erasures the TV weight is scaled by the measured fraction (1 - erased) so the
balance between the data term (a sum over measured pixels) and the prior is kept.

Failure criteria, reported as the first sweep point (from easy to hard) where:

* quality: PSNR < :data:`PSNR_BOUND_DB`, or PSNR more than :data:`PSNR_DROP_DB`
  below the method's own best in that sweep;
* convergence: :class:`~recon.errors.DivergenceError`, a non-finite estimate, or a
  final relative residual ``||A x - b|| / ||b||`` above
  ``max(RESIDUAL_FLOOR, RESIDUAL_FACTOR * ||noise|| / ||b||)``. Not applicable to the
  one-shot Wiener filter (``converged`` is None unless its estimate is non-finite):
  with the large lambda the sweep picks, its estimate is a scaled-down
  back-projection whose residual says nothing about stability.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import (
    DEFAULT_WEIGHTS,
    METHODS,
    fmt,
    format_table,
    load_sample,
    save_figure,
    scaled_problem,
    solve,
    write_json,
)
from recon.errors import DivergenceError
from recon.metrics import psnr, ssim
from recon.operators import PixelErasure
from recon.scenes import load_scene
from recon.simulate import simulate_measurement

#: Absolute quality bound. At the stability budget (300 iterations) the methods reach
#: 14-16 dB on this scene at high SNR (Wiener ~10 dB), so 12 dB is ~3 dB below the best.
PSNR_BOUND_DB = 12.0
PSNR_DROP_DB = 3.0
RESIDUAL_FLOOR = 0.05
RESIDUAL_FACTOR = 1.5
SCENE = "astronaut"
READ_NOISE_E = 2.0
ERASURE_PHOTONS = 5000.0

FULL = {"photons": [1e5, 1e4, 1e3, 300.0, 100.0, 30.0, 10.0],
        "erased": [0.0, 0.5, 0.8, 0.9, 0.95], "iterations": 300}
QUICK = {"photons": [1e4, 100.0], "erased": [0.0, 0.9], "iterations": 30}


def _condition(fine, coarse, scene, photons, erased, seed, iterations, weights):
    sim = simulate_measurement(fine, scene, bin_factor=2, photons=photons,
                               read_noise_e=READ_NOISE_E, seed=seed)
    mask = None
    if erased > 0:
        mask = PixelErasure.random(sim.b.shape, erased, seed=seed).mask
    op, b = scaled_problem(coarse, sim.b, mask)
    w = np.ones(sim.b.shape) if mask is None else mask
    noise_rel = float(np.linalg.norm(w * (sim.b - sim.b_clean)) / np.linalg.norm(w * sim.b))
    res_bound = max(RESIDUAL_FLOOR, RESIDUAL_FACTOR * noise_rel)
    truth = sim.truth[op.crop]
    lip = op.lipschitz()
    out = {"photons": photons, "erased": erased, "snr_db": sim.snr_db,
           "noise_relative": noise_rel, "residual_bound": res_bound, "methods": {}}
    for m in METHODS:
        weight = weights[m] if m == "wiener" else weights[m] * (1.0 - erased)
        rec = {"weight": weight}
        try:
            r = solve(m, op, b, iterations, weight, lipschitz=lip)
        except DivergenceError as exc:
            rec.update(psnr=None, ssim=None, residual=None, converged=False,
                       failure=f"diverged: {exc}")
            out["methods"][m] = rec
            continue
        est = r.x[op.crop]
        finite = bool(np.all(np.isfinite(est)))
        res = r.final_relative_residual
        if m == "wiener" and finite:
            # one-shot filter, nothing to converge; its residual reflects lambda and the
            # ignored crop, not stability
            converged, failure = None, None
        else:
            converged = finite and math.isfinite(res) and res <= res_bound
            failure = None if converged else (
                "non-finite estimate" if not finite else
                f"residual {res:.3f} > bound {res_bound:.3f}")
        rec.update(psnr=psnr(est, truth) if finite else None,
                   ssim=ssim(est, truth) if finite else None, residual=res,
                   converged=converged, failure=failure)
        out["methods"][m] = rec
    return out


def _failure_points(points: list[dict], key: str) -> dict:
    """First sweep value failing each criterion, per method."""
    res = {}
    for m in METHODS:
        vals = [(p[key], p["methods"][m]) for p in points]
        ps = [r["psnr"] for _, r in vals if r["psnr"] is not None]
        best = max(ps) if ps else None

        def first(pred, vals=vals):
            return next((v for v, r in vals if pred(r)), None)

        res[m] = {
            "best_psnr": best,
            "below_bound": first(lambda r: r["psnr"] is None or r["psnr"] < PSNR_BOUND_DB),
            "drop_from_best": first(lambda r, best=best: r["psnr"] is None or best is None
                                    or r["psnr"] < best - PSNR_DROP_DB),
            "not_converged": first(lambda r: r["converged"] is False),
        }
    return res


def run_stability(quick: bool = False, out: Path | None = None,
                  weights: dict[str, float] | None = None) -> dict:
    """Noise and erasure sweeps with failure points per method.

    Parameters
    ----------
    quick : bool
        Two points per sweep, short runs.
    out : Path, optional
        Directory for ``stability.json`` and ``stability.png``.
    weights : dict, optional
        Per-method weights (e.g. ``run_accuracy(...)["chosen_weights"]``); default
        :data:`instrument.benchmarks.DEFAULT_WEIGHTS`.

    Returns
    -------
    dict
        ``noise`` and ``erasure`` (lists of points with per-method ``psnr``,
        ``ssim``, ``residual``, ``converged``), ``failures`` (per sweep and method:
        ``below_bound``, ``drop_from_best``, ``not_converged``: the first failing
        sweep value or None), ``criteria``.
    """
    cfg = QUICK if quick else FULL
    w = dict(DEFAULT_WEIGHTS, **(weights or {}))
    t_start = time.perf_counter()
    fine, coarse = load_sample(2).psf, load_sample(4).psf
    scene = load_scene(SCENE, fine.shape)
    noise = [_condition(fine, coarse, scene, p, 0.0, 10, cfg["iterations"], w)
             for p in cfg["photons"]]
    erasure = [_condition(fine, coarse, scene, ERASURE_PHOTONS, f, 20, cfg["iterations"], w)
               for f in cfg["erased"]]
    result = {
        "quick": quick,
        "scene": SCENE,
        "iterations": cfg["iterations"],
        "weights": w,
        "read_noise_e": READ_NOISE_E,
        "erasure_photons": ERASURE_PHOTONS,
        "criteria": {"psnr_bound_db": PSNR_BOUND_DB, "psnr_drop_db": PSNR_DROP_DB,
                     "residual_floor": RESIDUAL_FLOOR, "residual_factor": RESIDUAL_FACTOR,
                     "tv_scaled_by_measured_fraction": True},
        "noise": noise,
        "erasure": erasure,
        "failures": {"noise": _failure_points(noise, "photons"),
                     "erasure": _failure_points(erasure, "erased")},
        "wall_seconds": time.perf_counter() - t_start,
    }
    if out is not None:
        out = Path(out)
        write_json(out / "stability.json", result)
        plot_stability(result, out / "stability.png")
    return result


def stability_table(result: dict) -> str:
    """Text table: PSNR per sweep point and the failure points per method."""
    c = result["criteria"]
    lines = [f"stability: scene '{result['scene']}', {result['iterations']} iterations; "
             f"fail = PSNR < {c['psnr_bound_db']:g} dB | > {c['psnr_drop_db']:g} dB below own "
             f"best | no convergence (divergence or residual > max({c['residual_floor']:g}, "
             f"{c['residual_factor']:g} x noise))"]
    for sweep, key, label in (("noise", "photons", "photons"),
                              ("erasure", "erased", "erased")):
        pts = result[sweep]
        headers = ["method"] + [f"{p[key]:g}" for p in pts] + ["<bound", "-3dB", "no conv"]
        rows = []
        for m in METHODS:
            f = result["failures"][sweep][m]
            cells = []
            for p in pts:
                r = p["methods"][m]
                cells.append(fmt(r["psnr"], ".1f") + ("*" if r["converged"] is False else ""))
            rows.append([m] + cells + [fmt(f["below_bound"], "g"), fmt(f["drop_from_best"], "g"),
                                       fmt(f["not_converged"], "g")])
        snr = " ".join(f"{p['snr_db']:.0f}" for p in pts)
        lines.append(f"PSNR (dB) vs {label} (SNR dB: {snr}); * = not converged")
        lines.append(format_table(headers, rows))
    return "\n".join(lines)


def plot_stability(result: dict, path: Path) -> Path:
    """PSNR against peak photons (log, decreasing) and against erased fraction."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.5, 3.8))
    ax1, ax2 = fig.subplots(1, 2)
    for ax, sweep, key in ((ax1, "noise", "photons"), (ax2, "erasure", "erased")):
        pts = result[sweep]
        xs = [p[key] for p in pts]
        for m in METHODS:
            ys = [np.nan if p["methods"][m]["psnr"] is None else p["methods"][m]["psnr"]
                  for p in pts]
            line, = ax.plot(xs, ys, marker="o", ms=4, label=m)
            bad = [(x, y) for x, y, p in zip(xs, ys, pts, strict=True)
                   if p["methods"][m]["converged"] is False and np.isfinite(y)]
            if bad:
                ax.plot(*zip(*bad, strict=True), "x", color=line.get_color(), ms=9)
        ax.axhline(result["criteria"]["psnr_bound_db"], color="k", ls="--", lw=0.8)
        ax.set_ylabel("PSNR (dB)")
        ax.grid(True, alpha=0.3)
    ax1.set_xscale("log")
    ax1.invert_xaxis()
    ax1.set_xlabel(f"peak photons (read noise {result['read_noise_e']:.0f} e-)")
    ax2.set_xlabel(f"erased fraction ({result['erasure_photons']:.0f} photons)")
    ax1.legend(fontsize=8, title="x = not converged", title_fontsize=7)
    fig.suptitle(f"stability, scene '{result['scene']}', {result['iterations']} iterations")
    fig.tight_layout()
    return save_figure(fig, path)
