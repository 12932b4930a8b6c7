"""Figures of the 3D accuracy benchmark (:mod:`benchmarks.volume_accuracy`).

:func:`plot_volume_panel` draws the 3D methods' tilted-target PSNR against seconds
on one axes (the 3D panel of the speed-vs-accuracy chart,
``accuracy_psnr_vs_seconds.png``); :func:`plot_volume_accuracy` writes the
benchmark's own figure. Matplotlib's object API with the Agg canvas (no pyplot).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from instrument.benchmarks import log_x_axis, save_figure


def _xy(points: list[dict], key: str) -> tuple[list[float], list[float]]:
    pts = [p for p in points if p.get(key) is not None and p.get("seconds") is not None]
    return [max(p["seconds"], 1e-5) for p in pts], [p[key] for p in pts]


def plot_volume_panel(ax, result: dict) -> None:
    """Tilted-target PSNR (dB) vs solver seconds for every 3D method, with baselines.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    result : dict
        A :func:`benchmarks.volume_accuracy.run_volume_accuracy` result.
    """
    for m, pts in result["curves"]["target"].items():
        w = result["chosen"]["target"][m]
        ax.plot(*_xy(pts, "psnr"), marker="s", ms=4,
                label=f"{m} (tv {w['tv']:g}, l1 {w['l1']:g})")
    bl = result["baselines"]
    ax.axhline(bl["zero_volume"]["psnr"], color="0.5", ls=":", lw=1, label="zero volume")
    ax.axhline(bl["back_projection"]["psnr"], color="0.3", ls="--", lw=1,
               label="back-projection")
    s = result["setup"]
    log_x_axis(ax)
    ax.set_xlabel("seconds (solver iterations only)")
    ax.set_ylabel("volume PSNR (dB, gain-fitted)")
    ax.set_title(f"3D tilted target, {len(s['depths_mm'])} planes of "
                 f"{s['sensor_shape'][0]}x{s['sensor_shape'][1]}, SNR "
                 f"{result['snr']['target']:.1f} dB")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


def _mip_yz(volume: np.ndarray) -> np.ndarray:
    """Maximum over x: (n_z, rows), shown with depth along the horizontal axis."""
    return np.asarray(volume).max(axis=2).T


def plot_volume_accuracy(result: dict, path: Path, volumes: dict,
                         truth_target: np.ndarray) -> Path:
    """The benchmark figure: curves, sweep and y-z projections of the tilted target.

    Top row: tilted-target PSNR vs seconds (:func:`plot_volume_panel`); bead axial
    and lateral errors vs seconds; the target sweep (PSNR against the TV and l1
    weights). Bottom row: maximum-intensity projections over x (depth horizontal,
    planes uniform in 1/z) of the truth and of each method's final volume.

    Parameters
    ----------
    result : dict
    path : Path
        PNG to write.
    volumes : dict
        ``(kind, method) -> volume`` (the final field-of-view volumes).
    truth_target : ndarray, shape (n_z, rows, cols)

    Returns
    -------
    Path
    """
    from matplotlib.figure import Figure

    methods = list(result["curves"]["target"])
    fig = Figure(figsize=(15, 8.5))
    axes = fig.subplots(2, 3)
    plot_volume_panel(axes[0, 0], result)
    ax = axes[0, 1]
    for k, (m, pts) in enumerate(result["curves"]["beads"].items()):
        ax.plot(*_xy(pts, "axial_planes_max_abs"), marker="o", ms=4, color=f"C{k}",
                label=f"{m}: max |axial| (planes)")
        x, lat = _xy(pts, "lateral_um_mean")
        ax.plot(x, np.asarray(lat) / 100.0, marker="^", ms=4, ls="--", color=f"C{k}",
                label=f"{m}: mean lateral (100 um)")
    ax.axhline(1.0, color="k", lw=0.8)
    log_x_axis(ax)
    ax.set(xlabel="seconds (solver iterations only)", ylabel="error",
           title=f"{result['setup']['beads']} beads: localisation error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    ax = axes[0, 2]
    for k, m in enumerate(methods):
        recs = [r for r in result["sweep"]["target"][m] if "psnr" in r]
        for reg, style in (("tv", "o-"), ("l1", "s--")):
            pts = sorted((r[reg], r["psnr"]) for r in recs if r[reg] > 0
                         and r["tv" if reg == "l1" else "l1"] == 0)
            if pts:
                ax.plot(*zip(*pts, strict=True), style, color=f"C{k}", ms=4,
                        label=f"{m} {reg.upper()}")
        none = [r["psnr"] for r in recs if r["tv"] == 0 and r["l1"] == 0]
        if none:
            ax.axhline(none[0], color=f"C{k}", ls=":", lw=1, label=f"{m} unregularised")
    log_x_axis(ax)
    ax.set(xlabel="weight (scaled problem)", ylabel="volume PSNR (dB)",
           title=f"target sweep, {result['setup']['sweep_iterations']} iterations")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    panels = [("truth", truth_target)] + [(m, volumes.get(("target", m))) for m in methods]
    for ax, (name, vol) in zip(axes[1], panels, strict=False):
        if vol is None:
            ax.set_axis_off()
            continue
        ax.imshow(_mip_yz(vol), aspect="auto", cmap="gray", interpolation="nearest")
        ax.set(xlabel="plane (near -> far, uniform in 1/z)", ylabel="row",
               title=f"tilted target, max over x: {name}")
    fig.tight_layout()
    return save_figure(fig, path)
