"""calibrate psf-from-scenes from files reports each step as it ends and records the
PSF's quality figure (what the held-out PSFs buy a fixed reference reconstruction)."""

from __future__ import annotations

import re

import numpy as np

from instrument.cli import main
from instrument.runs.runstore import RunStore
from recon.analysis.early_stop import THRESHOLDS
from recon.analysis.sensor_response import ROUNDS as SENSOR_ROUNDS
from tests.recon.test_psf_quality import synthetic_pairs


def calibrate_files(tmp_path, scenes, measurements):
    """The pairs saved as ``p{i}.npy`` in ``scenes/`` and ``raw/`` under ``tmp_path``,
    calibrated by the command (which must succeed); returns the run's path."""
    (tmp_path / "scenes").mkdir()
    (tmp_path / "raw").mkdir()
    for i, (x, b) in enumerate(zip(scenes, measurements, strict=True)):
        np.save(tmp_path / f"scenes/p{i}.npy", x)
        np.save(tmp_path / f"raw/p{i}.npy", b)
    run = tmp_path / "cal.zarr"
    assert main(["calibrate", "psf-from-scenes", "--scenes", str(tmp_path / "scenes"),
                 "--measurements", str(tmp_path / "raw"), "--z-mm", "20",
                 "--out", str(run)]) == 0
    return run


def test_progress_lines_and_the_quality_figure(tmp_path, capsys):
    scenes, measurements, _ = synthetic_pairs(3, 9)
    run = calibrate_files(tmp_path, scenes, measurements)
    out = capsys.readouterr().out.splitlines()
    lines = [ln for ln in out if ln.startswith("[")]
    solves = 2 * len(THRESHOLDS) * 3  # each pair with its held-out PSF and the shipped one
    total = SENSOR_ROUNDS + 1 + 3 + solves
    assert len(lines) == total
    for i, line in enumerate(lines, 1):
        assert re.fullmatch(rf"\[{i}/{total}\] .+ \(\d+ s\)", line), line
    # First the sensor response's rounds, one after the other; then the four estimates
    # run as parallel jobs and are reported as each ends, in any order; the recipe's
    # solves follow them, counted as they end.
    for r in range(1, SENSOR_ROUNDS + 1):
        assert lines[r - 1].startswith(f"[{r}/{total}] sensor response: round {r} of "
                                       f"{SENSOR_ROUNDS}"), lines
    lines = lines[SENSOR_ROUNDS:]
    steps = [re.sub(r"^\[\d+/\d+\] | \(\d+ s\)$", "", ln) for ln in lines]
    assert sorted(s.split(":")[0] for s in steps[:4]) == [
        "PSF from 3 pair(s)", "PSF without p0", "PSF without p1", "PSF without p2"], steps
    for k, line in enumerate(lines[4:], 1):
        assert line.startswith(f"[{SENSOR_ROUNDS + 4 + k}/{total}] recipe: solve {k} of "
                               f"{solves}"), line
    summary = RunStore.open(run).attrs["summary"]
    recipe = summary["early_stop"]  # and one line on what recon --psf RUN will run
    kept = "kept" if recipe["field_response"] else "not kept"
    said = [ln for ln in out if ln.startswith("recipe")]
    assert len(said) == 1, out
    assert said[0].startswith(f"recipe: FISTA {recipe['iterations']} iterations"), said
    assert f"field response {kept} ({recipe['field_gain_db']:+.2f} dB" in said[0], said
    # the PSF was estimated with the sensor's shading (recon.analysis.sensor_response)
    assert summary["sensor_response"]["min"] > 0 and summary["sensor_response"]["grid_shape"]
    quality = summary["held_out_reference_db"]
    assert sorted(quality) == ["p0", "p1", "p2"] and all(v > 5 for v in quality.values())
    assert abs(summary["held_out_reference_db_mean"] - np.mean(list(quality.values()))) <= 0.01
