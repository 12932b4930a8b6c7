"""The 3D failure map: bead localisation over bead count x photon count.

Beads ray-traced at random 3D positions on the virtual bench's diffuser
(:func:`benchmarks.volume_scenes.bead_scene`: off-axis effects, noise; the
reconstruction uses on-axis PSFs, so model mismatch), reconstructed by 3D FISTA and
3D ADMM at ``recon3d``'s former fixed TV (:data:`recon.volume.DEFAULT_TV`) and by
the automatic weight (:func:`recon.auto.volume.auto_volume`, every plane kept). A cell fails
when a bead is missed, a spurious one is found, or a bead lands more than one plane
off (:func:`benchmarks.volume_accuracy.bead_metrics`), or the solve diverges.
One figure: a panel per method, the fraction of beads found within one plane as
colour, failed cells crossed, auto's failed cells outlined on every panel.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import save_figure, write_json
from recon.auto.noise import estimate_noise
from recon.auto.volume import auto_volume
from recon.errors import DivergenceError
from recon.volume import DEFAULT_TV, VolumeAdmmPlan, fista3d

from .volume_accuracy import METHODS3D, bead_metrics
from .volume_scenes import bead_scene, make_bench

FULL = {"beads": [2, 6, 12, 24], "photons": [300.0, 3000.0, 30000.0], "iterations": 100,
        "bin_factor": 4, "n_planes": 8}
QUICK = {"beads": [3], "photons": [3000.0], "iterations": 20, "bin_factor": 4, "n_planes": 4}


def _solve(method: str, bench, scene, iterations: int):
    op = bench.op
    if method == "auto":
        r, rec = auto_volume("admm", op, scene.b, noise=estimate_noise(scene.b),
                             iterations=iterations, plan_of=VolumeAdmmPlan.of,
                             fista=fista3d)
        return r, {"tv": rec["weight"], "planes_kept": rec["planes_kept"],
                   "planes_without_evidence": rec["drop"]["planes"]}
    tv = DEFAULT_TV["admm" if method == "admm3d" else "fista"]
    return METHODS3D[method](op, scene.b, iterations=iterations, tv=tv, l1=0.0), {"tv": tv}


def run_failure_map_3d(quick: bool = False, out: Path | None = None) -> dict:
    """Bead count x photons for fista3d, admm3d and auto; ``cells[i][j][method]``."""
    cfg = QUICK if quick else FULL
    t0 = time.perf_counter()
    bench = make_bench(bin_factor=cfg["bin_factor"], n_planes=cfg["n_planes"])
    methods = [*METHODS3D, "auto"]
    cells = []
    for ph in cfg["photons"]:
        row = []
        for n in cfg["beads"]:
            scene = bead_scene(bench, n, photons=ph, seed=n)
            cell = {}
            for m in methods:
                try:
                    r, extra = _solve(m, bench, scene, cfg["iterations"])
                except DivergenceError as exc:
                    cell[m] = {"fails": True, "diverged": str(exc)[:200], "found": 0.0}
                    continue
                bm = bead_metrics(bench, scene, r.x[(slice(None), *bench.op.crop)])
                found = (n - bm["missed"]) / n
                ok = bm["within_one_plane"] and bm["spurious"] == 0
                cell[m] = {"fails": not ok, "found": found, "missed": bm["missed"],
                           "spurious": bm["spurious"],
                           "axial_planes_max_abs": bm["axial_planes_max_abs"], **extra}
            row.append(cell)
        cells.append(row)
    result = {"quick": quick, "setup": {k: v for k, v in cfg.items()}, "methods": methods,
              "rows": cfg["photons"], "cols": cfg["beads"], "cells": cells,
              "wall_seconds": time.perf_counter() - t0}
    if out is not None:
        out = Path(out)
        write_json(out / "failure_map_3d.json", result)
        plot_map_3d(result, out / "failure_map_3d.png")
    return result


def plot_map_3d(result: dict, path: Path) -> Path:
    """The figure described in the module docstring."""
    from matplotlib.figure import Figure

    methods = result["methods"]
    fig = Figure(figsize=(3.4 * len(methods), 3.4))
    axes = fig.subplots(1, len(methods), squeeze=False, gridspec_kw={"wspace": 0.35})[0]
    auto_fail = np.array([[c["auto"]["fails"] for c in row] for row in result["cells"]], float)
    im = None
    for ax, m in zip(axes, methods, strict=True):
        found = np.array([[c[m]["found"] for c in row] for row in result["cells"]], float)
        im = ax.imshow(found, origin="lower", cmap="viridis", vmin=0, vmax=1, aspect="auto")
        for i, row in enumerate(result["cells"]):
            for j, c in enumerate(row):
                if c[m]["fails"]:
                    ax.plot(j, i, "x", color="red", ms=9, mew=2)
                if auto_fail[i, j]:
                    ax.add_patch(_box(j, i))
                if m == "auto" and "planes_without_evidence" in c[m]:
                    ax.text(j, i + 0.3, f"{len(c[m]['planes_without_evidence'])} ne",
                            ha="center", fontsize=7, color="white")
        ax.set_xticks(range(len(result["cols"])), [str(v) for v in result["cols"]])
        ax.set_yticks(range(len(result["rows"])), [f"{v:g}" for v in result["rows"]])
        ax.set_xlabel("beads in the volume")
        ax.set_title(m, fontsize=9)
    axes[0].set_ylabel("peak photo-electrons")
    fig.colorbar(im, ax=list(axes), shrink=0.8, label="fraction of beads found")
    fig.suptitle("3D beads: failure (x) = a bead missed, spurious or > 1 plane off; auto's "
                 "failed cells boxed; auto: planes without evidence of signal (ne)",
                 fontsize=9)
    return save_figure(fig, path)


def _box(j, i):
    from matplotlib.patches import Rectangle

    return Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, edgecolor="white", lw=1.5,
                     linestyle="--")


def failure_map_3d_table(result: dict) -> str:
    """Per method: the failing cells (photons / beads)."""
    lines = [f"3D failure map (bin {result['setup']['bin_factor']}, "
             f"{result['setup']['n_planes']} planes, {result['setup']['iterations']} "
             "iterations; fail = a bead missed, spurious or > 1 plane off)"]
    for m in result["methods"]:
        failed = [f"{result['rows'][i]:g}/{result['cols'][j]}"
                  for i, row in enumerate(result["cells"]) for j, c in enumerate(row)
                  if c[m]["fails"]]
        lines.append(f"{m}: fails at {len(failed)}/"
                     f"{sum(len(r) for r in result['cells'])}: {', '.join(failed) or 'none'}")
    return "\n".join(lines)
