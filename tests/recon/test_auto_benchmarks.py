"""The auto-vs-oracle benchmark and the failure maps, on tiny configurations."""

from __future__ import annotations

import math

import numpy as np

from benchmarks.auto import auto_table, cost_in_turn, plot_budget, run_case
from benchmarks.auto_scenes import KINDS, make_scene
from benchmarks.failure_maps import _cell, failure_maps_table, plot_map


def test_scene_kinds_are_non_negative_with_unit_peak():
    for kind in ("photo:camera", "photo:brick", *KINDS):
        s = make_scene(kind, (120, 160))
        assert s.shape == (120, 160) and s.min() >= 0 and s.max() == 1.0, kind
        assert s[:5].max() == 0  # inset: a dark surround
    beads = make_scene("beads", (120, 160), density=0.002)
    assert np.mean(beads > 0.1) < 0.05  # sparse


def test_run_case_reports_oracle_default_budgets_and_the_chart(tmp_path):
    cfg = {"coarse_bin": 8, "iterations": 40, "grid": (1e-4, 1e-3), "refine": 10 ** 0.5,
           "timing_repeats": 2, "dark_e": 100.0, "budget_scenes": ("beads",),
           "budget_factors": (2.0,)}
    c = run_case("beads", "beads", 3000.0, cfg)
    # the cost: each pair's ratio (a fixed solve, then the default, in turn), in wall
    # and in CPU time; with one pair its ratio
    assert len(c["auto"]["seconds_runs"]) == 1 and len(c["fixed_seconds_runs"]) == 1
    assert c["auto_cost_ratio"] == c["auto"]["seconds"] / c["fixed_seconds"]
    assert c["auto_cost_ratio_runs"] == [c["auto_cost_ratio"]]
    assert c["auto_cost_ratio_cpu"] > 1.0 and c["auto_cost_ratio_cpu_runs"] == [
        c["auto_cost_ratio_cpu"]]
    # the oracle: the grid refined either side of its best
    assert len(c["grid"]) == 4 and c["oracle"]["psnr"] == max(g["psnr"] for g in c["grid"])
    assert c["auto"]["psnr"] is not None and not c["auto"]["blank"]
    assert c["auto"]["stop_reason"] and c["auto"]["candidates"] >= 1
    assert c["auto_shortfall_db"] == c["oracle"]["psnr"] - c["auto"]["psnr"]
    (b,) = c["budgets"]
    assert b["seconds_asked"] == 2.0 * c["fixed_seconds"] and b["psnr"] is not None
    result = {"cases": [c], "summary": {
        "mean_shortfall_db": c["auto_shortfall_db"], "worst_shortfall_db": 0.0,
        "cost_ratio_median": 1.0, "cost_ratio_max": 1.0, "failures": [],
        "budget_overrun_max": 1.0}, "setup": cfg}
    table = auto_table(result)
    assert "beads" in table and "oracle" in table and "time budgets" in table
    assert plot_budget(result, tmp_path / "chart.png").stat().st_size > 5000


def test_the_cost_is_the_median_of_the_pairs_ratios():
    """Each pair (a fixed solve, then the default, taken in turn) gives a ratio; the
    cost is their median, not a ratio of medians of runs minutes apart."""
    fixed = iter([{"seconds": 1.0, "cpu_seconds": 2.0}, {"seconds": 4.0, "cpu_seconds": 2.0},
                  {"seconds": 2.0, "cpu_seconds": 2.0}])
    auto = iter([{"seconds": 3.0, "cpu_seconds": 7.0}, {"seconds": 12.0, "cpu_seconds": 7.2},
                 {"seconds": 7.0, "cpu_seconds": 6.8}])
    first = {"seconds": 99.0, "cpu_seconds": 99.0}
    cost = cost_in_turn(first, [], 4, lambda: next(fixed), lambda: next(auto))
    assert cost["ratio_runs"] == [3.0, 3.0, 3.5] and cost["ratio"] == 3.0
    # a ratio of medians would be 7 / 2 = 3.5
    assert cost["cpu_ratio"] == 3.5 and cost["fixed_seconds"] == 2.0
    assert first["seconds"] == 7.0 and first["seconds_runs"] == [3.0, 12.0, 7.0]
    # without repeats: over the median of the grid's solves
    grid = [{"seconds": 1.0, "cpu_seconds": 1.0}, {"seconds": 3.0, "cpu_seconds": 2.0},
            {"psnr": None}]
    cost = cost_in_turn({"seconds": 8.0, "cpu_seconds": 6.0}, grid, 1, None, None)
    assert cost["ratio"] == 4.0 and cost["cpu_ratio"] == 4.0
    assert math.isnan(cost_in_turn({"seconds": 1.0, "cpu_seconds": 1.0}, [{}], 1, None,
                                   None)["ratio"])


def test_failure_map_cell_and_figure(tmp_path):
    from benchmarks.auto_scenes import render_case

    case = render_case("beads", 300.0, coarse_bin=8)
    cell = _cell(case, None, ["wiener", "admm"], 20)
    assert set(cell) == {"wiener", "admm"}
    assert all("fails" in v for v in cell.values())
    fails = {"psnr": 10.0, "converged": False, "fails": True}
    ok = {"psnr": 30.0, "converged": True, "fails": False, "tv": 1e-4}
    rows = [[{"admm": ok, "auto": ok}, {"admm": fails, "auto": ok}],
            [{"admm": fails, "auto": fails}, {"admm": fails, "auto": fails}]]
    result = {"methods": ["admm", "auto"], "setup": {"bound_db": 20.0, "coarse_bin": 8,
                                                     "iterations": 20},
              "density": {"rows": [300.0, 3000.0], "cols": ["a", "b"], "cells": rows},
              "erasure": {"rows": [300.0], "cols": ["0"], "cells": [rows[0][:1]]}}
    path = plot_map(result, "density", tmp_path / "map.png", "x")
    assert path.stat().st_size > 5000
    text = failure_maps_table(result)
    assert "density admm: best 30.00 dB; fails at 3/4" in text


def test_failure_map_3d_quick(tmp_path):
    from benchmarks.failure_map_3d import failure_map_3d_table, run_failure_map_3d

    r = run_failure_map_3d(quick=True, out=tmp_path)
    cell = r["cells"][0][0]
    assert set(cell) == {"fista3d", "admm3d", "auto"}
    assert all(0.0 <= c["found"] <= 1.0 for c in cell.values())
    assert "planes_kept" in cell["auto"]
    assert (tmp_path / "failure_map_3d.png").stat().st_size > 5000
    assert "auto: fails at" in failure_map_3d_table(r)
