"""The real-data benchmark (benchmarks.real_data) on two of the shared mirflickr pairs,
binned 6 x 6 (45 x 80), few iterations: it runs, writes its JSON with every column, the
contact sheet and the chart; LenslessPiCam's column is optional. Skipped only where the
shared data directory is absent; a missing pair there fails loudly."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from benchmarks import real_data
from benchmarks.psf_from_scenes import default_data_dir
from recon.preprocess.binning import box_bin

_KEYS = {"pair", "method", "weight", "psnr_db", "ssim", "seconds", "time_ratio", "tiling",
         "tiling_truth"}

if not default_data_dir().parent.is_dir():
    pytest.skip(f"no shared data directory ({default_data_dir().parent})",
                allow_module_level=True)

_FAKE_LENSLESS = '''
import numpy as np


class ADMM:
    """Stands in for LenslessPiCam's ADMM: returns the measurement as it came."""

    def __init__(self, psf):
        self.psf = psf

    def set_data(self, data):
        self.data = data

    def apply(self, n_iter=None, disp_iter=None, plot=False):
        self.n_iter = n_iter
        return self.data
'''


@pytest.fixture
def isolated_lensless(monkeypatch):
    """No ``lensless`` imported or on the path beyond what the test puts there."""
    monkeypatch.delitem(sys.modules, "lensless", raising=False)
    monkeypatch.delenv(real_data.LENSLESS_ENV, raising=False)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if "lensless" not in p])
    yield
    sys.modules.pop("lensless", None)


def _run(tmp_path, methods, **kw):
    args = dict(pairs=3, bin_factor=6, iterations=5, weights=(1e-4, 1e-3), log=lambda s: None)
    return real_data.run_benchmark(tmp_path, methods=methods, **{**args, **kw})


def test_every_column_on_three_binned_pairs(tmp_path, isolated_lensless, monkeypatch):
    """Each method of METHODS and one added entry: a row per pair (and weight of an
    oracle), finite scores, the time ratio over the same run's FFT floor, the oracle's
    weight the best mean of its grid; the JSON holds exactly what was returned."""
    pkg = tmp_path / "site" / "lensless"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(_FAKE_LENSLESS)
    monkeypatch.setenv(real_data.LENSLESS_ENV, str(tmp_path / "site"))
    extra = real_data.Method("measurement", "the measurement itself",
                             lambda psf, raw, weight, iterations: raw)
    out = tmp_path / "out"
    result = _run(out, [*real_data.METHODS, extra])
    saved = json.loads((out / "real_data.json").read_text())
    assert saved == json.loads(json.dumps(result))
    names = [m.name for m in real_data.METHODS] + ["measurement"]
    assert [m["name"] for m in saved["methods"]] == names
    assert all("skipped" not in m for m in saved["methods"])
    assert [m["method"] for m in saved["means"]] == names
    floor = saved["fft_floor_seconds"]
    assert floor > 0 and saved["setup"]["shape"] == [45, 80]
    for m in real_data.METHODS + [extra]:
        rows = [r for r in saved["rows"] if r["method"] == m.name]
        weights = [1e-4, 1e-3] if m.oracle else [None]
        assert sorted((r["pair"], str(r["weight"])) for r in rows) == sorted(
            (p, str(w)) for p in ("im43", "im157", "im189") for w in weights)
        for r in rows:
            calibrated = {"calibration_seconds", "recipe"} | (
                {"family_oracle"} if m.scores_family else set())
            assert set(r) == (_KEYS | calibrated if m.calibrate else _KEYS)
            if m.calibrate:
                assert r["calibration_seconds"] > 0 and r["recipe"]["iterations"] >= 10
            if m.calibrate and m.scores_family:  # its grid's best bounds it
                assert r["family_oracle"]["best"]["psnr_db"] >= r["family_oracle"][
                    "fitted"]["psnr_db"]
                assert r["family_oracle"]["fitted"]["psnr_db"] == pytest.approx(
                    r["psnr_db"], abs=0.05)
            assert np.isfinite([r["psnr_db"], r["ssim"], r["seconds"]]).all()
            assert r["time_ratio"] == pytest.approx(r["seconds"] / floor)
            truth = box_bin(np.load(default_data_dir() / "lensed" / f"{r['pair']}.npy"), 6)
            assert r["tiling_truth"] == pytest.approx(real_data.tiling_score(truth))
            assert 0 <= r["tiling"] <= 1
        by_w = {w: np.mean([r["psnr_db"] for r in rows if r["weight"] == w]) for w in weights}
        entry = next(x for x in saved["methods"] if x["name"] == m.name)
        assert by_w[entry["weight"]] == max(by_w.values())
        assert entry["weight_at_grid_edge"] is m.oracle  # a grid of two: both are edges
    assert (out / "contact.png").stat().st_size > 0
    assert (out / "speed_accuracy.png").stat().st_size > 0


def test_scene_recipe_needs_three_pairs_one_line(tmp_path):
    lines = []
    recipe = [m for m in real_data.METHODS if m.calibrate is not None]
    result = real_data.run_benchmark(tmp_path, pairs=2, bin_factor=6, methods=recipe,
                                     log=lines.append)
    assert "three pairs" in result["methods"][0]["skipped"]
    assert any("three pairs" in line for line in lines) and result["rows"] == []


def test_lensless_column_left_out_with_one_line_when_not_importable(tmp_path,
                                                                   isolated_lensless):
    lines = []
    lensless = [m for m in real_data.METHODS if m.name == "lensless-admm"]
    result = real_data.run_benchmark(tmp_path, pairs=2, bin_factor=6, iterations=3,
                                     methods=lensless, log=lines.append)
    assert result["methods"] == [{"name": "lensless-admm", "label": lensless[0].label,
                                  "skipped": real_data.LENSLESS_HINT}]
    assert result["rows"] == [] and result["means"] == []
    assert real_data.LENSLESS_HINT in lines and "\n" not in real_data.LENSLESS_HINT
    assert json.loads((tmp_path / "real_data.json").read_text())["methods"][0]["skipped"]


@pytest.mark.parametrize("argv, word", [(["--weights", "a,b"], "--weights"),
                                        (["--methods", "nope"], "--methods"),
                                        (["--iterations", "0"], "--iterations")])
def test_bad_options_one_line_exit_2(tmp_path, capsys, argv, word):
    assert real_data.main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert word in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_an_earlier_run_is_not_overwritten_unless_asked(tmp_path, capsys):
    """An --out holding real_data.json is refused before any work, the file unchanged."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "real_data.json").write_text("earlier")
    argv = ["--pairs", "2", "--bin", "6", "--iterations", "2", "--weights", "1e-3",
            "--methods", "admm-tv-oracle", "--out", str(out)]
    assert real_data.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "real_data.json" in err and len(err.splitlines()) == 1
    assert (out / "real_data.json").read_text() == "earlier"
    assert real_data.main([*argv, "--overwrite"]) == 0
    assert json.loads((out / "real_data.json").read_text())["means"][0]["weight"] == 1e-3


def test_the_peer_with_the_field_response_is_its_image_times_the_recipes(
        tmp_path, isolated_lensless, monkeypatch):
    """``lensless-admm-field`` multiplies LenslessPiCam's image (here the fake's: the
    measurement) by the field response of the pair's recipe, and by nothing when the
    recipe kept none."""
    from recon.early_stop import EarlyStop
    from recon.field_response import apply_field_response

    pkg = tmp_path / "site" / "lensless"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(_FAKE_LENSLESS)
    monkeypatch.setenv(real_data.LENSLESS_ENV, str(tmp_path / "site"))
    column = next(m for m in real_data.METHODS if m.name == "lensless-admm-field")
    assert column.calibrate is not None and not column.scores_family
    raw = np.random.default_rng(0).random((12, 16, 3)).astype(np.float32)
    psf = np.ones_like(raw)
    grid = np.array([[0.0, 1.0], [2.0, 3.0]])
    recipe = EarlyStop(10, (10,), np.zeros((1, 1, 1, 2)), "0" * 64, field_response=grid,
                       field_gain_db=1.0)
    out = column.solve(psf, raw, None, 3, recipe=recipe)
    assert np.allclose(out, apply_field_response(raw, grid))
    plain = column.solve(psf, raw, None, 3, recipe=EarlyStop(10, (10,), np.zeros((1, 1, 1, 2)),
                                                             "0" * 64))
    assert np.allclose(plain, raw)
