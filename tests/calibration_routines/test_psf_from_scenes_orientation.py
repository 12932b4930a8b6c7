"""One orientation for a PSF calibrated from scenes, checked on the real pairs.

The scenes of ``calibrate psf-from-scenes`` (files or API) are on the model grid, the
scene rotated by 180 degrees (Kuo 2020 Eq. 3.3, u = -m x; recon.io.DATA_ORIENTATION):
the lensed camera's frames registered to the lensless one are exactly that (the shared
pairs' lensed images show their scenes upside down: im394's sunglasses below the
nose). ``recon --psf RUN`` then writes its TIFF on that grid and its PNG upright: the
PNG is the lensed truth rotated by 180 degrees, the TIFF the lensed truth as stored.
Fails loudly when the shared data is absent (tests/real_data.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from PIL import Image

from benchmarks.psf_from_scenes import NAMES, load_pairs
from calibration_routines.psf_from_scenes import psf_run_from_files
from instrument.cli import main


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """Three real pairs binned 3 x 3 (90 x 160) calibrate; a fourth is reconstructed."""
    tmp = tmp_path_factory.mktemp("orientation")
    scenes, measurements = load_pairs(names=NAMES[:4], bin_factor=3)
    for d in ("scenes", "raw"):
        (tmp / d).mkdir()
    for name, x, b in zip(NAMES[:3], scenes[:3], measurements[:3], strict=True):
        np.save(tmp / "scenes" / f"{name}.npy", x)
        np.save(tmp / "raw" / f"{name}.npy", b)
    np.save(tmp / "held.npy", measurements[3])
    run = tmp / "cal.zarr"
    psf_run_from_files([str(tmp / "scenes")], [str(tmp / "raw")], run, z_mm=100.0)
    return tmp, run, scenes[3]


def _correlation(a, b) -> float:
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    return float(np.corrcoef(a, b)[0, 1])


def test_the_png_is_upright_and_the_tiff_on_the_model_grid(calibrated, capsys):
    tmp, run, truth = calibrated
    for out in ("view.png", "data.tif"):
        code = main(["recon", "--psf", str(run), "--raw", str(tmp / "held.npy"), "--dark",
                     "none", "--out", str(tmp / out), "--metrics-json", str(tmp / f"{out}.json")])
        assert code == 0, capsys.readouterr().err
    png = np.asarray(Image.open(tmp / "view.png").convert("RGB"), float)
    tif = np.asarray(tifffile.imread(tmp / "data.tif"), float).reshape(truth.shape)
    upright = truth[::-1, ::-1]
    assert _correlation(png, upright) > _correlation(png, truth) + 0.2
    assert _correlation(tif, truth) > _correlation(tif, upright) + 0.2
    orientation = json.loads((tmp / "view.png.json").read_text())["orientation"]
    assert orientation["png"] == "scene, upright"


def test_a_run_psf_without_dark_names_dark_none(calibrated, capsys):
    tmp, run, _ = calibrated
    capsys.readouterr()
    assert main(["recon", "--psf", str(run), "--raw", str(tmp / "held.npy"),
                 "--out", str(tmp / "no_dark.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--dark none" in err and len(err.splitlines()) == 1, err
