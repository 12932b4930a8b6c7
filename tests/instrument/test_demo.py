"""The main job on the simulated bench: ``diffuserlab demo``."""

from __future__ import annotations

import json

import numpy as np
import tifffile
from skimage import data
from skimage.transform import resize

from instrument.acquisition.demo import run_demo
from instrument.cli import main
from recon.io import load_image

#: PSNR (gain-fitted, after a +-2 px registration) of the reconstruction against the
#: known scene; the demo measured 19.6 dB here (seed 0, 150 iterations, 2 frames); a
#: broken model, PSF capture or reconstruction falls to ~6-10 dB. So did the automatic
#: weight when its path at 150 iterations was coarse (steps of 5.6x): TV 1e-5 and
#: 10.7 dB (recon.auto.weight.path_budget).
PSNR_BOUND_DB = 15.0
#: With its defaults the demo must not fall below the 21.3 dB it measured before the
#: automatic weight compared settled solves (seeds 1-4 then: 21.5, 20.8, 21.1, 20.7);
#: it measures 21.80 dB (seeds 1-3: 21.29, 21.43, 20.58) with the spatially varying
#: model's final solve on all pixels, 20.65 dB with the fit-pixel iterate
#: (recon.auto.weight.FINAL_ON_ALL_PIXELS). The on-axis PSF with the former default TV
#: weight gave 18.3 dB, with the brightness divided out 19.9 dB.
DEFAULTS_GOAL_DB = 21.3


def test_demo_run_writes_the_run_and_beats_the_psnr_bound(tmp_path):
    lines = []
    report = run_demo(tmp_path, seed=0, iterations=150, frames=2, progress=lines.append)
    for name in ("psf.tif", "psf_grid.tif", "dark.tif", "scene_raw.tif", "reconstruction.png",
                 "reconstruction.tif", "truth.png", "report.json"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert tifffile.imread(tmp_path / "psf_grid.tif").shape == (9, 256, 320)
    # the field's brightness (Eq. 5.1) falls off from the axis: corners < edges < 1,
    # and dividing it out of the reconstruction brings it closer to the scene
    # (measured with the defaults: 19.8 -> 21.3 dB)
    rel = np.reshape(report["psf_grid"]["relative_brightness"], (3, 3))
    assert rel[1, 1] == 1.0 and 0.5 < rel[0, 0] < rel[0, 1] < 1.0
    score = report["score_vs_known_scene"]
    assert score["psnr_db"] > score["uncorrected"]["psnr_db"] + 0.5
    saved = json.loads((tmp_path / "report.json").read_text())
    assert saved["score_vs_known_scene"]["psnr_db"] == report["score_vs_known_scene"]["psnr_db"]
    assert report["score_vs_known_scene"]["psnr_db"] > PSNR_BOUND_DB
    assert report["score_vs_known_scene"]["ssim"] > 0.4
    # its time is reported, not judged: a loaded host made it slow (no benchmark times
    # the demo; the docs state no goal for it)
    steps = report["timings_s"]
    assert steps and all(v >= 0 for v in steps.values())
    assert report["total_s"] >= max(steps.values())
    assert any("PSF at z" in line for line in lines) and lines[-1].startswith("[")
    assert report["reconstruction"]["final_relative_residual"] < 0.1
    # PNG views show the scene upright (the model grid is inverted, u = -m x): the
    # scene's region in truth.png, resized, correlates with the upright scene
    truth_view = load_image(tmp_path / "truth.png").astype(float)
    rows, cols = np.nonzero(truth_view > 0.05 * truth_view.max())
    region = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    scene = resize(data.camera().astype(float), truth_view[region].shape, anti_aliasing=True)
    for name in ("truth.png", "reconstruction.png"):
        crop = load_image(tmp_path / name).astype(float)[region]
        upright, flipped = (float(np.corrcoef(crop.ravel(), s.ravel())[0, 1])
                            for s in (scene, scene[::-1, ::-1]))
        assert upright > 0.5 and upright > flipped + 0.3, (name, upright, flipped)
    assert report["orientation"]["tif"].startswith("model grid")


def test_demo_defaults_model_the_spatially_varying_field_and_reach_the_goal(tmp_path):
    """The default reconstruction uses the PSF grid: a model of its caustics chosen from
    their predicted model errors, ADMM, the TV weight by hold-out cross-validation."""
    lines = []
    report = run_demo(tmp_path, progress=lines.append)
    rec = report["reconstruction"]
    assert rec["method"] == "admm" and rec["two_part"] and rec["n_kernels"] > 1
    assert rec["model"]["label"] != "convolution" and "predicted model error" in rec[
        "model"]["reason"]
    assert rec["auto"]["weight"]["criterion"] == "holdout"
    assert rec["auto"]["weight"]["final_pixels"].startswith("all, from the chosen")
    assert any("caustics" in line and "ADMM, TV" in line for line in lines)
    assert report["score_vs_known_scene"]["psnr_db"] > DEFAULTS_GOAL_DB
    assert report["score_vs_known_scene"]["ssim"] > 0.6


def test_cli_demo_and_bad_bench_file(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "d"), "--iterations", "30"]) == 0
    assert (tmp_path / "d" / "report.json").exists()
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[geometry]\nsensor_pixel_pitch_um = '5 cm'\n")
    assert main(["validate", str(bad)]) == 2
    assert "sensor_pixel_pitch_um" in capsys.readouterr().err
