"""``diffuserlab benchmark memory-limit`` at a small size: ``recon3d`` in fresh processes
is refused (exit status 2) below every plan and just below the smallest limit it
names, and solves at that limit with a plan whose estimate is within it, the process's
peak measured; the table says which runs were within their limit. Whether the peaks
are within the limits is the benchmark's verdict (a measurement), not this test's.
"""

from __future__ import annotations

from instrument.benchmarks.memory_limit import memory_limit_table, run_memory_limit
from instrument.cli import main


def test_refused_below_and_solved_at_the_named_limit(tmp_path):
    lines = []
    result = run_memory_limit(sizes=((32, 3),), weights=("1e-4",), iterations=3,
                              work_dir=str(tmp_path), announce=lines.append)
    below, just_below, at, *others = result["runs"]
    assert below["limit"] == "1MB" and below["refused"] and below["exit_status"] == 2
    named = below["named_limit"]
    assert named.endswith("GB") and just_below["named_limit"] == named
    assert just_below["refused"] and just_below["limit_bytes"] < at["limit_bytes"]
    assert at["limit"] == named and at["exit_status"] == 0 and not at["refused"]
    assert at["estimate_bytes"] <= at["limit_bytes"] and at["peak_bytes"] > 0
    assert at["within"] == (at["peak_bytes"] <= at["limit_bytes"])
    assert all(r["exit_status"] == 0 and r["estimate_bytes"] <= r["limit_bytes"]
               for r in others)
    assert len(lines) == len(result["runs"])
    table = memory_limit_table(result)
    assert "refused (exit 2), names " + named in table
    assert ("all within" if result["all_within"] else "NOT ALL WITHIN") in table
    assert not list(tmp_path.iterdir())  # the problem files went with the run


def test_the_table_says_which_run_was_over():
    run = {"sensor": 32, "planes": 3, "tv": "1e-4", "limit": "0.30GB", "refused": False,
           "plan": "in-memory", "expected_plan": None, "estimate_bytes": 290_000_000,
           "peak_bytes": 310_000_000, "within": False, "seconds": 1.0, "exit_status": 0}
    text = memory_limit_table({"runs": [run], "all_within": False})
    assert "peak 0.310 GB OVER the limit" in text and "NOT ALL WITHIN: 0 of 1" in text


def test_bad_sizes_are_refused(capsys):
    assert main(["benchmark", "memory-limit", "--sizes", "256by8"]) == 2
    assert "--sizes '256by8'" in capsys.readouterr().err
    assert main(["benchmark", "memory-limit", "--iterations", "0"]) == 2
