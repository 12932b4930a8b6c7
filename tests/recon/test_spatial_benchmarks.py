"""The spatially varying models' benchmarks (quick mode) and their tables."""

import json

from benchmarks.run import BENCHMARKS, format_result
from benchmarks.spatial import run_spatial_speed


def test_spatial_speed_quick_reports_ratios_and_memory(tmp_path):
    assert {"spatial_speed", "spatial_accuracy"} <= set(BENCHMARKS)
    r = run_spatial_speed(True, tmp_path)
    size = r["sizes"][0]
    # the ratio is the benchmark's figure, judged there against its goal, not here: its
    # size moves with the machine's load (0.20 beside two suites and three busy loops)
    assert size["kernels"] == 25 and size["local_ratio"] > 0
    assert size["local_ratio"] == size["local_seconds"] / size["fft_floor_seconds"]
    assert size["meets_goal"] == (size["local_ratio"] <= json.loads(
        (tmp_path / "spatial_speed.json").read_text())["goal"])
    assert set(size["pca"]) == {"1", "3", "5", "10"}
    mem = r["memory"]
    # 250 kernel spectra of a 2160 x 3840 padded grid: 8.3e9 B; PCA k = 3: 30 of them
    assert 8e9 < mem["local_5x5_10_depths"]["kernel_spectra"] < 9e9
    assert mem["pca_k3_10_depths"]["total"] < mem["local_5x5_10_depths"]["total"] / 3
    c = r["estimate_check"]
    assert 0.5 < c["built_operator_bytes"] / c["estimate_operator_bytes"] < 2.0
    assert json.loads((tmp_path / "spatial_speed.json").read_text())["goal"] == 1.5
    assert "local/floor" in format_result("spatial_speed", r)


def _far_result():
    point = {"psnr_db": 20.0, "ssim": 0.6, "seconds": 1.0, "model": "local", "tv": 2e-4,
             "iterations_used": 400}
    return {"cases": [{"scene": "camera", "photons": 3000.0,
                       "methods": {"on-axis": dict(point, psnr_db=19.0),
                                   "two-part auto": dict(point, model="pca:4")}}],
            "convergence": {"tv": 2e-4, "n_kernels": 9,
                            "admm": [{"iterations": 100, "seconds": 1.0, "psnr_db": 19.0},
                                     {"iterations": 200, "seconds": 2.0, "psnr_db": 21.0}],
                            "fista": [{"iterations": 200, "seconds": 2.0, "psnr_db": 16.5}]}}


def test_spatial_far_table_summary_and_figure(tmp_path):
    from benchmarks.run import summarise
    from benchmarks.spatial_far import plot_spatial_far

    assert "spatial_far" in BENCHMARKS
    r = _far_result()
    text = format_result("spatial_far", r)
    assert "two-part auto" in text and "pca:4" in text and "16.50" in text
    summary, lines = summarise({"spatial_far": r})
    assert summary["spatial_far_gain_db"] == [1.0] and "1.00 dB above the on-axis" in lines
    path = plot_spatial_far(r, tmp_path / "far.png")
    assert path.stat().st_size > 10_000
