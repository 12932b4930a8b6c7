"""The documentation's benchmark pages are generated from the stored benchmark output
(docs/benchmarks/results/<run>/), never typed by hand."""

import json
from pathlib import Path

import pytest

from benchmarks.report import markdown_page
from benchmarks.run import BENCHMARKS, format_result
from recon.errors import ReconInputError

RESULTS = Path(__file__).resolve().parents[2] / "docs/benchmarks/results"
RUNS = sorted(p for p in RESULTS.iterdir() if p.is_dir())


def test_there_are_stored_runs():
    assert RUNS, f"no benchmark output under {RESULTS}"


@pytest.mark.parametrize("run", RUNS, ids=lambda p: p.name)
def test_page_shows_every_result_and_chart_of_the_run(run):
    page = markdown_page(run, "Benchmarks", figures_prefix=f"results/{run.name}/")
    names = [n for n in BENCHMARKS if (run / f"{n}.json").is_file()]
    assert names
    for name in names:  # the table the command prints, from the stored JSON
        table = format_result(name, json.loads((run / f"{name}.json").read_text()))
        assert table.strip().splitlines()[0] in page
    for png in run.glob("*.png"):
        assert f"](results/{run.name}/{png.name})" in page
    summary = json.loads((run / "summary.json").read_text())
    assert summary["machine"]["cpu_count"] >= 1
    assert f"{summary['machine']['cpu_count']} CPUs" in page


def test_a_directory_without_results_is_refused(tmp_path):
    with pytest.raises(ReconInputError, match="summary.json"):
        markdown_page(tmp_path, "x")
