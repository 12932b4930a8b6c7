"""Failure maps: PSNR of every method over photon count x scene density and photon
count x erased fraction, with the contour where it fails and the auto choice on top.

Scenes (:mod:`benchmarks.auto_scenes`, real PSF rendered at bin 4 and
reconstructed at bin 8 for speed: model mismatch, Poisson + 3 e- read noise): sparse
beads at growing density up to a dense natural photograph (camera), and the camera
photograph with a growing fraction of erased sensor pixels (Eq. 3.10). Methods at
their fixed default weights (:data:`instrument.benchmarks.DEFAULT_WEIGHTS`, ``iterations``
each) and ``method="auto"`` (:func:`recon.auto.solve_channel`).

A cell fails when PSNR < :data:`BOUND_DB` or the solve stops converging (diverged,
non-finite, or a final relative residual above :data:`RESIDUAL_BOUND`). One figure
per map: a panel per method, PSNR as colour, the failure contour in black, the
failed cells crossed, auto's own failure contour dashed on every panel, and the
TV weight auto chose written in its panel's cells.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import DEFAULT_WEIGHTS, METHODS, fmt, save_figure, solve, write_json
from recon.auto import ChannelProblem, solve_channel
from recon.errors import DivergenceError, ReconInputError
from recon.metrics import psnr
from recon.options import ReconOptions

from .auto_scenes import render_case

#: PSNR below this fails (dB, gain-fitted, bin 8).
BOUND_DB = 20.0
#: Final relative residual above this: not converged.
RESIDUAL_BOUND = 0.2

FULL = {"photons": [100.0, 300.0, 1000.0, 3000.0, 10000.0, 30000.0],
        "densities": [0.0005, 0.002, 0.01, 0.05, "photo:camera"],
        "erased": [0.0, 0.5, 0.8, 0.9, 0.95], "iterations": 200, "coarse_bin": 8}
QUICK = {"photons": [300.0, 30000.0], "densities": [0.002, "photo:camera"],
         "erased": [0.0, 0.9], "iterations": 30, "coarse_bin": 8}


def _cell(case, weights_mask, methods, iterations) -> dict:
    op, b = case.op, case.b
    if weights_mask is not None:
        op = op.with_weights(weights_mask)
        b = np.ascontiguousarray(case.b * weights_mask, np.float32)
    out = {}
    for m in methods:
        t0 = time.perf_counter()
        try:
            if m == "auto":
                scale = float(np.max(np.abs(case.raw_e)))
                res, rec = solve_channel(
                    ChannelProblem(op, b, case.raw_e, scale),
                    ReconOptions.from_defaults(iterations=iterations, tv="auto", l1=0.0))
                extra = {"tv": rec["tv"], "chose": rec["method"]["method"]}
            else:
                res, extra = solve(m, op, b, iterations, DEFAULT_WEIGHTS[m]), {}
        except (DivergenceError, ReconInputError) as exc:
            out[m] = {"psnr": None, "converged": False, "error": str(exc)[:200]}
            continue
        x = res.x[op.crop]
        finite = bool(np.all(np.isfinite(x)))
        converged = finite and (m == "wiener" or res.final_relative_residual < RESIDUAL_BOUND)
        p = psnr(x, case.truth) if finite else None
        out[m] = {"psnr": p, "converged": converged,
                  "residual": res.final_relative_residual,
                  "seconds": time.perf_counter() - t0,
                  "fails": (not converged) or p is None or p < BOUND_DB, **extra}
    return out


def _density_label(d) -> str:
    return "photo" if isinstance(d, str) else f"beads {d:g}"


def run_failure_maps(quick: bool = False, out: Path | None = None) -> dict:
    """Both 2D maps; returns ``{"density": ..., "erasure": ..., "setup": ...}``, each
    map with ``rows`` (photons), ``cols`` and ``cells[i][j][method]`` records."""
    cfg = QUICK if quick else FULL
    methods = [*METHODS, "auto"]
    t0 = time.perf_counter()
    dens_cells, dens_cols = [], []
    for d in cfg["densities"]:
        dens_cols.append(_density_label(d))
    for ph in cfg["photons"]:
        row = []
        for d in cfg["densities"]:
            kind, density = (d, 0.002) if isinstance(d, str) else ("beads", d)
            case = render_case(kind, ph, coarse_bin=cfg["coarse_bin"], density=density)
            cell = _cell(case, None, methods, cfg["iterations"])
            cell["fill_fraction"] = float(np.mean(case.truth > 0.1 * case.truth.max()))
            row.append(cell)
        dens_cells.append(row)
    er_cells = []
    rng = np.random.default_rng(1)
    for ph in cfg["photons"]:
        case = render_case("photo:camera", ph, coarse_bin=cfg["coarse_bin"])
        row = []
        for e in cfg["erased"]:
            mask = None if e == 0 else (rng.random(case.op.sensor_shape) >= e).astype(
                np.float32)
            row.append(_cell(case, mask, methods, cfg["iterations"]))
        er_cells.append(row)
    result = {"quick": quick,
              "setup": {"bound_db": BOUND_DB, "residual_bound": RESIDUAL_BOUND,
                        "iterations": cfg["iterations"], "coarse_bin": cfg["coarse_bin"],
                        "weights": {m: DEFAULT_WEIGHTS[m] for m in METHODS}},
              "density": {"rows": cfg["photons"], "cols": dens_cols, "cells": dens_cells},
              "erasure": {"rows": cfg["photons"], "cols": [f"{e:g}" for e in cfg["erased"]],
                          "cells": er_cells},
              "methods": methods, "wall_seconds": time.perf_counter() - t0}
    if out is not None:
        out = Path(out)
        write_json(out / "failure_maps.json", result)
        plot_map(result, "density", out / "failure_map_density.png",
                 "scene (sparse beads: fraction of pixels holding a bead; photo: dense)")
        plot_map(result, "erasure", out / "failure_map_erasure.png",
                 "erased fraction of sensor pixels (camera scene)")
    return result


def _grid(m: dict, method: str, key: str = "psnr") -> np.ndarray:
    return np.array([[np.nan if c[method].get(key) is None else float(c[method][key])
                      for c in row] for row in m["cells"]])


def plot_map(result: dict, name: str, path: Path, xlabel: str) -> Path:
    """One figure for one map: a panel per method (see the module docstring)."""
    from matplotlib.figure import Figure

    m, methods = result[name], result["methods"]
    bound = result["setup"]["bound_db"]
    fig = Figure(figsize=(3.3 * len(methods), 3.6))
    axes = fig.subplots(1, len(methods), squeeze=False, gridspec_kw={"wspace": 0.35})[0]
    all_p = np.concatenate([_grid(m, k).ravel() for k in methods])
    vmin, vmax = np.nanmin(all_p), np.nanmax(all_p)
    auto_fail = np.array([[c["auto"].get("fails", True) for c in row] for row in m["cells"]],
                         float)
    im = None
    for ax, k in zip(axes, methods, strict=True):
        p = _grid(m, k)
        im = ax.imshow(p, origin="lower", cmap="viridis", vmin=vmin, vmax=vmax, aspect="auto")
        fails = np.array([[c[k].get("fails", True) for c in row] for row in m["cells"]], float)
        if 0 < fails.sum() < fails.size:
            ax.contour(fails, levels=[0.5], colors="black", linewidths=2)
        if 0 < auto_fail.sum() < auto_fail.size:
            ax.contour(auto_fail, levels=[0.5], colors="white", linestyles="dashed",
                       linewidths=1.5)
        for i, row in enumerate(m["cells"]):
            for j, c in enumerate(row):
                if c[k].get("fails", True):
                    ax.plot(j, i, "x", color="red", ms=8, mew=2)
                if k == "auto" and c[k].get("tv") is not None:
                    tv = c[k]["tv"]
                    label = "0" if tv == 0 else f"{math.log10(tv):.1f}"
                    ax.text(j, i, label, ha="center", va="center", fontsize=7, color="white")
        ax.set_xticks(range(len(m["cols"])), m["cols"], rotation=45, ha="right", fontsize=7)
        ax.set_yticks(range(len(m["rows"])), [f"{r:g}" for r in m["rows"]], fontsize=7)
        ax.set_title(k + (" (log10 TV chosen)" if k == "auto" else ""), fontsize=9)
        ax.set_xlabel(xlabel if k == methods[0] else "", fontsize=8)
    axes[0].set_ylabel("peak photo-electrons")
    fig.colorbar(im, ax=list(axes), shrink=0.8, label="PSNR (dB)")
    fig.suptitle(f"{name}: failure (x, black contour) = PSNR < {bound:g} dB or not "
                 "converged; auto's failure contour dashed white", fontsize=10)
    return save_figure(fig, path)


def failure_maps_table(result: dict) -> str:
    """Per map and method: the failing cells (photons, column)."""
    lines = [f"failure maps (bin {result['setup']['coarse_bin']}, "
             f"{result['setup']['iterations']} iterations, fail = PSNR < "
             f"{result['setup']['bound_db']:g} dB or not converged)"]
    for name in ("density", "erasure"):
        m = result[name]
        for k in result["methods"]:
            failed = [f"{m['rows'][i]:g}/{m['cols'][j]}" for i, row in enumerate(m["cells"])
                      for j, c in enumerate(row) if c[k].get("fails", True)]
            best = np.nanmax(_grid(m, k))
            lines.append(f"{name} {k}: best {fmt(best)} dB; fails at {len(failed)}/"
                         f"{sum(len(r) for r in m['cells'])}: {', '.join(failed) or 'none'}")
    return "\n".join(lines)
