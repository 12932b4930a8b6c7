"""``diffuserlab analyze design`` and ``python -m benchmarks.design``: a small successful run, bad
options (one line, exit 2, nothing written) and existing outputs kept."""

from __future__ import annotations

import json

import pytest

from instrument.cli import main

SMALL = ["--sensor-px", "96", "--pitch-um", "23.2"]


def test_analyze_design_writes_plot_and_json(tmp_path, capsys):
    out = tmp_path / "a"
    assert main(["analyze", "design", *SMALL, "--regular", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "12 field positions" in text and "ghost inner product" in text
    rec = json.loads((out / "design.json").read_text())
    assert rec["layout"] == "regular" and rec["threshold"] == 0.8
    (depth,) = rec["depths"]
    assert depth["z_mm"] == pytest.approx(1 / (1 / 1.5 - 1 / 3.8))
    assert len(depth["positions"]) == 12
    assert depth["summary"]["ghost_inner_product"]["min"] > 0.8  # periodic: ghosts
    assert (out / "design.png").stat().st_size > 10_000
    # an existing result is kept without --overwrite
    before = (out / "design.json").read_bytes()
    assert main(["analyze", "design", *SMALL, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and "--overwrite" in err[0]
    assert (out / "design.json").read_bytes() == before


@pytest.mark.parametrize("extra, words", [
    (["--focal-mm", "5"], ["--focal-mm 5", "--distance-mm"]),
    (["--lenslet-um", "0"], ["--lenslet-um"]),
    (["--pitch-um", "nan"], ["--pitch-um"]),
    (["--z-mm", "2,-1"], ["--z-mm"]),
    (["--z-mm", "two"], ["--z-mm"]),
    (["--threshold", "1.5"], ["--threshold"]),
    (["--falloff-deg", "-1"], ["--falloff-deg"]),
    (["--sensor-px", "40"], ["--sensor-px 40", "lenslet images"]),
    (["--sensor-px", "5000"], ["--sensor-px"]),
])
def test_analyze_design_bad_options(tmp_path, capsys, extra, words):
    out = tmp_path / "a"
    assert main(["analyze", "design", *SMALL, *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("diffuserlab: error:"), err
    for w in words:
        assert w in err[0], err
    assert not out.exists()


def test_analyze_design_layouts_exclusive(capsys):
    with pytest.raises(SystemExit) as info:
        main(["analyze", "design", "--random", "--regular"])
    assert info.value.code == 2
    assert "not allowed with" in capsys.readouterr().err


def test_benchmark_design_keeps_earlier_results(tmp_path, capsys):
    out = tmp_path / "b"
    out.mkdir()
    (out / "design.json").write_text("{}")
    from benchmarks.design import main as design

    assert design(["--quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0]
    assert (out / "design.json").read_text() == "{}" and not (out / "design.png").exists()
