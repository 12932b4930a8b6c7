"""Compressed sensing with pixel erasures (Kuo 2020, Sec. 3.1, Eq. 3.10, Fig. 3.7).

On the real hand measurement at bin 4: the full-data ADMM+TV reconstruction is the
reference; 80 % of the raw sensor pixels are erased (``PixelErasure.random(shape,
0.8, seed) @ op``, measurement multiplied by the mask) and the image is recovered
with FISTA+TV and ADMM+TV from the remaining 20 %. The comparison is what a lens
camera with the same dead pixels would give: the same 80 % of pixels erased in the
full reconstruction's sensor-FoV image, filled by linear interpolation
(:func:`scipy.interpolate.griddata`, nearest outside the convex hull). PSNRs are
against the full-data reconstruction. Two further figures put them in context: the
full-data FISTA result against the ADMM reference (how closely two solvers agree
without any erasure, a ceiling for the erased solves), and each erased solve against
the same solver's full-data result. The same is repeated on a simulated scene, where
the ground truth is known, adding the interpolation of the erased truth (an ideal
lens camera with the same dead pixels).

With erasures the TV weight is scaled by the measured fraction (0.2) so the balance
between the data term and the prior matches the full-data problem.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from instrument.benchmarks import (
    DEFAULT_WEIGHTS,
    fmt,
    format_table,
    load_sample,
    save_figure,
    scaled_problem,
    write_json,
)
from recon.metrics import fit_gain, psnr, ssim
from recon.operators import PixelErasure
from recon.scenes import load_scene
from recon.simulate import simulate_measurement
from recon.solvers import admm, fista

ERASED = 0.8
SEED = 0
#: TV weight for the real hand (bright hand on a dark background; the simulated-scene
#: sweep does not transfer to it). Chosen by eye: 1e-3 already smears the fingers.
REAL_TV = 3e-4
SIM_SCENE = "camera"
SIM_PHOTONS = 5000.0
SIM_READ_NOISE_E = 2.0


def interpolate_erased(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Fill the erased pixels of an image by linear interpolation of the kept ones.

    Parameters
    ----------
    image : ndarray (rows, cols)
    mask : ndarray (rows, cols)
        Non-zero where the pixel is kept.

    Returns
    -------
    ndarray, float64
        :func:`scipy.interpolate.griddata` (linear) at every pixel; pixels outside the
        convex hull of the kept ones take the nearest kept value.
    """
    from scipy.interpolate import griddata

    rows, cols = np.nonzero(mask > 0)
    pts = np.column_stack([rows, cols]).astype(np.float64)
    vals = np.asarray(image, np.float64)[rows, cols]
    gr, gc = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    # griddata does one tiny LAPACK solve per Delaunay simplex; OpenBLAS threads on a
    # busy 2-core machine made it 10-50x slower (1-6 s instead of 0.06 s here).
    with threadpool_limits(limits=1, user_api="blas"):
        out = griddata(pts, vals, (gr, gc), method="linear")
    hole = np.isnan(out)
    if hole.any():
        out[hole] = griddata(pts, vals, (gr[hole], gc[hole]), method="nearest")
    return out


def _scores(images: dict[str, np.ndarray], reference: np.ndarray) -> dict:
    return {k: {"psnr": psnr(v, reference), "ssim": ssim(v, reference)}
            for k, v in images.items()}


def _experiment(psf, b, tv_fista, tv_admm, iterations):
    """Full-data and 80 %-erased FISTA/ADMM solves plus the image-domain interpolation."""
    op, bs = scaled_problem(psf, b)
    eraser = PixelErasure.random(op.sensor_shape, ERASED, seed=SEED)
    op_e = eraser @ op
    b_e = (eraser.mask * bs).astype(np.float32)
    keep = 1.0 - ERASED
    jobs = {"admm_full": lambda: admm(op, bs, iterations=iterations, tv=tv_admm),
            "fista_full": lambda: fista(op, bs, iterations=iterations, tv=tv_fista),
            "fista_erased": lambda: fista(op_e, b_e, iterations=iterations, tv=tv_fista * keep),
            "admm_erased": lambda: admm(op_e, b_e, iterations=iterations, tv=tv_admm * keep)}
    images, seconds, residuals = {}, {}, {}
    for name, job in jobs.items():
        t0 = time.perf_counter()
        r = job()
        seconds[name] = time.perf_counter() - t0
        images[name] = r.x[op.crop]
        residuals[name] = r.final_relative_residual
    t0 = time.perf_counter()
    images["interpolated_full"] = interpolate_erased(images["admm_full"], eraser.mask)
    seconds["interpolation"] = time.perf_counter() - t0
    return op, eraser, images, seconds, residuals


def _comparisons(images: dict[str, np.ndarray]) -> dict:
    ref = images["admm_full"]
    return {
        # the Fig. 3.7 comparison: everything against the full-data ADMM reference
        "vs_full": _scores({k: images[k] for k in ("fista_erased", "admm_erased",
                                                   "interpolated_full", "fista_full")}, ref),
        # what the erasure alone costs each solver
        "vs_same_solver_full": {
            "fista_erased": _scores({"x": images["fista_erased"]}, images["fista_full"])["x"],
            "admm_erased": _scores({"x": images["admm_erased"]}, ref)["x"]},
    }


def run_erasure(quick: bool = False, out: Path | None = None,
                weights: dict[str, float] | None = None) -> dict:
    """Fig. 3.7 as numbers: erase 80 % of the sensor vs 80 % of the image.

    Parameters
    ----------
    quick : bool
        Short runs.
    out : Path, optional
        Directory for ``erasure.json`` and ``erasure.png``.
    weights : dict, optional
        TV weights for the simulated scene (``fista``, ``admm`` keys), e.g. from the
        accuracy sweep; default :data:`instrument.benchmarks.DEFAULT_WEIGHTS`. The real
        hand uses :data:`REAL_TV`.

    Returns
    -------
    dict
        ``real`` and ``simulated``, each with ``vs_full`` (PSNR/SSIM against the
        full-data ADMM reconstruction of ``fista_erased``, ``admm_erased``,
        ``interpolated_full`` and, as the solver-agreement ceiling, ``fista_full``)
        and ``vs_same_solver_full``; ``simulated["vs_truth"]`` adds ``admm_full``,
        ``fista_full`` and ``interpolated_truth`` (erased truth interpolated: an
        ideal lens camera with the same dead pixels).
    """
    w = dict(DEFAULT_WEIGHTS, **(weights or {}))
    iterations = 40 if quick else 1000
    t_start = time.perf_counter()
    prep = load_sample(4)
    op, mask, images, seconds, residuals = _experiment(prep.psf, prep.raw, REAL_TV, REAL_TV,
                                                       iterations)
    real = {"tv": REAL_TV, "tv_erased": REAL_TV * (1 - ERASED), **_comparisons(images),
            "seconds": seconds, "residuals": residuals,
            "measured_pixels": int(mask.mask.sum())}

    fine = load_sample(2).psf
    sim = simulate_measurement(fine, load_scene(SIM_SCENE, fine.shape), bin_factor=2,
                               photons=SIM_PHOTONS, read_noise_e=SIM_READ_NOISE_E, seed=5)
    op_s, mask_s, images_s, seconds_s, residuals_s = _experiment(
        prep.psf, sim.b, w["fista"], w["admm"], iterations)
    truth = sim.truth[op_s.crop]
    with_truth = dict(images_s, interpolated_truth=interpolate_erased(truth, mask_s.mask))
    simulated = {"scene": SIM_SCENE, "snr": sim.snr, "tv_admm": w["admm"],
                 "tv_fista": w["fista"], **_comparisons(images_s),
                 "vs_truth": _scores(with_truth, truth), "seconds": seconds_s,
                 "residuals": residuals_s}
    result = {"quick": quick, "erased_fraction": ERASED, "seed": SEED,
              "iterations": iterations, "tv_scaled_by_measured_fraction": True,
              "real": real, "simulated": simulated,
              "wall_seconds": time.perf_counter() - t_start}
    if out is not None:
        out = Path(out)
        write_json(out / "erasure.json", result)
        plot_erasure(images, images_s, truth, out / "erasure.png")
    return result


def erasure_table(result: dict) -> str:
    """Text table of a :func:`run_erasure` result."""
    r, s = result["real"], result["simulated"]
    lines = [f"erasure: {result['erased_fraction']:.0%} of sensor pixels erased (seed "
             f"{result['seed']}), {result['iterations']} iterations; real hand TV "
             f"{r['tv']:g}; simulated '{s['scene']}' ({s['snr']['snr_db']:.1f} dB SNR, TV "
             f"FISTA {s['tv_fista']:g}, ADMM {s['tv_admm']:g}); TV x0.2 with erasures"]
    rows = []
    for k in ("fista_erased", "admm_erased", "interpolated_full", "fista_full", "admm_full",
              "interpolated_truth"):
        rv, sv, tv = (r["vs_full"].get(k, {}), s["vs_full"].get(k, {}),
                      s["vs_truth"].get(k, {}))
        rs = r["vs_same_solver_full"].get(k, {})
        rows.append([k, fmt(rv.get("psnr")), fmt(rv.get("ssim"), ".3f"), fmt(rs.get("psnr")),
                     fmt(sv.get("psnr")), fmt(tv.get("psnr")), fmt(tv.get("ssim"), ".3f")])
    lines.append(format_table(["estimate", "real: PSNR vs ADMM full", "SSIM",
                               "vs same solver full", "sim: vs ADMM full", "sim: vs truth",
                               "SSIM"], rows))
    return "\n".join(lines)


def plot_erasure(images: dict, images_s: dict, truth: np.ndarray, path: Path) -> Path:
    """Fig. 3.7-style montage: full data, FISTA/ADMM from 20 %, interpolated, truth."""
    from matplotlib.figure import Figure

    keys = ("admm_full", "fista_erased", "admm_erased", "interpolated_full")
    fig = Figure(figsize=(13, 5.2))
    axes = fig.subplots(2, 5)
    for axrow, label, imgs, tr in ((axes[0], "real", images, None),
                                   (axes[1], "sim", images_s, truth)):
        full = imgs["admm_full"]
        top = float(np.percentile(full, 99.9)) or 1.0
        panels = [(k, imgs[k]) for k in keys] + [("truth", tr)]
        for ax, (title, img) in zip(axrow, panels, strict=True):
            ax.set_axis_off()
            if img is None:
                continue
            g = fit_gain(img, full) if img is not full else 1.0
            ax.imshow(np.clip(g * img / top, 0, 1), cmap="gray", vmin=0, vmax=1)
            ax.set_title(f"{label}: {title}", fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
