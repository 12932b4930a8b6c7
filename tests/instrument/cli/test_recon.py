"""The diffuserlab CLI: the real-data run, its outputs, and exit code 2 on bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import tifffile

from instrument.cli import main
from recon.auto.weight import path_budget
from recon.io import DATA_ORIENTATION, load_image
from tests.real_data import check_hand_image, sample_paths

ARTIFACTS = Path(__file__).resolve().parents[3] / "out" / "test-artifacts"


def test_cli_recon_real_sample(tmp_path, capsys):
    psf, raw = sample_paths()
    out = tmp_path / "hand.png"
    js = tmp_path / "m.json"
    rc = main(
        [
            "recon",
            "--psf",
            str(psf),
            "--raw",
            str(raw),
            "--method",
            "admm",
            "--iterations",
            "60",
            "--bin",
            "4",
            "--out",
            str(out),
            "--metrics-json",
            str(js),
        ]
    )
    assert rc == 0
    m = json.loads(js.read_text())
    for key in (
        "method",
        "iterations",
        "shape",
        "padded_shape",
        "seconds_total",
        "seconds_per_iteration",
        "fft_pair_seconds",
        "ratio_to_fft_floor",
        "final_relative_residual",
        "objective",
    ):
        assert key in m
    assert m["shape"] == [300, 400] and m["padded_shape"] == [600, 800]
    assert m["ratio_to_fft_floor"] == pytest.approx(
        m["seconds_per_iteration"] / m["fft_pair_seconds"]
    )
    # the automatic weight's path and the chosen weight's run on share one budget
    assert len(m["objective"][0]) == m["iterations_used"] <= path_budget(60)
    assert m["objective"][0][-1] < 0.01 * m["objective"][0][0]
    assert m["final_relative_residual"] < 0.05
    image = tifffile.imread(tmp_path / "hand.tif")
    assert image.dtype == np.float32
    check_hand_image(image)
    assert out.exists() and out.stat().st_size > 1000
    # the PNG view is the TIFF turned upright (rotated by 180 degrees)
    view = load_image(out).astype(float)
    clipped = np.clip(image, 0, np.percentile(image, 99.9))
    turned, same = (float(np.corrcoef(view.ravel(), c.ravel())[0, 1])
                    for c in (clipped[::-1, ::-1], clipped))
    assert turned > 0.99 and turned > same + 0.2, (turned, same)
    assert m["orientation"]["tiff"] == DATA_ORIENTATION
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shutil.copy(out, ARTIFACTS / "cli_admm_hand.png")
    assert "x FFT floor" in capsys.readouterr().out


def test_cli_erase(tmp_path):
    psf, raw = sample_paths()
    js = tmp_path / "m.json"
    rc = main(
        [
            "recon",
            "--psf",
            str(psf),
            "--raw",
            str(raw),
            "--method",
            "fista",
            "--iterations",
            "10",
            "--bin",
            "8",
            "--erase",
            "0.8",
            "--seed",
            "2",
            "--out",
            str(tmp_path / "e"),
            "--metrics-json",
            str(js),
        ]
    )
    assert rc == 0
    assert abs(json.loads(js.read_text())["erased_fraction"] - 0.8) < 0.02
    assert (tmp_path / "e.png").exists() and (tmp_path / "e.tif").exists()


def _npy(tmp_path, name, array):
    p = tmp_path / name
    np.save(p, array)
    return str(p)


def _bad_cases(tmp_path):
    rng = np.random.default_rng(0)
    good = rng.random((40, 48)).astype(np.float32)
    nan = good.copy()
    nan[3, 4] = np.nan
    text = tmp_path / "junk.tif"
    text.write_text("not a tiff")
    return {
        "missing file": (
            ["--psf", str(tmp_path / "none.tif"), "--raw", _npy(tmp_path, "r.npy", good)],
            "not found",
        ),
        "unreadable": (["--psf", str(text), "--raw", _npy(tmp_path, "r.npy", good)], "junk.tif"),
        "shape mismatch": (
            ["--psf", _npy(tmp_path, "p.npy", good), "--raw", _npy(tmp_path, "r2.npy", good[:30])],
            "shape",
        ),
        "nan": (
            ["--psf", _npy(tmp_path, "pn.npy", nan), "--raw", _npy(tmp_path, "r.npy", good)],
            "NaN",
        ),
        "zero psf": (
            [
                "--psf",
                _npy(tmp_path, "pz.npy", np.zeros_like(good)),
                "--raw",
                _npy(tmp_path, "r.npy", good),
            ],
            "zero",
        ),
        "negative psf": (
            ["--psf", _npy(tmp_path, "pneg.npy", -good), "--raw", _npy(tmp_path, "r.npy", good)],
            "no positive values",
        ),
        "bad erase": (
            [
                "--psf",
                _npy(tmp_path, "p.npy", good),
                "--raw",
                _npy(tmp_path, "r.npy", good),
                "--erase",
                "1.2",
            ],
            "erased fraction",
        ),
        "bad iterations": (
            [
                "--psf",
                _npy(tmp_path, "p.npy", good),
                "--raw",
                _npy(tmp_path, "r.npy", good),
                "--iterations",
                "0",
            ],
            "iterations",
        ),
    }


@pytest.mark.parametrize(
    "case",
    [
        "missing file",
        "unreadable",
        "shape mismatch",
        "nan",
        "zero psf",
        "negative psf",
        "bad erase",
        "bad iterations",
    ],
)
def test_cli_bad_input_exits_2(tmp_path, capsys, case):
    args, fragment = _bad_cases(tmp_path)[case]
    rc = main(["recon", *args, "--out", str(tmp_path / "o.png")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and err.startswith("diffuserlab: error:")
    assert fragment.lower() in err.lower()
    assert not (tmp_path / "o.png").exists()


def test_benchmark_recon_runs_the_3d_benchmarks(tmp_path, capsys):
    from benchmarks.run import BENCHMARKS as STUDIES
    from instrument.benchmarks.run import BENCHMARKS

    assert "volume_speed" in BENCHMARKS and {"volume_speed", "volume_accuracy"} <= set(STUDIES)
    assert main(["benchmark", "recon", "--quick", "--only", "volume_speed",
                 "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "volume_speed.json").read_text())
    assert data["memory"][0]["method"] == "admm3d"
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["volume_speed_ratio"]["64x64x4"]) == {"fista3d", "admm3d"}
    assert "3D speed 64x64x4" in capsys.readouterr().out


@pytest.mark.parametrize("field", [True, False])
def test_the_recipe_line_says_whether_the_recipe_has_a_field_response(field):
    """The terminal says what ran: a recipe with a field response darkens the field its
    calibration scenes left dark, and its line says so."""
    from instrument.cli.recon import choice_lines

    lines = choice_lines({"method": "fista", "calibration": {
        "psf_threshold": 0.0, "iterations": 90, "denoise_weight": 0.05,
        "field_response": field}})
    said = [ln for ln in lines if "scene-calibration recipe" in ln]
    assert len(said) == 1 and "90 FISTA iterations" in said[0]
    assert ("field response" in said[0]) is field, said
