"""The PSF calibrated from known scenes on real measurements, scored by leave-one-out.

Run with ``python -m benchmarks.psf_from_scenes [--data DIR] [--out DIR] [--pairs N]
[--bin B]``.

Data: the five DiffuserCam pairs of ``shared/data/mirflickr-real`` (a photograph on a
monitor captured by the lensless camera and, registered, by a lensed one; README
there): the lensed images are the known scenes, on the sensor grid, with the
measurements of the lensless camera (dark-subtracted, 270 x 480 RGB). For each pair
the PSF is estimated from the other pairs
(:func:`recon.analysis.psf_from_scenes.leave_one_out`, the default ADMM settings) and
predicts the left-out pair's measurement; the relative residual
``||C (x * P h) - b|| / ||b||`` is reported per pair and channel, beside that of a
flat PSF (every pixel alike, its total fitted to the same training pairs by least
squares), which explains nothing but the scenes' mean brightness. The PSF
estimated from all the pairs is drawn (``psf.png``: RGB, each channel over its 99.9th
percentile, gamma 0.5 so the faint caustics show).

Writes ``residuals.json`` and ``psf.png`` in ``--out`` (default
``out/benchmark/psf_from_scenes``) and prints one line per pair.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from recon.analysis.psf_from_scenes import estimate_psf_from_scenes, leave_one_out
from recon.operators import ConvolutionOperator
from recon.preprocess import box_bin

__all__ = ["NAMES", "default_data_dir", "flat_residuals", "load_pairs", "main", "run_study"]

#: The pairs of the shared set, in the README's order.
NAMES = ("im43", "im157", "im189", "im394", "im408")


def default_data_dir() -> Path:
    """``shared/data/mirflickr-real`` next to the repository."""
    return Path(__file__).resolve().parents[1].parent / "shared/data/mirflickr-real"


def load_pairs(data_dir: Path | None = None, names=NAMES, bin_factor: int = 1
               ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The lensed scenes and lensless measurements of ``names``, binned.

    Returns
    -------
    scenes, measurements : list of ndarray, float32, (270 / b, 480 / b, 3)

    Raises
    ------
    FileNotFoundError
        A pair is missing (the message names the directory).
    """
    d = Path(data_dir) if data_dir is not None else default_data_dir()
    scenes, measurements = [], []
    for n in names:
        files = d / "lensed" / f"{n}.npy", d / "diffuser" / f"{n}.npy"
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise FileNotFoundError(f"the real scene/measurement pairs are missing "
                                    f"({', '.join(missing)}); give their directory "
                                    "(shared/data/mirflickr-real)")
        scenes.append(box_bin(np.load(files[0]), bin_factor))
        measurements.append(box_bin(np.load(files[1]), bin_factor))
    return scenes, measurements


def flat_residuals(scenes, measurements) -> np.ndarray:
    """Held-out residuals of a flat PSF (one value everywhere, fitted by least
    squares to the other pairs per channel): the baseline, (n_pairs, channels)."""
    shape = scenes[0].shape
    out = np.zeros((len(scenes), shape[2]))
    for k in range(len(scenes)):
        train = [i for i in range(len(scenes)) if i != k]
        for c in range(shape[2]):
            preds = [_flat_prediction(scenes[i][..., c]) for i in train]
            b = [measurements[i][..., c] for i in train]
            gain = (sum(float(np.vdot(p, m)) for p, m in zip(preds, b, strict=True))
                    / sum(float(np.vdot(p, p)) for p in preds))
            pred = gain * _flat_prediction(scenes[k][..., c])
            b_k = measurements[k][..., c]
            out[k, c] = float(np.linalg.norm(pred - b_k) / np.linalg.norm(b_k))
    return out


def _flat_prediction(scene: np.ndarray) -> np.ndarray:
    """``C (x * P 1)``: the measurement a PSF of ones predicts, float64."""
    op = ConvolutionOperator(np.ones(scene.shape, np.float32))
    padded = np.zeros(op.padded_shape, np.float32)
    padded[op.crop] = scene
    return op.forward(padded).astype(np.float64)


def psf_figure(psf: np.ndarray, path: Path) -> Path:
    """Draw an RGB PSF: each channel over its 99.9th percentile, gamma 0.5."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    top = np.percentile(psf, 99.9, axis=(0, 1))
    image = np.clip(psf / np.maximum(top, 1e-30), 0, 1) ** 0.5
    fig = Figure(figsize=(9, 5.4))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.imshow(image, interpolation="nearest")
    ax.set_title("PSF from the five known scenes (RGB, gamma 0.5)")
    ax.set_axis_off()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return path


def run_study(data_dir: Path | None, out: Path, pairs: int = len(NAMES),
              bin_factor: int = 1) -> dict:
    """Leave-one-out over the first ``pairs`` pairs; writes ``residuals.json`` and
    ``psf.png`` in ``out`` and returns the numbers."""
    names = NAMES[:pairs]
    scenes, measurements = load_pairs(data_dir, names, bin_factor)
    t0 = time.perf_counter()
    loo = leave_one_out(scenes, measurements)
    seconds = time.perf_counter() - t0
    flat = flat_residuals(scenes, measurements)
    full = estimate_psf_from_scenes(scenes, measurements)
    result = {
        "pairs": list(names), "bin_factor": bin_factor, "shape": list(scenes[0].shape),
        "method": full.method, "seconds_leave_one_out": round(seconds, 1),
        "held_out": {n: [round(float(v), 4) for v in loo.residuals[k]]
                     for k, n in enumerate(names)},
        "held_out_mean": round(loo.mean, 4),
        "flat_psf_held_out": {n: [round(float(v), 4) for v in flat[k]]
                              for k, n in enumerate(names)},
        "flat_psf_mean": round(float(flat.mean()), 4),
        "negative_fraction": 0.0 if full.psf.min() >= 0 else float(np.mean(full.psf < 0)),
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "residuals.json").write_text(json.dumps(result, indent=1) + "\n")
    np.save(out / "psf.npy", full.psf)
    psf_figure(full.psf, out / "psf.png")
    return result


def main(argv=None) -> int:
    """The command line (module docstring)."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.psf_from_scenes",
                                description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=None, help="the pairs' directory (default "
                   "shared/data/mirflickr-real next to the repository)")
    p.add_argument("--out", type=Path, default=Path("out/benchmark/psf_from_scenes"))
    p.add_argument("--pairs", type=int, default=len(NAMES), choices=range(2, len(NAMES) + 1))
    p.add_argument("--bin", type=int, default=1, dest="bin_factor", choices=(1, 2, 3, 5))
    args = p.parse_args(argv)
    try:
        r = run_study(args.data, args.out, args.pairs, args.bin_factor)
    except FileNotFoundError as exc:
        print(f"python -m benchmarks.psf_from_scenes: error: {exc}", file=sys.stderr)
        return 2
    print(f"held-out relative residual per pair (R, G, B); {r['method']}")
    for n, v in r["held_out"].items():
        print(f"{n:6s} {v[0]:.3f} {v[1]:.3f} {v[2]:.3f}   flat PSF "
              + " ".join(f"{x:.3f}" for x in r["flat_psf_held_out"][n]))
    print(f"mean   {r['held_out_mean']:.3f} (flat PSF {r['flat_psf_mean']:.3f}); "
          f"{r['seconds_leave_one_out']} s; wrote {args.out}/residuals.json, psf.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
