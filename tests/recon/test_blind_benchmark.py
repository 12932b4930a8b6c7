"""The compressive-calibration comparison (Fig. 5.4d) on a tiny virtual microscope."""

import json

import pytest

from benchmarks.blind import METHODS, PRESETS, run_blind_calibration
from benchmarks.run import BENCHMARKS, format_result
from recon.errors import ReconInputError


@pytest.mark.slow
def test_blind_benchmark_tiny_run_reports_every_method(tmp_path):
    """About 50 s of CPU (ray tracing, two blind calibrations); passed in 157 s loaded."""
    assert "blind_calibration" in BENCHMARKS
    r = run_blind_calibration(True, tmp_path, preset="tiny")
    assert list(r["methods"]) == list(METHODS)
    for name, m in r["methods"].items():
        assert len(m["inner"]) == 25 and 0 <= m["inner_min"] <= m["inner_mean"] <= 1.0001
        assert m["psnr_db"] > 5, name
    assert r["methods"]["centre"]["psfs"] == 1 and r["methods"]["grid"]["psfs"] == 9
    assert r["methods"]["blind"]["images"] == 9
    # the noise-free ray-traced PSFs at the nodes are the ceiling of every calibration
    oracle = r["methods"]["oracle"]
    assert all(oracle["inner_mean"] > m["inner_mean"] for k, m in r["methods"].items()
               if k != "oracle")
    saved = json.loads((tmp_path / "blind_calibration.json").read_text())
    assert set(saved["methods"]) == set(METHODS)
    assert (tmp_path / "blind_calibration.png").stat().st_size > 10_000
    assert "scene PSNR dB" in format_result("blind_calibration", r)


def test_blind_benchmark_needs_a_node_on_the_axis(tmp_path, monkeypatch):
    monkeypatch.setitem(PRESETS, "tiny", {**PRESETS["tiny"], "n_images": 4})
    with pytest.raises(ReconInputError, match="odd square"):
        run_blind_calibration(True, tmp_path, preset="tiny")
