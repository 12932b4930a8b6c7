"""The priors on measured data: the tutorial hand (2D) and the 3D sample, side by side.

``python -m benchmarks.prior_figures --out docs/images`` (from a checkout, with
``$DIFFUSERLAB_DATA`` / ``$DIFFUSERLAB_DATA3D`` or the data beside the repository)
writes ``priors_hand.png``, ``priors_3d.png`` and ``priors_figures.json`` (weights,
held-out errors, seconds). There is no ground truth: these are looks, the scene-suite
benchmark (:mod:`benchmarks.priors`) measures.

* Hand: the tutorial PSF and raw at bin 4, ADMM with each prior at its automatic
  weight (:func:`recon.auto.prior_path`, the same held-out blocks) and the automatic
  prior's choice between them (:func:`recon.auto.prior.choose_prior`), 200
  iterations; the full image and a 2x crop of the fingers.
* 3D: every 4th plane of the 3D sample at bin 2, 3D ADMM with 3D TV at its automatic
  weight, then the wavelet and the DnCNN on each plane at fixed weights (a volume's
  automatic weight is TV's); maximum projections along depth.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from recon import PsfStack, reconstruct
from recon.auto import noise_energy_of, prior_path
from recon.auto.prior import choose_prior
from recon.planar import scaled_problem
from recon.priors import PRIORS
from recon.sample import load_sample
from recon.volume.sample import load_volume_sample

__all__ = ["hand", "main", "volume"]


def _panel(ax, image: np.ndarray, title: str) -> None:
    ax.imshow(image, cmap="gray", vmin=0, vmax=float(np.percentile(image, 99.7)) or 1.0)
    ax.set_title(title, fontsize=8)
    ax.set_axis_off()


def hand(out: Path, iterations: int = 200) -> dict:
    """The hand with each prior (automatic weights) and the automatic choice."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    prepared = load_sample(4)
    raw = np.array(prepared.raw, np.float32)
    scale = float(np.max(np.abs(raw)))
    op, b = scaled_problem(np.array(prepared.psf, np.float32), raw, None, b_scale=scale)
    _, energy = noise_energy_of(op, raw, scale)
    t0 = time.perf_counter()
    res, weight, choice = choose_prior(prior_path(op, b, iterations=iterations,
                                                  noise_energy=energy))
    seconds = time.perf_counter() - t0
    fig = Figure(figsize=(12, 6.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, len(PRIORS))
    record = {"chosen": choice.prior, "reason": choice.reason, "seconds": seconds,
              "candidates": choice.candidates}
    for k, cand in enumerate(choice.candidates):
        p = cand["prior"]
        img = np.flip(choice.results[p].x[op.crop], axis=(0, 1))  # upright
        tag = " (chosen)" if p == choice.prior else ""
        _panel(axes[0, k], img, f"{p}{tag}: weight {cand['weight']:.3g}, held-out "
                                f"{cand['holdout_error']:.4g}, {cand['seconds']:.0f} s")
        r0, c0 = img.shape[0] // 4, img.shape[1] // 4
        _panel(axes[1, k], img[r0:r0 + img.shape[0] // 2, c0:c0 + img.shape[1] // 2],
               f"{p}: centre, 2x")
    fig.suptitle(f"tutorial hand, bin 4, ADMM <= {iterations} iterations per weight: each "
                 f"prior at its automatic weight; the automatic prior chose {choice.prior}",
                 fontsize=9)
    fig.savefig(out / "priors_hand.png", dpi=100)
    return record


def volume(out: Path, iterations: int = 100) -> dict:
    """Max projections of the 3D sample with 3D TV (automatic) and the plane priors."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    sample = load_volume_sample()
    stack = sample.stack[::4]
    model = PsfStack(stack, sample.depths[::4])
    raw = sample.raw
    runs = {}
    t0 = time.perf_counter()
    runs["tv"] = reconstruct(model, raw, "admm", bin_factor=2, iterations=iterations,
                             dark="none")
    times = {"tv": time.perf_counter() - t0}
    weights = {"tv": runs["tv"].info.tv, "wavelet": runs["tv"].info.tv, "dncnn": 0.2}
    for p in ("wavelet", "dncnn"):
        t0 = time.perf_counter()
        runs[p] = reconstruct(model, raw, "admm", bin_factor=2, iterations=iterations, dark="none",
                              tv=weights[p], prior=p)
        times[p] = time.perf_counter() - t0
    fig = Figure(figsize=(12, 3.8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    for ax, p in zip(axes, ("tv", "wavelet", "dncnn"), strict=True):
        mip = runs[p].upright().max(axis=0)
        _panel(ax, mip, f"{p}{' (automatic weight)' if p == 'tv' else ''}: weight "
                        f"{weights[p]:.3g}, {times[p]:.0f} s")
    fig.suptitle(f"3D sample, every 4th plane ({len(stack)}), bin 2, 3D ADMM {iterations} "
                 "iterations: maximum projections along depth", fontsize=9)
    fig.savefig(out / "priors_3d.png", dpi=100)
    return {"planes": len(stack), "weights": weights, "seconds": times}


def main(argv=None) -> int:
    """Write the figures and their record; refuses to replace them without --overwrite."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/prior-figures"))
    p.add_argument("--overwrite", action="store_true")
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    names = ("priors_hand.png", "priors_3d.png", "priors_figures.json")
    if not a.overwrite and any((a.out / n).exists() for n in names):
        print(f"error: {a.out} holds earlier figures; pass --overwrite", file=sys.stderr)
        return 2
    record = {"hand": hand(a.out), "volume": volume(a.out)}
    (a.out / "priors_figures.json").write_text(json.dumps(record, indent=1, default=float)
                                              + "\n")
    print(json.dumps(record, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
