"""The ADMM's priors on real measurements: anisotropic TV, isotropic TV and TGV.

Run with ``python -m benchmarks.real_priors [--data DIR] [--psf-dir DIR] [--out DIR]
[--pairs N] [--priors P,...] [--weights W,...]``.

Data: the five DiffuserCam pairs of ``shared/data/mirflickr-real`` (a photograph on a
monitor captured by the lensless camera and, registered, by a lensed one). Each pair is
reconstructed with the PSF estimated from the *other* four pairs
(:func:`recon.analysis.psf_from_scenes.leave_one_out`, non-negative; read from
``--psf-dir`` as ``psf_tied_{pair}_{channel}.npy`` when there, else computed and saved
there), by :func:`recon.reconstruct` (ADMM, ``dark="none"``, no binning) with each
prior at the automatic weight and at each fixed weight of ``--weights``. The estimate
is scored against the lensed image after a per-channel least-squares gain (the two
cameras' exposures differ), clipped to [0, 1]: PSNR and SSIM by scikit-image. Each
reconstruction is timed (wall clock, this machine).

Writes ``results.json`` (every pair and setting: PSNR, SSIM, seconds, the weight) and
``contact.png`` (one row per pair: the lensed truth, then each prior at its automatic
weight) in ``--out`` (default ``out/benchmark/real_priors``), and prints one line per
setting with the means over the pairs.

With ``--simulated`` it scores the same priors on simulated scenes of the priors
benchmark instead (:mod:`benchmarks.priors`: camera, chelsea and brick rendered
through the measured tutorial PSF with its noise and model mismatch, bin 8, 200
iterations), each at its best weight of :data:`SIM_GRID` (the oracle, by PSNR against
the truth), into ``simulated.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.psf_from_scenes import NAMES, load_pairs

__all__ = ["add_pair_options", "gain_fit", "load_psfs", "load_sensor_psfs", "main", "run_study",
           "score"]

#: The priors compared (names of :data:`recon.priors.PRIORS`).
PRIORS = ("tv", "tv-iso", "tgv")
#: The simulated scenes and the fixed weights of ``--simulated``.
SIM_SCENES = ("camera", "chelsea", "brick")
SIM_GRID = (3.16e-5, 1e-4, 3.16e-4, 1e-3)


def gain_fit(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``estimate`` (H, W, 3) times each channel's least-squares gain against
    ``truth`` (same shape), clipped to [0, 1]; float32."""
    from recon.metrics import fit_gain

    out = np.empty(truth.shape, np.float32)
    for c in range(truth.shape[-1]):
        e = estimate[..., c].astype(np.float64)
        out[..., c] = np.clip(fit_gain(e, truth[..., c]) * e, 0, 1)
    return out


def score(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """PSNR (dB) and SSIM of ``estimate`` (already gain-fitted) against ``truth``,
    both (H, W, 3) in [0, 1] (scikit-image, data range 1)."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    return (float(peak_signal_noise_ratio(truth, estimate, data_range=1)),
            float(structural_similarity(truth, estimate, channel_axis=-1, data_range=1)))


def load_psfs(psf_dir: Path, names, scenes, measurements) -> list[np.ndarray]:
    """Each pair's leave-one-out PSF (H, W, 3) float32: read from ``psf_dir``
    (``psf_tied_{pair}_{c}.npy``), or estimated from the other pairs of ``scenes`` /
    ``measurements`` and saved there."""
    files = [[psf_dir / f"psf_tied_{n}_{c}.npy" for c in range(3)] for n in names]
    if all(f.is_file() for row in files for f in row):
        return [np.stack([np.load(f) for f in row], -1).astype(np.float32) for row in files]
    from recon.analysis.psf_from_scenes import leave_one_out

    psfs = leave_one_out(scenes, measurements).psfs
    psf_dir.mkdir(parents=True, exist_ok=True)
    for row, psf in zip(files, psfs, strict=True):
        for c, f in enumerate(row):
            np.save(f, np.asarray(psf[..., c], np.float32))
    return [np.asarray(p, np.float32) for p in psfs]


def load_sensor_psfs(psf_dir: Path | None, names, scenes, measurements) -> list[np.ndarray]:
    """Each pair's leave-one-out PSF (H, W, 3) float32 as the scene calibration makes
    it (:func:`recon.analysis.sensor_response.estimate_with_sensor_response` on the
    other pairs): read from ``psf_dir`` (``psf_sensor_{pair}.npy``) when there, else
    estimated and, with a ``psf_dir``, saved there."""
    from recon.analysis.sensor_response import estimate_with_sensor_response

    psfs = []
    for k, n in enumerate(names):
        path = None if psf_dir is None else Path(psf_dir) / f"psf_sensor_{n}.npy"
        if path is not None and path.is_file():
            psfs.append(np.load(path).astype(np.float32))
            continue
        xs = [x for i, x in enumerate(scenes) if i != k]
        bs = [b for i, b in enumerate(measurements) if i != k]
        psfs.append(np.asarray(estimate_with_sensor_response(xs, bs)[0].psf, np.float32))
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, psfs[-1])
    return psfs


def _reconstruct(psf, raw, prior: str, weight):
    import recon

    t0 = time.perf_counter()
    res = recon.reconstruct(psf, raw, method="admm", prior=prior, tv=weight, dark="none",
                            bin_factor=1)
    return np.asarray(res.image), time.perf_counter() - t0, res.info.tv


def contact_sheet(rows: list[list[np.ndarray]], titles: list[str], names, path: Path) -> Path:
    """One row per pair: the images of ``rows`` side by side, titled."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n_r, n_c = len(rows), len(rows[0])
    fig = Figure(figsize=(3.2 * n_c, 1.9 * n_r))
    FigureCanvasAgg(fig)
    for i, row in enumerate(rows):
        for j, image in enumerate(row):
            ax = fig.add_subplot(n_r, n_c, i * n_c + j + 1)
            ax.imshow(image, interpolation="nearest")
            ax.set_axis_off()
            if i == 0:
                ax.set_title(titles[j], fontsize=9)
            if j == 0:
                ax.text(-10, 135, names[i], rotation=90, va="center", ha="right", fontsize=8)
    fig.subplots_adjust(0.02, 0.01, 0.99, 0.95, 0.02, 0.08)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def run_study(data_dir: Path | None, psf_dir: Path, out: Path, pairs: int = len(NAMES),
              priors=PRIORS, weights=(), log=print) -> dict:
    """Every prior at the automatic weight and at each of ``weights`` on the first
    ``pairs`` pairs; writes ``results.json`` and ``contact.png`` in ``out`` and returns
    the numbers (``rows``: one dict per pair and setting; ``means``: per setting)."""
    names = NAMES[:pairs]
    scenes, measurements = load_pairs(data_dir, names)
    psfs = load_psfs(psf_dir, names, scenes, measurements)
    settings = [(p, "auto") for p in priors] + [(p, float(w)) for p in priors for w in weights]
    rows, sheet = [], [[s] for s in scenes]
    for prior, weight in settings:
        for k, n in enumerate(names):
            image, seconds, used = _reconstruct(psfs[k], measurements[k], prior, weight)
            est = gain_fit(image, scenes[k])
            psnr, ssim = score(est, scenes[k])
            rows.append({"pair": n, "prior": prior, "weight": weight, "psnr_db": psnr,
                         "ssim": ssim, "seconds": seconds, "weight_used": str(used)})
            log(f"{prior:7s} {weight!s:8s} {n:6s} {psnr:6.2f} dB {ssim:.3f} {seconds:6.1f} s "
                f"weight {str(used)[:50]}")
            if weight == "auto":
                sheet[k].append(est)
    means = []
    for prior, weight in settings:
        sel = [r for r in rows if r["prior"] == prior and r["weight"] == weight]
        means.append({"prior": prior, "weight": weight,
                      "psnr_db": float(np.mean([r["psnr_db"] for r in sel])),
                      "ssim": float(np.mean([r["ssim"] for r in sel])),
                      "seconds": float(np.mean([r["seconds"] for r in sel]))})
    result = {"pairs": list(names), "rows": rows, "means": means}
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(result, indent=1) + "\n")
    contact_sheet(sheet, ["lensed (truth)"] + [f"{p}, auto weight" for p in priors], names,
                  out / "contact.png")
    return result


def run_simulated(out: Path, priors=PRIORS, log=print) -> dict:
    """Each prior's oracle weight of :data:`SIM_GRID` on :data:`SIM_SCENES` (the priors
    benchmark's rendering, :data:`benchmarks.priors.FULL`); writes ``simulated.json``."""
    from benchmarks.auto_scenes import render_case
    from benchmarks.priors import _KINDS, FULL, _oracle

    rows = []
    for name in SIM_SCENES:
        kind, photons = _KINDS[name]
        case = render_case(kind, photons, coarse_bin=FULL["coarse_bin"], seed=0,
                           read_noise_e=FULL["read_noise_e"], dark_e=FULL["dark_e"])
        for prior in priors:
            best = _oracle(case, prior, SIM_GRID, FULL["iterations"])["best"]
            rows.append({"scene": name, "prior": prior, **best})
            log(f"{name:8s} {prior:7s} weight {best['weight']:.3g} {best['psnr']:6.2f} dB "
                f"{best['ssim']:.3f} {best['seconds']:5.1f} s")
    out.mkdir(parents=True, exist_ok=True)
    (out / "simulated.json").write_text(json.dumps({"rows": rows}, indent=1) + "\n")
    return {"rows": rows}


def add_pair_options(parser: argparse.ArgumentParser, out: Path) -> None:
    """The real pairs' options shared by the benchmarks on them: ``--data``,
    ``--psf-dir``, ``--out`` (default ``out``) and ``--pairs``."""
    parser.add_argument("--data", type=Path, default=None, help="the pairs' directory "
                        "(default shared/data/mirflickr-real next to the repository)")
    parser.add_argument("--psf-dir", type=Path,
                        default=Path("out/benchmark/psf_leave_one_out"),
                        help="leave-one-out PSFs psf_tied_{pair}_{c}.npy (computed when "
                        "absent)")
    parser.add_argument("--out", type=Path, default=out)
    parser.add_argument("--pairs", type=int, default=len(NAMES),
                        choices=range(2, len(NAMES) + 1))


def main(argv=None) -> int:
    """The command line (module docstring)."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.real_priors",
                                description=__doc__.splitlines()[0])
    add_pair_options(p, Path("out/benchmark/real_priors"))
    p.add_argument("--priors", default=",".join(PRIORS), help="comma-separated prior names")
    p.add_argument("--weights", default="", help="comma-separated fixed weights besides auto")
    p.add_argument("--simulated", action="store_true", help="the simulated scenes instead")
    args = p.parse_args(argv)
    try:
        weights = [float(w) for w in args.weights.split(",") if w.strip()]
    except ValueError:
        print(f"python -m benchmarks.real_priors: error: --weights {args.weights!r}: give "
              "numbers separated by commas, e.g. 1e-4,1e-3", file=sys.stderr)
        return 2
    from recon.priors import PRIORS as KNOWN

    priors = [s.strip() for s in args.priors.split(",") if s.strip()]
    unknown = [s for s in priors if s not in KNOWN]
    if unknown or not priors:
        print(f"python -m benchmarks.real_priors: error: --priors {args.priors!r}: name "
              f"some of {', '.join(KNOWN)}", file=sys.stderr)
        return 2
    if args.simulated:
        run_simulated(args.out, priors)
        print(f"wrote {args.out}/simulated.json")
        return 0
    try:
        r = run_study(args.data, args.psf_dir, args.out, args.pairs, priors, weights)
    except FileNotFoundError as exc:
        print(f"python -m benchmarks.real_priors: error: {exc}", file=sys.stderr)
        return 2
    for m in r["means"]:
        print(f"mean {m['prior']:7s} {m['weight']!s:8s} {m['psnr_db']:6.2f} dB "
              f"{m['ssim']:.3f} {m['seconds']:6.1f} s")
    print(f"wrote {args.out}/results.json, contact.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
