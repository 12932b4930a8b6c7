"""Bench configuration: the default bench, TOML round trip, and one clear message
(location, TOML line, fix) for every kind of invalid file."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from instrument.config import (
    SIMULATED_DRIVERS,
    BenchConfig,
    BenchConfigError,
    DeviceConfig,
    GeometryConfig,
    Problem,
    default_bench,
    to_toml,
)
from instrument.devices.bench_setup import (
    load_bench,
    parse_bench,
    simulated_twin,
    with_simulated_drivers,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DEFAULT_TOML = to_toml(default_bench())
XYZ = "axes = {x = [-25.0, 25.0], y = [-25.0, 25.0], z = [0.0, 250.0]}"


def line_of(text: str, fragment: str, nth: int = 0) -> int:
    """1-based number of the line holding the nth occurrence of ``fragment``."""
    hits = [n for n, line in enumerate(text.splitlines(), 1) if fragment in line]
    return hits[nth]


def problems(text: str, **kw) -> list[Problem]:
    with pytest.raises(BenchConfigError) as info:
        parse_bench(text, source="bench.toml", **kw)
    return info.value.problems


def only(text: str, location: str, **kw) -> Problem:
    found = problems(text, **kw)
    assert [p.location for p in found] == [location], [str(p) for p in found]
    return found[0]


def edit(old: str, new: str, nth: int = 0) -> str:
    """DEFAULT_TOML with the nth occurrence of ``old`` replaced."""
    parts = DEFAULT_TOML.split(old)
    assert len(parts) > nth + 1, old
    return old.join(parts[: nth + 1]) + new + old.join(parts[nth + 1 :])


# ---------------------------------------------------------------- valid benches


def test_default_bench_has_the_simulated_devices():
    bench = default_bench()
    kinds = {d.id: (d.kind, d.driver) for d in bench.devices}
    assert kinds == {
        "camera": ("camera", "simulated-camera"),
        "source_stage": ("stage", "simulated-stage"),
        "led_array": ("led_array", "simulated-led-array"),
        "slm": ("slm", "simulated-slm"),
        "mask_stage": ("stage", "simulated-stage"),
    }
    assert list(bench.device("source_stage").params["axes"]) == ["x", "y", "z"]
    assert list(bench.device("mask_stage").params["axes"]) == [
        "x",
        "y",
        "z",
        "tip",
        "tilt",
        "rotation",
    ]
    assert bench.device("led_array").params["shape"] == [32, 32]
    camera = bench.device("camera").params
    assert camera["sensor_shape"] == list(bench.geometry.sensor_shape_px)
    assert camera["pixel_pitch_um"] == bench.geometry.sensor_pixel_pitch_um
    z_travel = bench.device("source_stage").params["axes"]["z"]
    assert (
        z_travel[0]
        <= bench.calibration.z_range_mm[0]
        < bench.calibration.z_range_mm[1]
        <= (z_travel[1])
    )
    assert with_simulated_drivers(bench) == bench  # already its own twin
    assert bench.branches == ["lensless", "holography"]
    with pytest.raises(KeyError, match="no device 'nope'"):
        bench.device("nope")


def test_default_bench_round_trips_through_toml(tmp_path):
    bench = default_bench()
    assert parse_bench(DEFAULT_TOML) == bench
    path = tmp_path / "bench.toml"
    path.write_text(DEFAULT_TOML)
    assert load_bench(path) == bench
    assert to_toml(load_bench(path)) == DEFAULT_TOML
    assert "# distance from the diffuser to the sensor, millimetres" in DEFAULT_TOML
    assert parse_bench(to_toml(bench, comments=False)) == bench


def test_to_toml_escapes_strings_and_writes_nested_params():
    bench = default_bench()
    cam = bench.devices[0].model_copy(
        update={
            "params": {
                "label": 'say "hi"\\\n\tok \x7f é',
                "roi": {"x": 0, "w": 1.5},
                "flags": [True, False],
                "weird key": 1,
            }
        }
    )
    odd = bench.model_copy(
        update={"name": "odd 'name' \"quoted\"", "devices": [cam, *bench.devices[1:]]}
    )
    assert parse_bench(to_toml(odd), check_drivers=False) == odd


def test_example_files_are_valid():
    assert load_bench(EXAMPLES / "bench-simulated.toml") == default_bench()
    lab = load_bench(EXAMPLES / "bench-lab.toml", check_drivers=False)
    assert [d.driver for d in lab.devices] == [
        "aravis",
        "thorlabs-apt",
        "illuminate",
        "fullscreen-slm",
        "zaber-ascii",
    ]
    sim = load_bench(EXAMPLES / "bench-lab.toml", simulate=True)
    assert [d.driver for d in sim.devices] == [SIMULATED_DRIVERS[d.kind] for d in lab.devices]


def test_with_simulated_drivers_translates_shared_params():
    lab = load_bench(EXAMPLES / "bench-lab.toml", check_drivers=False)
    sim = with_simulated_drivers(lab)
    assert [(d.id, d.kind) for d in sim.devices] == [(d.id, d.kind) for d in lab.devices]
    assert sim.geometry == lab.geometry and sim.calibration == lab.calibration
    cam, stage, leds, slm, mask = sim.devices
    # camera: shape and pitch from the geometry; Aravis settings and address dropped
    assert cam.params == {"sensor_shape": [2048, 2448], "pixel_pitch_um": 3.45}
    # stage: axis names + limits_mm become the twin's travel table
    assert stage.params == {"axes": {"x": [0, 25], "y": [0, 25], "z": [0, 50]}, "velocity": 2.0}
    assert mask.params["axes"]["rotation"] == [-180.0, 180.0]  # default travel
    assert leds.params == {"shape": [32, 32], "pitch_mm": 4.0}
    # SLM: shape_px -> resolution, wavelength from the geometry, bit_depth/screen dropped
    assert slm.params == {"resolution": [1080, 1920], "pixel_pitch_um": 8.0, "wavelength_nm": 532}
    assert lab.devices[0].driver == "aravis"  # the original is untouched
    twin, dropped = simulated_twin(lab.devices[0], lab.geometry)
    assert twin == cam and sorted(dropped) == [
        "camera_name",
        "exposure_s",
        "packet_size",
        "pixel_format",
    ]
    twin, dropped = simulated_twin(lab.devices[3])  # no geometry: nothing filled in
    assert twin.params == {"resolution": [1080, 1920], "pixel_pitch_um": 8.0}


# ------------------------------------------------------------- invalid benches


def test_unknown_driver():
    text = edit('driver = "simulated-slm"', 'driver = "acme-slm"')
    p = only(text, "devices[3].driver")
    assert "unknown driver 'acme-slm' of device 'slm'" in p.message
    assert "simulated-slm" in p.fix and "--simulate" in p.fix
    assert p.line == line_of(text, "acme-slm")
    assert parse_bench(text, check_drivers=False).devices[3].driver == "acme-slm"
    assert parse_bench(text, simulate=True).devices[3].driver == "simulated-slm"


def test_driver_of_the_wrong_kind():
    text = edit('driver = "simulated-led-array"', 'driver = "simulated-stage"')
    p = only(text, "devices[2].driver")
    assert "driver 'simulated-stage' of device 'led_array' drives a stage" in p.message
    assert "kind = 'led_array'" in p.message
    assert "use a led_array driver (" in p.fix and "simulated-led-array)" in p.fix
    assert p.line == line_of(text, 'driver = "simulated-stage"', 1)


def test_duplicate_device_id():
    text = edit('id = "slm"', 'id = "camera"')
    p = only(text, "devices[3].id")
    assert "duplicate device id 'camera' (already used by devices[0])" in p.message
    assert 'id = "camera_2"' in p.fix
    assert p.line == line_of(text, 'id = "camera"', 1)


def test_missing_fields():
    text = edit("sensor_pixel_pitch_um = 13.0\n", "")
    p = only(text, "geometry.sensor_pixel_pitch_um")
    assert p.message == "missing required key"
    assert p.fix == "add sensor_pixel_pitch_um = 13.0 under [geometry]"
    assert p.line == line_of(text, "[geometry]")

    text = edit('driver = "simulated-camera"\n', "")
    p = only(text, "devices[0].driver")
    assert 'add driver = "simulated-camera" in the [[devices]] table number 1' in p.fix

    text = DEFAULT_TOML.split("[geometry]")[0]
    found = problems(text)
    assert {p.location for p in found} == {"devices", "geometry"}
    assert any("missing required table [geometry]" in p.message for p in found)


def test_wrong_units_are_refused_naming_the_unit():
    text = edit("diffuser_sensor_distance_mm = 8.9", 'diffuser_sensor_distance_mm = "5 cm"')
    p = only(text, "geometry.diffuser_sensor_distance_mm")
    assert str(p) == (
        "line 14: geometry.diffuser_sensor_distance_mm: expected millimetres as a number, "
        "got '5 cm'; fix: '5 cm' is 50 mm: write diffuser_sensor_distance_mm = 50"
    )
    assert p.line == line_of(text, "5 cm") == 14

    p = only(edit("settle_s = 0.2", 'settle_s = "10 ms"'), "calibration.settle_s")
    assert "expected seconds as a number, got '10 ms'" in p.message
    assert "write settle_s = 0.01" in p.fix

    p = only(
        edit("sensor_pixel_pitch_um = 13.0", 'sensor_pixel_pitch_um = "13 um"'),
        "geometry.sensor_pixel_pitch_um",
    )
    assert "expected micrometres" in p.message and "write sensor_pixel_pitch_um = 13" in p.fix

    p = only(
        edit("aperture_mm = [2.67, 2.11]", 'aperture_mm = [2.67, "4 in"]'), "geometry.aperture_mm"
    )
    assert "expected millimetres as a number, got '4 in'" in p.message
    assert "plain number in millimetres" in p.fix

    p = only(edit("n_depths = 32", 'n_depths = "32"'), "calibration.n_depths")
    assert p.message == "expected an integer, got '32'"

    p = only(edit("settle_s = 0.2", "settle_s = true"), "calibration.settle_s")
    assert "expected a number, got true" in p.message


def test_driver_params_with_units_in_their_names_are_checked_too():
    text = edit(XYZ, XYZ + '\nspeed_mm_s = 2\nlimit_mm = "2 cm"')
    p = only(text, "devices[1].params.limit_mm", check_drivers=False)
    assert "expected millimetres as a number, got '2 cm'" in p.message
    assert "write limit_mm = 20" in p.fix
    assert p.line == line_of(text, "limit_mm")

    text = edit(XYZ, XYZ + '\nspeed_mm_s = "2 mm/s"')
    p = only(text, "devices[1].params.speed_mm_s", check_drivers=False)
    assert "expected millimetres per second as a number, got '2 mm/s'" in p.message

    p = only(edit("z = [0.0, 250.0]", 'z = [0.0, "25 cm"]'), "devices[1].params.axes.z")
    assert "expected millimetres as a number, got '25 cm'" in p.message
    assert "'25 cm' is 250 mm: write 250" in p.fix


def test_parameters_the_driver_does_not_take():
    text = edit("pitch_mm = 4.0", "pich_mm = 4.0")
    p = only(text, "devices[2].params.pich_mm")
    assert "driver 'simulated-led-array' of device 'led_array' takes no parameter 'pich_mm'" in (
        p.message
    )
    assert p.fix.startswith("did you mean 'pitch_mm'? remove it or use one of: ")
    assert p.line == line_of(text, "pich_mm")
    assert parse_bench(text, check_drivers=False).devices[2].params["pich_mm"] == 4.0


def test_out_of_range_values():
    p = only(
        edit("diffuser_sensor_distance_mm = 8.9", "diffuser_sensor_distance_mm = -1"),
        "geometry.diffuser_sensor_distance_mm",
    )
    assert p.message == "out of range: expected a value in (0, 500] mm, got -1.0"
    assert p.fix == "set diffuser_sensor_distance_mm within (0, 500] mm"

    p = only(
        edit("sensor_shape_px = [256, 320]", "sensor_shape_px = [480, 4]"),
        "geometry.sensor_shape_px",
    )
    assert "expected each value in [8, 32768], got [480, 4]" in p.message

    p = only(
        edit("z_range_mm = [20.0, 200.0]", "z_range_mm = [200.0, 20.0]"), "calibration.z_range_mm"
    )
    assert "minimum" in p.message and p.fix == "write z_range_mm = [20, 200]"

    p = only(edit("wavelength_nm = 532.0", "wavelength_nm = nan"), "geometry.wavelength_nm")
    assert "expected a value in [200, 2000] nm, got nan" in p.message


def test_toml_syntax_error_has_line_and_column():
    text = edit("aperture_mm = [2.67, 2.11]", "aperture_mm = 2.2 mm")
    p = only(text, "(TOML syntax)")
    assert p.line == line_of(text, "aperture_mm = 2.2 mm") and p.column is not None
    assert f"at line {p.line}, column {p.column}: 'aperture_mm = 2.2 mm'" in p.message
    assert "without its unit" in p.fix

    p = only('name = "x"\n[geometry\n', "(TOML syntax)")
    assert p.line == 2 and "line 2" in p.message

    p = only('name = "x"\nname = "y"\n', "(TOML syntax)")
    assert p.line == 2 and "defined twice" in p.fix


def test_unknown_keys_suggest_the_spelling():
    p = only(edit("settle_s = 0.2", "settle_s = 0.2\nsetle_s = 1"), "calibration.setle_s")
    assert p.message == "unknown key 'setle_s'"
    assert p.fix.startswith("did you mean 'settle_s'?")

    p = only(
        edit('driver = "simulated-camera"', 'driver = "simulated-camera"\nport = "/dev/x"'),
        "devices[0].port",
    )
    assert "driver parameters go under [devices.params]" in p.fix


def test_bad_kind_id_axes_and_diffuser():
    p = only(edit('kind = "led_array"', 'kind = "lamp"'), "devices[2].kind")
    assert "expected 'camera', 'stage', 'led_array', 'slm' or 'dmd', got 'lamp'" in p.message

    p = only(edit('id = "slm"', 'id = "My SLM"'), "devices[3].id")
    assert "invalid device id 'My SLM'" in p.message and p.fix == 'write id = "my_slm"'

    p = only(edit("tilt = [", "tlit = ["), "devices[4].params.axes")
    assert "unknown stage axis name(s) ['tlit']" in p.message and "'tlit' -> 'tilt'" in p.fix

    p = only(edit(XYZ, 'axes = ["x", "x"]'), "devices[1].params.axes", check_drivers=False)
    assert "duplicate stage axis name(s) ['x']" in p.message
    assert parse_bench(edit(XYZ, 'axes = ["x", "z"]'), check_drivers=False)  # names only: ok

    p = only(edit("z = [0.0, 250.0]", "z = [250.0, 0.0]"), "devices[1].params.axes.z")
    assert "travel of axis 'z' must be [low, high] with low < high, got [250.0, 0.0]" in p.message
    assert p.fix == "write z = [low, high] in millimetres, e.g. z = [0.0, 50.0]"

    p = only(edit(XYZ, "axes = 3"), "devices[1].params.axes")
    assert "expected a table of axis travel ranges or an array of axis names" in p.message

    text = edit(XYZ + "\n", "")
    p = only(text, "devices[1].params.axes")
    assert "a stage lists its axes in params.axes" in p.message
    assert p.line == line_of(text, "[devices.params]", 1)  # the table to add it to

    p = only(edit('diffuser_kind = "smooth"', 'diffuser_kind = "rough"'), "geometry.diffuser_kind")
    assert "expected 'smooth' or 'microlens', got 'rough'" in p.message


def test_bench_rules_one_camera_and_an_slm():
    text = edit(
        'kind = "slm"\ndriver = "simulated-slm"', 'kind = "camera"\ndriver = "simulated-camera"'
    )
    found = problems(text, check_drivers=False)
    locs = {p.location: p for p in found}
    assert set(locs) == {"devices[3].kind", "devices"}
    assert "a lensless bench has exactly one camera" in locs["devices[3].kind"].message
    assert "found 2: devices[0] 'camera', devices[3] 'slm'" in locs["devices[3].kind"].message
    assert "a holography bench needs at least one SLM" in locs["devices"].message

    text = edit('branches = ["lensless", "holography"]', 'branches = ["holography"]')
    assert parse_bench(text, check_drivers=False).branches == ["holography"]
    no_cam = text.replace(
        'kind = "camera"\ndriver = "simulated-camera"',
        'kind = "led_array"\ndriver = "simulated-led-array"',
    )
    # the camera rule is for lensless benches
    assert len(parse_bench(no_cam, check_drivers=False).devices) == 5
    p = only(
        edit('branches = ["lensless", "holography"]', 'branches = ["lensless"]').replace(
            'kind = "camera"\ndriver = "simulated-camera"',
            'kind = "led_array"\ndriver = "simulated-led-array"',
        ),
        "devices",
        check_drivers=False,
    )
    assert "found none" in p.message and 'kind = "camera"' in p.fix


def test_every_problem_is_reported_at_once():
    text = (
        edit('id = "slm"', 'id = "camera"')
        .replace("diffuser_sensor_distance_mm = 8.9", 'diffuser_sensor_distance_mm = "9 mm"')
        .replace('driver = "simulated-led-array"', 'driver = "acme-leds"')
        .replace("n_depths = 32", "n_depths = 0")
    )
    with pytest.raises(BenchConfigError) as info:
        parse_bench(text, source="lab.toml")
    err = info.value
    assert [p.location for p in err.problems] == [
        "geometry.diffuser_sensor_distance_mm",
        "calibration.n_depths",
        "devices[2].driver",
        "devices[3].id",
    ]
    assert str(err).startswith("lab.toml: 4 problems in the bench configuration:\n")
    assert err.lines()[0].startswith("lab.toml:14: geometry.diffuser_sensor_distance_mm: ")
    assert all("; fix: " in line for line in err.lines())


@pytest.mark.parametrize(
    ("edits", "locations"),
    [
        pytest.param(  # the second pair was checked only once the first was in order
            [("z_range_mm = [20.0, 200.0]", "z_range_mm = [200.0, 20.0]"),
             ("exposure_bounds_s = [1e-05, 1.0]", "exposure_bounds_s = [1.0, 1e-05]"),
             ("n_depths = 32", "n_depths = 0")],
            ["calibration.z_range_mm", "calibration.n_depths", "calibration.exposure_bounds_s"],
            id="calibration-pairs",
        ),
        pytest.param(  # a stage's axes were checked only once its other keys were valid
            [('id = "source_stage"', 'id = "Source Stage"'),
             (XYZ, "axes = {x = [25.0, -25.0], q = [0, 1]}\nspeed_mm_s = \"2 cm\"")],
            ["devices[1].id", "devices[1].params.axes", "devices[1].params.axes.x",
             "devices[1].params.speed_mm_s"],
            id="stage-axes",
        ),
    ],
)
def test_problems_of_one_section_do_not_hide_each_other(edits, locations):
    text = DEFAULT_TOML
    for old, new in edits:
        text = text.replace(old, new, 1)
    found = problems(text, check_drivers=False)
    assert [p.location for p in found] == locations
    assert len({p.line for p in found[:2]}) == 2 and all(p.line for p in found)


def test_driver_checks_say_nothing_twice():
    # an empty driver name: the model's message only, not also "unknown driver ''"
    p = only(edit('driver = "simulated-slm"', 'driver = ""'), "devices[3].driver")
    assert p.message == "empty driver name"
    # a parameter the driver does not take: its value's unit does not matter
    p = only(edit("pitch_mm = 4.0", 'pitch_mm = 4.0\nspeed_mm_s = "2 cm"'),
             "devices[2].params.speed_mm_s")
    assert "takes no parameter 'speed_mm_s'" in p.message
    # both values of an empty pair missing: one problem
    p = only(edit("z_range_mm = [20.0, 200.0]", "z_range_mm = []"), "calibration.z_range_mm")
    assert p.message == "too few values"


def test_values_refused_by_a_driver_are_found_whatever_else_is_wrong():
    text = (
        edit("adc_bits = 12", "adc_bits = 3\nfoo = 1")  # refused, and an unknown parameter
        .replace('diffuser_kind = "smooth"', 'diffuser_kind = "rough"')  # a schema error
        .replace("resolution = [96, 120]", "resolution = [0, 120]")  # refused by the SLM
    )
    found = problems(text, construct=True)
    assert [(p.location, p.line) for p in found] == [
        ("geometry.diffuser_kind", line_of(text, "diffuser_kind")),
        ("devices[0].params.adc_bits", line_of(text, "adc_bits = 3")),
        ("devices[0].params.foo", line_of(text, "foo = 1")),
        ("devices[3].params.resolution", line_of(text, "resolution =")),
    ]
    # with the simulated twins, at the key the file uses (an SLM's shape_px)
    lab = (EXAMPLES / "bench-lab.toml").read_text().replace("shape_px = [1080, 1920]",
                                                           "shape_px = [1080, 0]")
    p = only(lab, "devices[3].params.shape_px", construct=True, simulate=True)
    assert "cols=0" in p.message and p.line == line_of(lab, "shape_px = [1080, 0]")


def test_a_missing_required_parameter_is_not_reported_again_by_the_driver(monkeypatch):
    from drivers.simulated import SimulatedStage
    from instrument.devices import registry

    class NeedsAxes(SimulatedStage):
        def __init__(self, device_id, *, axes, **params):
            super().__init__(device_id, axes=axes, **params)

    monkeypatch.setitem(registry._local, "needs-axes", NeedsAxes)
    text = edit('driver = "simulated-stage"\n\n[devices.params]\n' + XYZ,
                'driver = "needs-axes"\n\n[devices.params]\nvelocity = 2.0')
    p = only(text, "devices[1].params.axes", construct=True)  # no "missing argument 'axes'"
    assert p.message == "a stage lists its axes in params.axes"


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("[" * 3000 + "]" * 3000, "nested too deeply to read"),
        ("[" * 30 + "1" + "]" * 30, "nested more than 16 levels deep"),
        ("9" * 5000, "more than 4300 digits"),
    ],
    ids=["deeper-than-tomllib", "deep", "long-int"],
)
def test_hostile_values_are_bench_config_errors(value, message):
    found = problems(edit("pitch_mm = 4.0", f"pitch_mm = {value}"), construct=True)
    assert len(found) == 1 and message in found[0].message
    assert all(len(p.format()) < 300 for p in found)


def test_simulate_with_a_kind_that_is_not_a_string():
    p = only(edit('kind = "slm"', 'kind = ["slm"]'), "devices[3].kind",
             construct=True, simulate=True)  # was a TypeError (unhashable list)
    assert "expected 'camera', 'stage', 'led_array', 'slm' or 'dmd'" in p.message


def test_unreadable_files(tmp_path):
    with pytest.raises(BenchConfigError, match=r"missing\.toml: \(file\): cannot read: No such"):
        load_bench(tmp_path / "missing.toml")
    with pytest.raises(BenchConfigError, match="not a directory"):
        load_bench(tmp_path)
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(b'name = "x"\ndescription = "caf\xe9"\n')
    with pytest.raises(BenchConfigError) as info:
        load_bench(bad)
    assert info.value.problems[0].line == 2 and "UTF-8" in str(info.value)


def test_models_refuse_bad_values_from_python_too():
    with pytest.raises(ValidationError, match="expected millimetres as a number"):
        GeometryConfig(
            sensor_pixel_pitch_um=3.45,
            sensor_shape_px=(10, 10),
            diffuser_sensor_distance_mm="5 cm",
            aperture_mm=(1, 1),
            diffuser_kind="smooth",
        )
    cam = DeviceConfig(id="cam", kind="camera", driver="simulated-camera")
    with pytest.raises(ValidationError, match="duplicate device id 'cam'"):
        BenchConfig(name="b", devices=[cam, cam], geometry=default_bench().geometry)
