"""``scripts/compare_benchmarks.py``: two runs of the benchmarks agree when every value
that does not depend on timing is equal (docs/architecture.md, "Benchmarks before and
after the move")."""

from __future__ import annotations

import json

from scripts.compare_benchmarks import compare_files, compare_values, main


def _result(psnr: float = 12.67, seconds: float = 0.30, ratio: float = 2.6,
            meets_goal: bool = True) -> dict:
    return {"scenes": {"camera": {"admm": {"psnr": psnr, "ssim": 0.374, "weight": 3e-4,
                                           "seconds": seconds}}},
            "methods": {"admm": {"ratio": ratio, "goal": 3.0, "meets_goal": meets_goal,
                                 "seconds_per_iteration": seconds / 10}},
            "counts": [100, 0], "wall_seconds": 40.0 * seconds, "failure": None}


def test_timing_differs_results_equal():
    r = compare_values(_result(), _result(seconds=0.51, ratio=3.4, meets_goal=False))
    assert r.same
    assert r.equal == r.values - r.timing == 7
    # seconds, s/iteration, wall seconds, the ratio and its goal's verdict
    assert sorted("/".join(p) for p, _, _ in r.timing_differ) == [
        "methods/admm/meets_goal", "methods/admm/ratio",
        "methods/admm/seconds_per_iteration", "scenes/camera/admm/seconds", "wall_seconds"]


def test_a_result_that_differs_is_reported():
    r = compare_values(_result(), _result(psnr=12.67 + 1e-6))
    assert not r.same
    assert [p for p, _, _ in r.differ] == [("scenes", "camera", "admm", "psnr")]
    assert compare_values(_result(), _result(psnr=12.67 * (1 + 1e-12))).same


def test_a_goal_verdict_without_a_ratio_is_a_result():
    a = {"meets_goal": True, "shortfall_db": -0.3}
    assert not compare_values(a, {"meets_goal": False, "shortfall_db": -0.3}).same


def test_nan_equals_nan_and_missing_values_count():
    assert compare_values({"x": float("nan")}, {"x": float("nan")}).same
    r = compare_values({"x": 1, "y": [1, 2]}, {"x": 1, "y": [1]})
    assert not r.same and r.missing == [(("y", "[1]"), 2, "<absent>")]


def test_folders_and_exit_status(tmp_path, capsys):
    before, after = tmp_path / "before", tmp_path / "after"
    for root, res in ((before, _result()), (after, _result(seconds=0.9))):
        (root / "sub").mkdir(parents=True)
        (root / "sub" / "accuracy.json").write_text(json.dumps(res))
    assert main([str(before), str(after)]) == 0
    assert "sub/accuracy.json: 7 of 7 values equal; timing 3 of 5 differ" in (
        capsys.readouterr().out)
    (after / "sub" / "accuracy.json").write_text(json.dumps(_result(psnr=11.0)))
    (after / "extra.json").write_text("{}")
    assert main([str(before), str(after)]) == 1
    out = capsys.readouterr().out
    assert "DIFFERS scenes/camera/admm/psnr: 12.67 -> 11.0" in out
    assert "extra.json: only after" in out
    assert compare_files(before, after)["extra.json"] == "only after"
    assert main([str(before), str(tmp_path / "absent")]) == 2
    assert "no such file or folder" in capsys.readouterr().err
