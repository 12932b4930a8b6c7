"""The spatially varying models' benchmarks (quick mode) and their tables."""

import json

from recon.benchmarks.run import BENCHMARKS, format_result
from recon.benchmarks.spatial import run_spatial_speed


def test_spatial_speed_quick_reports_ratios_and_memory(tmp_path):
    assert {"spatial_speed", "spatial_accuracy"} <= set(BENCHMARKS)
    r = run_spatial_speed(True, tmp_path)
    size = r["sizes"][0]
    assert size["kernels"] == 25 and size["local_ratio"] > 0.3
    assert set(size["pca"]) == {"1", "3", "5", "10"}
    mem = r["memory"]
    # 250 kernel spectra of a 2160 x 3840 padded grid: 8.3e9 B; PCA k = 3: 30 of them
    assert 8e9 < mem["local_5x5_10_depths"]["kernel_spectra"] < 9e9
    assert mem["pca_k3_10_depths"]["total"] < mem["local_5x5_10_depths"]["total"] / 3
    c = r["estimate_check"]
    assert 0.5 < c["built_operator_bytes"] / c["estimate_operator_bytes"] < 2.0
    assert json.loads((tmp_path / "spatial_speed.json").read_text())["goal"] == 1.5
    assert "local/floor" in format_result("spatial_speed", r)
