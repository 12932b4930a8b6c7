"""`calibrate resume` checks that the bench resuming a run is the one that started it."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from instrument.cli import main
from instrument.config import default_bench
from instrument.runs.run_identity import bench_differences, resume_differences
from instrument.runs.runstore import RunStore

ROOT = Path(__file__).resolve().parents[3]
BENCH = ROOT / "examples" / "bench-simulated.toml"


def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _config() -> dict:
    return default_bench().model_dump(mode="json")


def test_differences_are_classified():
    rec = _config()
    cur = json.loads(json.dumps(rec))
    assert bench_differences(rec, cur) == []
    cur["geometry"]["diffuser_sensor_distance_mm"] = 9.5
    cur["name"] = "other"
    cur["devices"][1]["params"]["port"] = "/dev/ttyUSB3"
    cur["devices"][0]["params"]["adc_bits"] = 10
    cur["devices"] = cur["devices"][:-1]  # the mask stage is gone
    diffs = {d.where: d.severity for d in bench_differences(rec, cur)}
    assert diffs == {
        "geometry.diffuser_sensor_distance_mm": "fatal", "name": "acceptable",
        "devices.source_stage.params.port": "acceptable",
        "devices.camera.params.adc_bits": "fatal", "devices.mask_stage": "fatal",
    }
    attrs = {"bench_config": rec, "software_version": "0.1"}
    more = resume_differences(attrs, stored_frame=((4, 5), "uint16"), bench_config=rec,
                              frame=((4, 6), "uint16"), software_version="0.2")
    assert [(d.where, d.severity) for d in more] == [
        ("camera.frame_shape", "fatal"), ("software_version", "acceptable")]
    assert str(more[0]) == "camera.frame_shape: [4, 5] -> [4, 6]"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A complete dark run taken with examples/bench-simulated.toml, and bench files
    that differ from it in the geometry (fatal) and in the name (acceptable)."""
    d = tmp_path_factory.mktemp("identity")
    text = BENCH.read_text()
    (d / "geometry.toml").write_text(text.replace("diffuser_sensor_distance_mm = 8.9",
                                                  "diffuser_sensor_distance_mm = 9.5"))
    (d / "renamed.toml").write_text(text.replace('name = "simulated"', 'name = "bench-2"'))
    assert main(["calibrate", "dark", str(BENCH), "--simulate", "--frames", "2",
                 "--out", str(d / "dark.zarr")]) == 0
    return d


def test_resume_on_another_geometry_is_refused_and_changes_nothing(run, capsys):
    before = _tree(run)
    assert main(["calibrate", "resume", str(run / "dark.zarr"), str(run / "geometry.toml"),
                 "--simulate", "--accept-differences"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert "another set-up" in err
    assert "geometry.diffuser_sensor_distance_mm: 8.9 -> 9.5" in err
    assert _tree(run) == before


def test_harmless_difference_needs_the_flag_and_is_recorded(run, capsys):
    store = run / "dark.zarr"
    before = _tree(run)
    assert main(["calibrate", "resume", str(store), str(run / "renamed.toml"),
                 "--simulate"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "name: 'simulated' -> 'bench-2'" in err
    assert "--accept-differences" in err
    assert _tree(run) == before
    assert main(["calibrate", "resume", str(store), str(run / "renamed.toml"),
                 "--simulate", "--accept-differences"]) == 0
    attrs = RunStore.open(store).attrs
    assert attrs["bench_config"]["name"] == "simulated"  # what the run started with
    last = attrs["resumes"][-1]
    assert last["bench_config"]["name"] == "bench-2"
    assert last["accepted_differences"] == ["name: 'simulated' -> 'bench-2'"]
    assert last["software_version"] == attrs["software_version"]


def test_resume_with_the_same_bench_needs_no_flag(run):
    assert main(["calibrate", "resume", str(run / "dark.zarr"), str(BENCH), "--simulate"]) == 0
    assert RunStore.open(run / "dark.zarr").attrs["resumes"][-1]["accepted_differences"] == []
