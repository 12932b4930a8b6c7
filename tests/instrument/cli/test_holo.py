"""``diffuserlab holo evaluate`` and ``holo benchmark``: the command lines of the
Table 7.1 evaluation and the hologram speed benchmark (quick runs)."""

from __future__ import annotations

import json

import numpy as np

from instrument.cli import main
from recon.cgh.evaluation import METHODS


def test_evaluate_cli_quick_on_a_folder(tmp_path):
    rng = np.random.default_rng(1)
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for i in range(2):
        np.save(imgs / f"im{i}.npy", rng.random((30, 40)))
    out = tmp_path / "out"
    assert main(["holo", "evaluate", "--quick", "--images", str(imgs), "--out", str(out)]) == 0
    for f in ("records.csv", "summary.json", "table.md", "psnr_vs_seconds.png"):
        assert (out / f).stat().st_size > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["n_images"] == 2
    assert {c["method"] for c in summary["cells"]} == set(METHODS)
    assert "Table 7.1" in (out / "table.md").read_text()
    assert main(["holo", "evaluate", "--images", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert main(["holo", "evaluate", "--size", "100", "--factors", "36", "--images",
                 str(imgs), "--out", str(out)]) == 2  # 100 is not divisible by 6


def test_benchmark_quick(tmp_path, capsys):
    js = tmp_path / "bench.json"
    assert main(["holo", "benchmark", "--quick", "--json", str(js)]) == 0
    rep = json.loads(js.read_text())
    assert rep["grid"] == [144, 256] and rep["iterations"] == 10
    assert 3.5 <= rep["ffts_per_iteration"] < 5.0
    assert rep["ratio"] > 0 and rep["peak_traced_mb"] > 0
    assert "s/iteration =" in capsys.readouterr().out
    assert main(["holo", "benchmark", "--quick", "--factor", "15"]) == 2


def test_holo_evaluate_is_wired(tmp_path, capsys):
    assert main(["holo", "evaluate", "--quick", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "table.md").is_file() and (tmp_path / "summary.json").is_file()
    assert "wrote" in capsys.readouterr().out
