"""The 3D auto benchmark (benchmarks.volume_auto) and the external-data benchmark
(benchmarks.volume_external): their metrics on known inputs, and one quick run
each. No timing thresholds (the machine is shared)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from benchmarks.volume_auto import (
    _apply_rule,
    object_metrics,
    run_volume_auto,
    volume_auto_table,
)
from benchmarks.volume_external import fine_structure, fine_structure_share
from instrument.benchmarks.volume_auto_scenes import render_volume_case
from recon.errors import ReconInputError


@pytest.fixture(scope="module")
def case():
    return render_volume_case("extended", 3000.0, n_planes=4, dim=10.0)


def test_object_metrics_of_the_truth_and_of_a_misplaced_object(case):
    exact = object_metrics(case, case.truth)
    assert all(o["within_one_plane"] and o["depth_plane"] == pytest.approx(o["plane"])
               for o in exact)
    assert [o["brightness"] for o in exact] == pytest.approx([1.0] * 4)
    moved = case.truth.copy()
    moved[0] += moved[3]  # the farthest object's light put on the nearest plane
    moved[3] = 0
    far = object_metrics(case, moved)[3]
    assert not far["within_one_plane"] and far["brightness"] == 0.0
    dim = case.truth.copy()
    dim[2] *= 0.5
    assert object_metrics(case, dim)[2]["brightness"] == pytest.approx(0.5)


def test_scene_dims_far_planes_and_leaves_unoccupied_planes_empty():
    c = render_volume_case("beads", 3000.0, n_planes=5, dim=30.0, occupied=(0, 2, 4))
    assert [o["plane"] for o in c.objects] == [0, 2, 4]
    assert [o["brightness"] for o in c.objects] == pytest.approx(
        [1.0, 30 ** -0.5, 1 / 30.0])
    assert not np.any(c.truth[[1, 3]]) and np.all(c.truth.sum(axis=(1, 2))[[0, 2, 4]] > 0)
    with pytest.raises(ReconInputError, match="dim"):
        render_volume_case("beads", 3000.0, dim=0.5)


def test_rules_on_a_recorded_path():
    """The rule study applies the rules as admm_auto does: the largest weight within
    se_rule standard errors of the minimum, at most bound x the minimum's weight."""
    path = [{"weight": w, "holdout_error": e, "standard_error": 0.1}
            for w, e in ((1e-3, 2.0), (4e-4, 1.05), (1.6e-4, 1.0), (6.4e-5, 0.98))]
    assert _apply_rule(path, 1.0, math.inf) == 4e-4
    assert _apply_rule(path, 1.0, 2.0) == pytest.approx(1.28e-4)
    assert _apply_rule(path, 0.0, 1.0) == 6.4e-5


def test_fine_structure_sees_texture_not_edges():
    rng = np.random.default_rng(0)
    block = np.zeros((64, 64))
    block[16:48, 16:48] = 1.0
    textured = block * (1 + 0.5 * rng.random((64, 64)))
    assert fine_structure(block) == pytest.approx(0.0, abs=1e-9)
    assert fine_structure(textured) > 0.05
    assert fine_structure_share(block, textured) < 0.01
    assert fine_structure_share(textured, textured) == pytest.approx(1.0)


def test_volume_auto_quick(tmp_path):
    r = run_volume_auto(quick=True, out=tmp_path)
    c = r["cases"][0]
    assert c["oracle"]["tv"] in r["setup"]["grid"] and c["auto"]["psnr"] is not None
    assert len(c["auto"]["objects"]) == r["setup"]["n_planes"]
    assert c["auto"]["planes_kept"] == list(range(r["setup"]["n_planes"]))
    assert r["summary"]["mean_shortfall_db"] == pytest.approx(c["auto_shortfall_db"])
    assert json.loads((tmp_path / "volume_auto.json").read_text())["setup"]["rule"]["tv"]
    assert "auto below oracle" in volume_auto_table(r)
    # without repeats the cost is over the grid's own solves
    grid_s = [g["seconds"] for g in c["grid"]]
    assert c["fixed_seconds"] == pytest.approx(float(np.median(grid_s)))
    assert r["summary"]["cost_ratio_max"] == pytest.approx(c["auto_cost_ratio"])


def test_volume_auto_times_the_default_in_turn_with_a_fixed_solve(tmp_path):
    """The default's cost is the median of runs taken in turn with fixed solves at the
    oracle's weight (the first, untimed-in-turn run dropped), as the 2D suite does."""
    from benchmarks.volume_auto import QUICK, run_case

    c = run_case("beads", 10.0, 3000.0, QUICK | {"timing_repeats": 3})
    assert len(c["auto"]["seconds_runs"]) == 2 and len(c["fixed_seconds_runs"]) == 2
    assert c["fixed_seconds"] == pytest.approx(float(np.median(c["fixed_seconds_runs"])))
    pairs = [a / f for a, f in zip(c["auto"]["seconds_runs"], c["fixed_seconds_runs"],
                                   strict=True)]
    assert c["auto_cost_ratio_runs"] == pytest.approx(pairs)
    assert c["auto_cost_ratio"] == pytest.approx(float(np.median(pairs)))
    assert c["auto_cost_ratio"] > 1.0  # the default solves a path of weights, then one
    assert len(c["auto_cost_ratio_cpu_runs"]) == 2 and c["auto_cost_ratio_cpu"] > 1.0


def test_volume_external_quick(tmp_path):
    from benchmarks.volume_external import run_volume_external, volume_external_table

    r = run_volume_external(quick=True, out=tmp_path)
    for name in ("fista3d", "admm3d"):
        m = r["methods"][name]
        assert len(m["seconds"]) == len(m["relative_residual"]) == r["setup"]["iterations"]
        assert m["relative_residual"][-1] < m["relative_residual"][0]
    lens = r["methods"]["lensless_fista"]
    assert "skipped" in lens or (lens["relative_residual"][-1] < lens["relative_residual"][0]
                                 and "lensless_vs_fista3d" in r["agreement"])
    assert 0.5 < r["agreement"]["admm3d_vs_fista3d_mip"] <= 1.0
    assert (tmp_path / "volume_external.png").stat().st_size > 10000
    assert "recon3d default" in volume_external_table(r)
