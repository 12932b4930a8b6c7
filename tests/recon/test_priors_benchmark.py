"""The priors benchmark (benchmarks.priors) on a tiny configuration."""

from __future__ import annotations

from benchmarks.priors import plot_priors, priors_table, run_scene


def test_one_scene_reports_every_prior_the_choice_and_the_chart(tmp_path):
    cfg = {"coarse_bin": 16, "iterations": 20, "read_noise_e": 3.0, "dark_e": 100.0,
           "grids": {"tv": (1e-4, 1e-3), "wavelet": (3e-4,), "dncnn": (0.2,)}}
    c = run_scene("camera", cfg)
    assert set(c["priors"]) == {"tv", "wavelet", "dncnn"}
    for p, rec in c["priors"].items():
        assert [g["weight"] for g in rec["grid"]] == list(cfg["grids"][p])
        assert rec["oracle"]["psnr"] == max(g["psnr"] for g in rec["grid"])
        a = rec["auto"]
        assert a["prior"] == p and a["psnr"] is not None and a["time_ratio"] > 0
    tv_oracle = c["priors"]["tv"]["oracle"]["psnr"]
    assert c["gain_over_tv_oracle_db"] == c["auto"]["psnr"] - tv_oracle
    # the automatic prior's image is its chosen prior's automatic-weight image
    chosen = c["priors"][c["auto"]["prior"]]["auto"]
    assert abs(chosen["psnr"] - c["auto"]["psnr"]) < 1e-9
    assert c["best_prior"] in c["priors"] and c["auto"]["reason"]
    result = {"cases": [c], "setup": {"iterations": 20, "coarse_bin": 16}, "summary": {
        "mean_gain_over_tv_oracle_db": c["gain_over_tv_oracle_db"],
        "worst_gain_over_tv_oracle_db": c["gain_over_tv_oracle_db"], "chosen_is_best": 1}}
    assert "camera" in priors_table(result)
    assert plot_priors(result, tmp_path / "p.png").stat().st_size > 5000
