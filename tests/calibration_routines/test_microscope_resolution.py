"""Two-point resolution of the calibrated virtual microscope (Fig. 6.4a)."""

import json
from pathlib import Path

import pytest

from calibration_routines.microscope import calibrate_microscope
from calibration_routines.microscope_resolution import resolution_table
from instrument.devices.bench_setup import load_bench
from instrument.devices.virtual_bench import VirtualBench

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "bench-microscope.toml"


@pytest.mark.slow
def test_calibration_with_resolution_check_on_a_small_grid(tmp_path):
    """A 3 x 3 grid at 2.4 mm on the microscope binned to 68 x 120; pairs ray traced
    (about 40 s of CPU; measured 59 um = 2 px at all five positions)."""
    text = EXAMPLE.read_text().replace("[135, 240]", "[68, 120]").replace(
        "pixel_pitch_um = 23.2", "pixel_pitch_um = 46.4")
    (tmp_path / "b.toml").write_text(text)
    with VirtualBench(load_bench(tmp_path / "b.toml"), seed=1) as vb:
        calibrate_microscope(vb, tmp_path / "runs", n=3, frames_per_point=1, depths_mm=[2.4],
                             resolution_check=True)
    found = json.loads((tmp_path / "runs" / "resolution.json").read_text())
    assert len(found) == 1 and found[0]["truth"] == "ray-traced"
    res = [p["resolution_um"] for p in found[0]["positions"]]
    assert len(res) == 5 and all(r is not None and 25 < r < 120 for r in res)
    assert "um" in resolution_table(found)
