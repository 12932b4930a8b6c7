"""A far scene through a spatially varying lensless camera: the two-part model and its
ADMM against the on-axis PSF and against FISTA (Kuo 2020, Eq. 5.1-5.7).

The camera is the virtual bench's (:func:`recon.optics.lensless.default_geometry`: 256 x 320 px
at 13 um, a smooth diffuser 8.9 mm from the sensor, a 20 deg pixel fall-off). A
bundled photograph on a plane 40 mm away spans 0.8 of the sensor's field (15 mm,
+-10.6 deg), ray traced with spatial variance on a 5 x 5 patch grid, finer than the
calibration's 3 x 3 (:meth:`recon.optics.lensless.LenslessModel.render`, 2x oversampled),
then Poisson shot noise at ``photons`` for the brightest pixel and 3 e- read noise.
The calibration is the demo's: ray-traced pinhole PSFs on a 3 x 3 grid spanning the
scene (+-7.5 mm), Poisson noise at 20000 e- for the central PSF's peak, registered by
cross-correlation (:meth:`recon.spatial.PsfGrid.from_positions`); the outer PSFs lose
up to half their light past the sensor's edge.

Methods, each scored by PSNR and SSIM after a gain fit and a +-2 px registration
(:func:`recon.metrics.register_truth`) against the scene resampled onto the object
grid (:meth:`recon.optics.lensless.LenslessModel.scene_truth`):

* ``on-axis``: the central PSF alone (:func:`recon.reconstruct`, ADMM, automatic TV),
  the brightness measured from the grid divided out (what the demo did before);
* ``two-part auto`` / ``two-part local``: the grid's caustics
  (:func:`recon.spatial.caustic_grid`) in the model :func:`recon.spatial.choose_model`
  picks, or in the local convolution model, solved by ADMM
  (:func:`recon.spatial.spatial_admm`) with the automatic TV weight, the brightness
  divided out (:func:`recon.reconstruct` of the grid). (The two-part convolution
  model is the on-axis method: one caustic, the brightness divided out.)
* convergence (first case): the two-part local model at the best of three fixed TV
  weights (:data:`CONVERGENCE_WEIGHTS`), ADMM and FISTA (:func:`recon.solvers.fista`,
  Haar-shift TV) at doubling iteration counts: PSNR against seconds, the
  speed-vs-accuracy chart of this model.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from instrument.benchmarks import fmt, format_table, log_x_axis, save_figure, write_json

__all__ = ["plot_spatial_far", "run_spatial_far", "spatial_far_table"]

log = logging.getLogger(__name__)

#: Scene depth (mm) and the fraction of the sensor's field the scene spans.
Z_MM, FIELD_FRACTION = 40.0, 0.8
#: Peak photo-electrons of the calibration PSFs (the central one).
PSF_PHOTONS = 20000.0
#: Patches per axis of the rendering (the calibration grid is 3 x 3).
RENDER_PATCHES = 5


def _camera(seed: int):
    from recon.optics.lensless import LenslessModel, default_geometry

    model = LenslessModel(default_geometry("smooth", seed))
    geo = model.geometry
    width = FIELD_FRACTION * geo.sensor_shape[1] * geo.sensor_pitch_um * 1e-3 * Z_MM / geo.d_mm
    return model, width


def _calibration(model, width: float, rng):
    """3 x 3 ray-traced pinhole PSFs spanning the scene, noisy, registered."""
    from recon.spatial import PsfGrid

    half = width / 2
    positions = [(x, y) for y in (-half, 0.0, half) for x in (-half, 0.0, half)]
    psfs = np.stack([model.psf((x, y, Z_MM)) for x, y in positions])
    gain = PSF_PHOTONS / float(psfs[4].max())
    noisy = rng.poisson(psfs * gain).astype(np.float32)
    return PsfGrid.from_positions(noisy, positions, z_mm=Z_MM, d_mm=model.geometry.d_mm)


def _measurement(model, scene, width: float, photons: float, rng):
    image = model.render(scene, Z_MM, width, patches=RENDER_PATCHES)
    electrons = image * (photons / float(image.max()))
    raw = rng.poisson(electrons) + rng.normal(0.0, 3.0, image.shape)
    return raw.astype(np.float32)


def _score(image, truth) -> dict:
    from recon.metrics import psnr, register_truth, ssim

    _, t = register_truth(image, truth)
    return {"psnr_db": psnr(image, t), "ssim": ssim(image, t)}


def _bin(grid, raw, truth, factor: int):
    from recon.preprocess import box_bin
    from recon.spatial.api import bin_grid

    if factor == 1:
        return grid, raw, truth
    return (bin_grid(grid, factor), box_bin(raw, factor).astype(np.float32),
            box_bin(truth, factor))


def _methods(grid, raw, truth, iterations: int, models=("auto", "local")) -> dict:
    from recon.api import reconstruct
    from recon.spatial import correct_brightness

    out = {}
    t0 = time.perf_counter()
    on_axis = reconstruct(grid.psfs[grid.central], raw, iterations=iterations, dark="none")
    image = correct_brightness(on_axis.image, grid)
    out["on-axis"] = {**_score(image, truth), "seconds": time.perf_counter() - t0,
                      "model": "convolution (on-axis PSF)", "tv": on_axis.info["tv"],
                      "iterations_used": on_axis.info["iterations_used"]}
    for model in models:
        name = f"two-part {model}"
        t0 = time.perf_counter()
        rec = reconstruct(grid, raw, "admm", two_part=True, background="none",
                          model=model, iterations=iterations)
        m = rec.metrics()
        out[name] = {**_score(rec.image, truth), "seconds": time.perf_counter() - t0,
                     "model": rec.choice.label(), "tv": rec.info["tv"],
                     "iterations_used": rec.info["iterations_used"],
                     "ratio_to_fft_floor": m["ratio_to_fft_floor"]}
    return out


#: TV weights of the convergence comparison's sweep (ADMM at its largest count).
CONVERGENCE_WEIGHTS = (1e-4, 2e-4, 4e-4)


def _convergence(grid, raw, truth, admm_its, fista_its,
                 weights=CONVERGENCE_WEIGHTS) -> dict:
    """PSNR against seconds of ADMM and FISTA on the two-part local model, at the TV
    weight of :data:`CONVERGENCE_WEIGHTS` with which ADMM's longest run scores best (the
    automatic weight's final solve stops early, so at its weight the converged
    minimiser can be worse than the kept iterate: both solvers are compared on one
    objective whose minimiser is good)."""
    from recon.solvers import fista
    from recon.spatial import spatial_admm
    from recon.spatial.api import grid_model

    _, op = grid_model(grid, model="local", bin_factor=1, two_part=True)
    scale = float(np.max(raw))
    b = (raw / scale).astype(np.float32)

    def score(x):
        return _score(x[op.crop] * scale / op.brightness, truth)

    sweep = ({w: score(spatial_admm(op, b, iterations=max(admm_its), tv=w).x)["psnr_db"]
              for w in weights} if len(weights) > 1 else {})
    tv = max(sweep, key=sweep.get) if sweep else weights[0]
    lipschitz = op.lipschitz()
    curves = {"admm": [], "fista": []}
    for name, counts in (("admm", admm_its), ("fista", fista_its)):
        for n in counts:
            t0 = time.perf_counter()
            if name == "admm":
                res = spatial_admm(op, b, iterations=n, tv=tv)
            else:
                res = fista(op, b, iterations=n, tv=tv, lipschitz=lipschitz)
            seconds = time.perf_counter() - t0
            curves[name].append({"iterations": n, "seconds": seconds, **score(res.x)})
    return {"tv": tv, "sweep_psnr_db": {f"{w:g}": v for w, v in sweep.items()},
            "n_kernels": int(op.n_kernels), **curves}


def run_spatial_far(quick: bool, out: Path) -> dict:
    """Run the benchmark (module docstring); write ``spatial_far.json`` and
    ``spatial_far.png`` under ``out``.

    Parameters
    ----------
    quick : bool
        One scene and photon level, the problem binned 2 x 2, the automatic model only,
        the convergence at TV 2e-4 and at most 200 iterations.
    out : Path

    Returns
    -------
    dict
        ``cases`` (scene, photons, per method PSNR, SSIM, seconds, model, weight,
        iterations), ``convergence`` (ADMM and FISTA curves), settings.
    """
    from recon.scenes import load_scene

    rng = np.random.default_rng(0)
    model, width = _camera(seed=0)
    grid = _calibration(model, width, rng)
    factor = 2 if quick else 1
    iterations = 200
    cases = [("camera", 3000.0)] if quick else [
        ("camera", 3000.0), ("camera", 30000.0), ("astronaut", 3000.0), ("coffee", 3000.0)]
    results = []
    first = None
    for scene_name, photons in cases:
        scene = load_scene(scene_name, (512, 512))
        raw = _measurement(model, scene, width, photons, rng)
        truth = model.scene_truth(scene, Z_MM, width)
        g, r, t = _bin(grid, raw, truth, factor)
        methods = _methods(g, r, t, iterations, ("auto",) if quick else ("auto", "local"))
        results.append({"scene": scene_name, "photons": photons, "methods": methods})
        log.info("%s at %g e-: %s", scene_name, photons,
                 ", ".join(f"{k} {v['psnr_db']:.1f} dB" for k, v in methods.items()))
        if first is None:
            first = (g, r, t)
    admm_its = (50, 100, 200) if quick else (50, 100, 200, 400)
    fista_its = (100, 200) if quick else (100, 200, 400, 800, 1600, 3200)
    convergence = _convergence(*first, admm_its, fista_its,
                               (2e-4,) if quick else CONVERGENCE_WEIGHTS)
    result = {"cases": results, "convergence": convergence, "quick": quick,
              "z_mm": Z_MM, "scene_width_mm": width, "bin": factor,
              "render_patches": RENDER_PATCHES, "calibration": "3 x 3 over the scene",
              "iterations": iterations, "psf_photons": PSF_PHOTONS}
    write_json(Path(out) / "spatial_far.json", result)
    plot_spatial_far(result, Path(out) / "spatial_far.png")
    return result


def spatial_far_table(result: dict) -> str:
    """PSNR / SSIM per case and method, then the convergence curves."""
    rows = []
    for case in result["cases"]:
        for name, m in case["methods"].items():
            rows.append([f"{case['scene']} {case['photons']:g} e-", name, m["model"],
                         fmt(m["psnr_db"]), fmt(m["ssim"], ".3f"), fmt(m["tv"], ".2g"),
                         m["iterations_used"], fmt(m["seconds"], ".1f")])
    text = format_table(["case", "method", "model", "PSNR dB", "SSIM", "TV", "it", "s"], rows)
    c = result["convergence"]
    curve = [[name, p["iterations"], fmt(p["seconds"], ".1f"), fmt(p["psnr_db"])]
             for name in ("admm", "fista") for p in c[name]]
    return (text + f"\n\nconvergence, two-part local model ({c['n_kernels']} kernels), TV "
            f"{c['tv']:.2g}:\n" + format_table(["solver", "it", "s", "PSNR dB"], curve))


def plot_spatial_far(result: dict, path: Path) -> Path:
    """PSNR against seconds: ADMM and FISTA on the two-part local model, and the
    automatic methods of the first case as points.

    Parameters
    ----------
    result : dict
        The record of :func:`run_spatial_far`.
    path : Path
        The PNG to write (replaced if it exists: the caller owns the output folder).

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.2))
    ax = fig.subplots()
    c = result["convergence"]
    for name, style in (("admm", "o-"), ("fista", "s--")):
        pts = c[name]
        ax.plot([p["seconds"] for p in pts], [p["psnr_db"] for p in pts], style,
                label=f"{name.upper()}, local model, TV {c['tv']:.2g}")
        for p in pts:
            ax.annotate(str(p["iterations"]), (p["seconds"], p["psnr_db"]), fontsize=7,
                        xytext=(3, -9), textcoords="offset points")
    case = result["cases"][0]
    for k, (name, m) in enumerate(case["methods"].items()):
        ax.plot(m["seconds"], m["psnr_db"], "D", ms=6, color=f"C{k + 2}",
                label=f"{name} ({m['model']}), automatic")
    log_x_axis(ax)
    ax.set_xlabel("seconds (numbers: iterations)")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(f"{case['scene']} at {case['photons']:g} e-, 40 mm, 3 x 3 calibration",
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return save_figure(fig, path)
