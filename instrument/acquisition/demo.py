"""The main job on the built-in simulated bench: ``diffuserlab demo``.

Open the devices, take dark frames, capture the PSF at one depth by lighting the LED
behind the pinhole on the source stage, and the PSFs of a 3 x 3 grid of positions
over the scene's field at that depth, capture a scene at that depth, reconstruct it
and write the run (frames, PSFs, result, a JSON report with timings and PSNR/SSIM
against the known scene, before and after the brightness is divided out).

The reconstruction (``method="auto"``) models the scene as far (Eq. 5.1's two parts):
the grid's caustics in the forward model that the grid calls for (the convolution,
PCA or local convolution model, :func:`recon.spatial.api.grid_model`), solved by ADMM
(:func:`recon.spatial.spatial_admm`) with the TV weight chosen by hold-out
cross-validation, and the field's brightness measured from the grid divided out
(the lensless camera's vignetting). A fixed ``method`` uses the on-axis PSF alone
(:func:`recon.reconstruct`) and divides the same brightness out
(:func:`recon.spatial.correct_brightness`): what the bench's spatially varying
PSFs cost the convolution model.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from recon import reconstruct
from recon.io import DATA_ORIENTATION, scene_view
from recon.metrics import psnr, register_truth, ssim
from recon.options import ReconOptions
from recon.spatial import PsfGrid
from recon.spatial.brightness import correct_brightness, node_brightness

from ..atomic import write_json
from ..devices.virtual_bench import PlanarScene, VirtualBench
from ..writer.files import save_image
from .exposure import autoexpose, average_frames

log = logging.getLogger(__name__)

#: The declared defaults of the method and iterations (:class:`recon.options.ReconOptions`).
_D = ReconOptions.defaults()


#: The files :func:`run_demo` writes in its directory.
OUTPUT_FILES = ("psf.tif", "psf_grid.tif", "dark.tif", "scene_raw.tif", "reconstruction.png",
                "reconstruction.tif", "truth.png", "report.json")


def run_demo(out_dir: str | Path = "out/demo", *, seed: int = 0, z_mm: float = 40.0,
             method: str = _D["method"], iterations: int = _D["iterations"], frames: int = 4,
             progress: Callable[[str], None] = print) -> dict:
    """Run the demo session on the simulated bench and write its outputs.

    Parameters
    ----------
    out_dir : path
        Run directory (created): ``psf.tif``, ``psf_grid.tif`` (the 3 x 3 grid's PSFs
        per second of exposure, row-major; positions in the report), ``scene_raw.tif``,
        ``dark.tif``, ``reconstruction.png``/``.tif`` (brightness-corrected),
        ``truth.png``, ``report.json``. The PNG views show the scene upright; the TIFF
        keeps the model grid (:data:`recon.io.DATA_ORIENTATION`).
    seed : int
        Seeds the bench (diffuser, noise).
    z_mm : float
        Depth of the PSF calibration and of the scene, mm in front of the diffuser.
    method : str
        ``"auto"``: the grid's model (two-part, far scene), ADMM and the TV weight
        chosen from the data, the report saying what and why; a method of
        :data:`recon.solvers.SOLVERS`: the on-axis PSF with that method and its default
        TV weight.
    iterations : int
        Maximum iterations (the automatic weight takes at most twice as many).
    frames : int
        Frames averaged per capture.
    progress : callable
        Receives one line per step.

    Returns
    -------
    dict
        The report written to ``report.json``.
    """
    from skimage import data

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}

    def step(name: str, since: float) -> float:
        now = time.perf_counter()
        timings[name] = now - since
        progress(f"[{now - t0:6.1f} s] {name} ({now - since:.2f} s)")
        return now

    bench = VirtualBench(seed=seed)
    with bench:
        t = step("open devices", t0)
        cam, stage, leds = bench.camera, bench.source_stage, bench.led_array
        leds.all_off()
        offset = float(np.median(average_frames(cam, 2)[0]))  # dark level, DN
        led_xy = np.asarray(leds.positions_mm)

        def capture_psf(x_mm: float, y_mm: float):
            """Pinhole at (x, y, z), the LED nearest behind it lit: PSF minus dark."""
            stage.move_to({"x": x_mm, "y": y_mm, "z": z_mm}, timeout_s=60.0)
            led = int(np.argmin(np.hypot(led_xy[:, 0] - x_mm, led_xy[:, 1] - y_mm)))
            leds.set_leds([led], colour="white", brightness=1.0)
            exposure = autoexpose(cam, dark_level=offset)
            lit, meta = average_frames(cam, frames)
            leds.all_off()
            dark_lit, _ = average_frames(cam, frames)
            return lit - dark_lit, exposure, meta

        # PSF: pinhole on axis at z, the LED right behind it
        psf, psf_exp, psf_meta = capture_psf(0.0, 0.0)
        t = step(f"PSF at z = {z_mm:g} mm (exposure {psf_exp.exposure_s * 1e3:.2f} ms)", t)
        # scene: a natural image on a plane at the same depth
        width_mm = 0.8 * bench.geometry.sensor_shape[1] * bench.geometry.sensor_pitch_um \
            * 1e-3 * z_mm / bench.geometry.d_mm
        # the field's brightness: PSFs on a 3 x 3 grid spanning the scene (Eq. 5.1)
        half = 0.5 * width_mm
        grid_xy = [(x, y) for y in (-half, 0.0, half) for x in (-half, 0.0, half)]
        grid_psfs = []
        for x, y in grid_xy:
            if x == 0.0 and y == 0.0:
                grid_psfs.append(psf / psf_exp.exposure_s)
                continue
            h, exposure, _ = capture_psf(x, y)
            grid_psfs.append(h / exposure.exposure_s)
        grid = PsfGrid.from_positions(np.stack(grid_psfs), grid_xy, z_mm=z_mm,
                                      d_mm=bench.geometry.d_mm)
        t = step(f"PSF grid 3 x 3 over +-{half:.1f} mm (the field's PSFs and brightness)", t)
        scene = PlanarScene(data.camera().astype(float) / 255.0, z_mm, width_mm)
        bench.set_scene(scene)
        stage.move_to({"z": stage.limits["z"][1]}, timeout_s=60.0)  # pinhole out of the way
        scene_exp = autoexpose(cam, dark_level=offset)
        scene_raw, scene_meta = average_frames(cam, frames)
        bench.set_scene(None)
        dark, _ = average_frames(cam, frames)
        bench.set_scene(scene)
        raw = scene_raw - dark
        t = step(f"scene capture (exposure {scene_exp.exposure_s * 1e3:.2f} ms)", t)
        truth = bench.scene_truth()
    if method == "auto":
        rec = reconstruct(grid, raw, "admm", model="auto", two_part=True, dark="none",
                          background="none", iterations=iterations, tv="auto")
        image, uncorrected = rec.image, rec.image * rec.operator.brightness
        recon_metrics = rec.metrics()
        t = step(f"reconstruction ({rec.choice.label()} model of the PSF grid's caustics: "
                 f"{rec.choice.reason}; ADMM, TV {rec.info['tv']:.3g}, "
                 f"{rec.info['iterations_used']} iterations; brightness divided out)", t)
    else:
        result = reconstruct(psf, raw, method, iterations=iterations, dark="none")
        t = step(f"reconstruction (on-axis PSF, {result.info['method']}, TV "
                 f"{result.info['tv']:.3g}, {result.info['iterations_used']} iterations)", t)
        uncorrected, recon_metrics = result.image, result.metrics()
        image = correct_brightness(result.image, grid)
        t = step("brightness correction (Eq. 5.1, from the PSF grid)", t)
    shift, truth_reg = register_truth(image, truth)
    score = {"psnr_db": psnr(image, truth_reg), "ssim": ssim(image, truth_reg),
             "registration_shift_px": list(shift),
             "uncorrected": {"psnr_db": psnr(uncorrected, truth_reg),
                             "ssim": ssim(uncorrected, truth_reg)}}
    save_image(out / "psf.tif", psf.astype(np.float32))
    save_image(out / "psf_grid.tif", grid.psfs)
    save_image(out / "dark.tif", dark.astype(np.float32))
    save_image(out / "scene_raw.tif", scene_raw.astype(np.float32))
    save_image(out / "reconstruction.png", scene_view(image))
    save_image(out / "reconstruction.tif", image)
    save_image(out / "truth.png", scene_view(truth_reg))
    report = {
        "bench": bench.config.name, "seed": seed, "z_mm": z_mm,
        "geometry": {"sensor_shape": list(bench.geometry.sensor_shape),
                     "sensor_pitch_um": bench.geometry.sensor_pitch_um,
                     "d_mm": bench.geometry.d_mm,
                     "aperture_mm": list(bench.geometry.aperture_mm),
                     "min_z_mm": bench.model.min_z_mm()},
        "exposure_s": {"psf": psf_exp.exposure_s, "scene": scene_exp.exposure_s},
        "frames_averaged": frames,
        "psf_grid": {"positions_mm": [list(p) for p in grid_xy],
                     "relative_brightness": node_brightness(grid).tolist(),
                     "file": "psf_grid.tif (registered, per second of exposure)"},
        "frames": {"psf": psf_meta, "scene": scene_meta},
        "reconstruction": {k: v for k, v in recon_metrics.items()
                           if k not in ("objective", "data_residual")},
        "score_vs_known_scene": score,
        "orientation": {"png": "scene, upright", "tif": DATA_ORIENTATION},
        "timings_s": timings,
        "total_s": time.perf_counter() - t0,
    }
    write_json(out / "report.json", report)
    step(f"wrote {out} (PSNR {score['psnr_db']:.2f} dB, SSIM {score['ssim']:.3f})", t)
    return report
