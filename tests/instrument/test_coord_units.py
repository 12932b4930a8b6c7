"""Stored coordinates carry their units and dimension names, from the device
declarations (instrument/runs/coords.py): a run on the simulated bench writes them, the API
and ``runs show`` read them back, and a unit changed in a declaration changes the
stored one."""

from __future__ import annotations

import pytest

from drivers.camera import Camera
from drivers.settings import with_settings
from drivers.stage import Stage
from instrument.runs.coords import FRAME_COORDS, CoordError, coord_specs
from instrument.runs.runstore import RunStore


def _sweep(tmp_path, name="sweep.zarr"):
    from calibration_routines.psf_sweep import PsfSweepPlan
    from instrument.acquisition.runner import Runner
    from instrument.devices.virtual_bench import VirtualBench

    with VirtualBench(seed=3) as bench:
        plan = PsfSweepPlan.for_bench(bench, z_min_mm=40.0, z_max_mm=60.0, n_depths=2,
                                      frames_per_point=1)
        result = Runner(bench).run(plan, tmp_path / name)
    assert result.status == "complete", result.error
    return RunStore.open(result.path)


def test_a_run_stores_the_declared_units_and_dimension_names(tmp_path, capsys):
    store = _sweep(tmp_path)
    info = store.coord_info()
    assert list(info) == store.coord_names
    assert info["exposure_s"] == {"unit": "s", "dim": "exposure_s"}
    assert info["gain"] == {"unit": Camera.setting("gain").unit, "dim": "gain"} \
        and info["gain"]["unit"] == "dB"
    assert info["source_stage.z"] == {"unit": "mm", "dim": "z"}
    assert info["device_timestamp_s"] == {"unit": "s", "dim": "time"}
    assert info["led_array.brightness"]["unit"] == ""
    assert all(v["unit"] is not None and v["dim"] for v in info.values())
    assert store.summary(verify=False)["coords"] == info
    from instrument.cli import main

    assert main(["runs", "show", str(store.path)]) == 0
    out = capsys.readouterr().out
    assert "gain [dB]" in out and "source_stage.z [mm]," in out
    assert "device_timestamp_s [s] (time)" in out


def test_a_unit_changed_in_a_declaration_changes_the_stored_one(tmp_path, monkeypatch):
    from drivers.simulated import SimulatedCamera

    gain = Camera.setting("gain").replace(unit="x")  # a camera whose gain is a factor
    settings = with_settings(SimulatedCamera.SETTINGS, gain)
    monkeypatch.setattr(SimulatedCamera, "SETTINGS", settings)
    monkeypatch.setattr(SimulatedCamera, "_SPECS", {s.name: s for s in settings})
    store = _sweep(tmp_path)
    assert store.coord_info()["gain"]["unit"] == "x"
    assert store.coord_info()["exposure_s"]["unit"] == "s"


def test_stage_axis_units_come_from_the_stage_declaration():
    from drivers.simulated import SimulatedStage

    with SimulatedStage("rot", axes=["x", "rotation"]) as rot:
        specs = coord_specs(["rot.x", "rot.rotation", "frame_index"], {"rot": rot})
    assert specs["rot.x"] == {"unit": "mm", "dim": "x"}
    assert specs["rot.rotation"] == {"unit": Stage.setting("limits").unit_of("rotation"),
                                     "dim": "rotation"} and specs["rot.rotation"]["unit"] == "deg"
    assert specs["frame_index"] == {"unit": FRAME_COORDS["frame_index"][0], "dim": "index"}


def test_every_device_kind_has_declared_coordinates():
    """coord_names of a bench with every kind, the DMD included, all have a unit."""
    from types import SimpleNamespace

    from drivers.simulated import (
        SimulatedCamera,
        SimulatedDmd,
        SimulatedLedArray,
        SimulatedSlm,
        SimulatedStage,
    )
    from instrument.acquisition.runner import coord_names

    devices = {"cam": SimulatedCamera("cam"), "st": SimulatedStage("st"),
               "leds": SimulatedLedArray("leds"), "slm": SimulatedSlm("slm"),
               "dmd": SimulatedDmd("dmd")}
    for d in devices.values():
        d.open()
    try:
        names = coord_names(SimpleNamespace(devices=devices))
        specs = coord_specs(names, devices)
    finally:
        for d in devices.values():
            d.close()
    assert specs["dmd.exposure_s"] == {"unit": "s", "dim": "exposure_s"}
    assert specs["dmd.period_s"]["unit"] == "s" and specs["dmd.running"]["dim"] == "state"
    assert {n.split(".")[0] for n in names if "." in n} == {"st", "leds", "slm", "dmd"}


def test_an_undeclared_coordinate_is_refused():
    with pytest.raises(CoordError, match=r"'humidity' has no declared unit.*FRAME_COORDS"):
        coord_specs(["humidity"])
    with pytest.raises(CoordError, match=r"no device 'stage9'"):
        coord_specs(["stage9.z"], {})


def test_a_run_written_before_units_reads_as_unknown(tmp_path, capsys):
    import numpy as np

    store = RunStore.create(tmp_path / "old.zarr", plan_name="p", plan_params={},
                            points=[{}], frame_tags=[["f"]], frame_shape=(4, 4),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    assert store.coord_info() == {"exposure_s": {"unit": None, "dim": None}}
    from instrument.cli.runs import format_summary

    assert "exposure_s [?]" in format_summary(store.summary())
