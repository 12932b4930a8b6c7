"""`calibrate` and `align mask` check their outputs and input runs before the bench
opens, and every stage target, exposure and LED before the first move: one error line, exit 2,
nothing written."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from instrument.cli import main


def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    assert main(["calibrate", "dark", "--simulate", "--frames", "2",
                 "--out", str(d / "dark.zarr")]) == 0
    (d / "file.txt").write_text("a file\n")
    return d


CASES = {
    "falloff run of another routine": (
        ["calibrate", "psf-grid", "--simulate", "--falloff-run", "{d}/dark.zarr",
         "--out", "{d}/grid.zarr"], "is a 'dark-flat' run, not an angular-response run"),
    "falloff run missing": (
        ["calibrate", "psf-grid", "--simulate", "--falloff-run", "{d}/none.zarr",
         "--out", "{d}/grid.zarr"], "no run store at"),
    "out exists": (["calibrate", "dark", "--simulate", "--out", "{d}/dark.zarr"],
                   "exists; pass --overwrite"),
    "out under a regular file": (
        ["calibrate", "dark", "--simulate", "--out", "{d}/file.txt/run.zarr"],
        "a file of that name exists"),
    "overwrite onto a regular file": (
        ["calibrate", "dark", "--simulate", "--out", "{d}/file.txt", "--overwrite"],
        "it is not a diffuserlab run store"),
    "out is the falloff run": (
        ["calibrate", "psf-grid", "--simulate", "--falloff-run", "{d}/dark.zarr",
         "--out", "{d}/dark.zarr", "--overwrite"], "is the input --falloff-run"),
    "sweep beyond the stage travel": (
        ["calibrate", "psf-sweep", "--simulate", "--z-min", "30", "--z-max", "300",
         "--n-depths", "3", "--out", "{d}/sweep.zarr"],
        "point 3 of 3 {'z_mm': 300.0}: source_stage: target z=300 mm is outside the limits"),
    "dark exposure beyond the camera's range": (
        ["calibrate", "dark", "--simulate", "--exposure-s", "1000", "--out", "{d}/d2.zarr"],
        "camera: exposure_s=1000.0 is not a number in range"),
    "align out exists": (["align", "mask", "--simulate", "--out", "{d}/file.txt"],
                         "an alignment record is never replaced"),
    "align out inside a run store": (
        ["align", "mask", "--simulate", "--out", "{d}/dark.zarr/x.align"],
        "is inside the run store"),
    "align out inside the lut": (
        ["align", "mask", "--simulate", "--lut", "{d}/dark.zarr", "--out",
         "{d}/dark.zarr/x.align"], "is inside the input --lut"),
}


@pytest.mark.parametrize("name", CASES)
def test_refused_before_the_bench_opens(d, name, capsys):
    argv, expected = CASES[name]
    before = _tree(d)
    assert main([a.format(d=d) for a in argv]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err, err
    assert expected in err
    assert "opened" not in cap.out + cap.err and "Traceback" not in err
    assert _tree(d) == before
