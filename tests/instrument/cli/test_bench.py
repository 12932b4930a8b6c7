"""``diffuserlab validate`` and ``diffuserlab devices``: exit codes and output."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from instrument.cli import build_parser, main
from instrument.config import default_bench, to_toml
from instrument.devices import registry
from tests.instrument.test_registry import EVENTS, OPENED, use_fakes

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
SIM = str(EXAMPLES / "bench-simulated.toml")
DEFAULT_TOML = to_toml(default_bench())
LAB = str(EXAMPLES / "bench-lab.toml")


@pytest.fixture
def fakes(monkeypatch):
    use_fakes(monkeypatch)  # simulated-* are the recording fakes here


def write(tmp_path: Path, text: str) -> str:
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return str(path)


def test_validate_ok(capsys):
    assert main(["validate", SIM]) == 0
    out, err = capsys.readouterr()
    assert out == (
        "ok: 5 devices (1 camera, 1 led_array, 1 slm, 2 stages), bench 'simulated' "
        f"(lensless, holography) in {SIM}\n"
    )
    assert err == ""


def test_validate_reports_every_problem_with_location_and_fix(capsys, tmp_path):
    text = (
        to_toml(default_bench())
        .replace("diffuser_sensor_distance_mm = 8.9", 'diffuser_sensor_distance_mm = "5 cm"')
        .replace('id = "slm"', 'id = "camera"')
        .replace('driver = "simulated-led-array"', 'driver = "acme-leds"')
    )
    path = write(tmp_path, text)
    assert main(["validate", path]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 3
    assert all(line.startswith(f"diffuserlab: error: {path}:") for line in lines)
    assert all("; fix: " in line for line in lines)
    assert lines[0] == (
        f"diffuserlab: error: {path}:14: geometry.diffuser_sensor_distance_mm: expected "
        "millimetres as a number, got '5 cm'; fix: '5 cm' is 50 mm: write "
        "diffuser_sensor_distance_mm = 50"
    )
    numbered = text.splitlines()
    unknown = numbered.index('driver = "acme-leds"') + 1
    second_camera = [n for n, t in enumerate(numbered, 1) if t == 'id = "camera"'][1]
    assert f":{unknown}: devices[2].driver: unknown driver 'acme-leds'" in lines[1]
    assert f":{second_camera}: devices[3].id: duplicate device id 'camera'" in lines[2]


def test_validate_constructs_devices_to_check_parameter_values(capsys, tmp_path):
    text = to_toml(default_bench()).replace("adc_bits = 12", "adc_bits = 20")
    path = write(tmp_path, text)
    assert main(["validate", path]) == 2
    err = capsys.readouterr().err.splitlines()
    line = text.splitlines().index("adc_bits = 20") + 1  # the parameter's own line
    assert err == [
        f"diffuserlab: error: {path}:{line}: devices[0].params.adc_bits: driver "
        "'simulated-camera' refused the parameters of device 'camera': adc_bits=20 is not an "
        "integer in range; fix: use an integer with 8 <= adc_bits <= 16"
    ]


def test_validate_lists_every_independent_problem_in_one_run(capsys, tmp_path):
    """Schema errors in several sections and devices, an unknown driver, a driver of the
    wrong kind, parameter values the drivers refuse (two in one device), a parameter a
    driver does not take, a duplicate id, unordered pairs: one line each, no more."""
    text = DEFAULT_TOML
    for old, new in [
        ("sensor_pixel_pitch_um = 13.0", "sensor_pixel_pitch_um = -13.0"),
        ("z_range_mm = [20.0, 200.0]", "z_range_mm = [200.0, 20.0]"),
        ("exposure_bounds_s = [1e-05, 1.0]", "exposure_bounds_s = [1.0, 1e-05]"),
        ('id = "camera"', 'id = "Camera X"'),
        ("\npixel_pitch_um = 13.0", "\npixel_pitch_um = -1.0"),
        ("adc_bits = 12", "adc_bits = 3"),
        ("x = [-25.0, 25.0], y", "x = [25.0, -25.0], y"),
        ('driver = "simulated-led-array"', 'driver = "acme-leds"'),
        ("pitch_mm = 4.0", 'pitch_mm = "4 cm"'),
        ("resolution = [96, 120]", "resolution = [0, 120]"),
        ("wavelength_nm = 532.0\n\n[[devices]]", "wavelength_nm = 532.0\nport = 1\n\n[[devices]]"),
        ('id = "mask_stage"\nkind = "stage"\ndriver = "simulated-stage"',
         'id = "slm"\nkind = "stage"\ndriver = "simulated-slm"'),
    ]:
        assert old in text, old
        text = text.replace(old, new, 1)
    numbered = text.splitlines()

    def line(fragment: str, nth: int = 0) -> int:
        return [n for n, t in enumerate(numbered, 1) if t.startswith(fragment)][nth]

    expected = [
        (line("sensor_pixel_pitch_um"), "geometry.sensor_pixel_pitch_um"),
        (line("z_range_mm"), "calibration.z_range_mm"),
        (line("exposure_bounds_s"), "calibration.exposure_bounds_s"),
        (line('id = "Camera X"'), "devices[0].id"),
        (line("pixel_pitch_um"), "devices[0].params.pixel_pitch_um"),
        (line("adc_bits"), "devices[0].params.adc_bits"),
        (line("axes", 0), "devices[1].params.axes.x"),
        (line('driver = "acme-leds"'), "devices[2].driver"),
        (line("pitch_mm"), "devices[2].params.pitch_mm"),
        (line("resolution"), "devices[3].params.resolution"),
        (line("port = 1"), "devices[3].params.port"),
        (line('id = "slm"', 1), "devices[4].id"),
        (line('driver = "simulated-slm"', 1), "devices[4].driver"),
    ]
    path = write(tmp_path, text)
    assert main(["validate", path]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err and "internal error" not in err
    lines = err.splitlines()
    prefix = f"diffuserlab: error: {path}:"
    assert all(ln.startswith(prefix) and "; fix: " in ln for ln in lines)
    found = [ln[len(prefix):].split(": ", 2)[:2] for ln in lines]
    assert [(int(n), loc) for n, loc in found] == expected  # in line order, each once


def test_validate_syntax_error_and_missing_file(fakes, capsys, tmp_path):
    path = write(tmp_path, 'name = "x"\n\n[geometry]\naperture_mm = [5, 4\n')
    assert main(["validate", path]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"diffuserlab: error: {path}:4: (TOML syntax): Unclosed array")
    assert len(err.splitlines()) == 1

    assert main(["validate", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err
    assert "nope.toml: (file): cannot read: No such file or directory; fix: check the path" in err


def test_validate_lab_bench_unknown_drivers_then_simulated(capsys):
    lab_drivers = [("aravis", "camera"), ("thorlabs-apt", "source_stage"),
                   ("illuminate", "led_array"), ("fullscreen-slm", "slm"),
                   ("zaber-ascii", "mask_stage")]
    installed = set(registry.names())
    assert {"thorlabs-apt", "zaber-ascii", "illuminate", "aravis", "fullscreen-slm",
            "v4l2"} <= installed  # the real drivers
    missing = [(name, dev) for name, dev in lab_drivers if name not in installed]
    assert main(["validate", LAB]) == (2 if missing else 0)
    err = capsys.readouterr().err.splitlines()
    assert [line.split(": ")[4] for line in err] == [
        f"unknown driver {name!r} of device {dev!r}; fix" for name, dev in missing
    ]
    assert all("--simulate" in line for line in err)

    assert main(["validate", LAB, "--simulate"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("ok: 5 devices") and "'lab-diffusercam'" in out[0]
    assert out[1] == (
        "  camera: aravis -> simulated-camera (params dropped: camera_name, exposure_s, "
        "packet_size, pixel_format)"
    )
    assert out[2] == (
        "  source_stage: thorlabs-apt -> simulated-stage (params dropped: port, "
        "serial_numbers)"
    )
    assert out[5] == (
        "  mask_stage: zaber-ascii -> simulated-stage (params dropped: baudrate, "
        "device_numbers, port)"
    )


def test_devices_default_bench(capsys):
    assert main(["devices"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == (
        "5 devices (1 camera, 1 led_array, 1 slm, 2 stages), bench 'simulated' "
        "(lensless, holography) from built-in simulated bench:"
    )
    rows = [line.split() for line in out[1:]]
    assert [r[:4] for r in rows] == [
        ["camera", "camera", "simulated-camera", "open"],
        ["source_stage", "stage", "simulated-stage", "open"],
        ["led_array", "led_array", "simulated-led-array", "open"],
        ["slm", "slm", "simulated-slm", "open"],
        ["mask_stage", "stage", "simulated-stage", "open"],
    ]
    assert 'positions={"x":0.0,"y":0.0,"z":0.0}' in rows[1]


def test_devices_settings_lists_values_units_and_the_open_devices_limits(capsys):
    assert main(["devices", "--settings"]) == 0
    out = capsys.readouterr().out.splitlines()
    camera = out.index(next(line for line in out if line.startswith("  camera ")))
    assert out[camera + 1].split()[:3] == ["pixel_format", "=", "mono12"]
    exposure = next(line for line in out if line.split()[0] == "exposure_s")
    # the simulated camera's range, read from its info, not the kind's declaration
    assert exposure.split("=", 1)[1].strip() == "0.01 s  (1e-06 to 60 s)"
    slm = out.index(next(line for line in out if line.startswith("  slm ")))
    assert [line.split()[0] for line in out[slm + 1:slm + 3]] == ["lut_rad", "settle_s"]


def test_devices_json_declares_settings_with_a_schema_other_tools_check(capsys):
    jsonschema = pytest.importorskip("jsonschema")  # with napari (the napari extra)

    assert main(["devices", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [d["id"] for d in doc["devices"]] == [
        "camera", "source_stage", "led_array", "slm", "mask_stage"]
    camera = doc["devices"][0]
    assert camera["status"]["is_open"] and camera["settings"]["exposure_s"] == 0.01
    spec = {d["name"]: d for d in camera["declarations"]}["exposure_s"]
    assert (spec["unit"], spec["low"], spec["high"]) == ("s", 1e-06, 60.0)
    for device in doc["devices"]:  # each device's own values satisfy its schema
        writable = {d["name"] for d in device["declarations"] if not d["read_only"]}
        jsonschema.validate({k: v for k, v in device["settings"].items() if k in writable},
                            device["schema"])
    with pytest.raises(jsonschema.ValidationError):  # and an unknown or bad one fails
        jsonschema.validate({"exposure": 0.01}, camera["schema"])
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"trigger_mode": "sometimes"}, camera["schema"])


def test_devices_opens_and_closes_every_device(fakes, capsys):
    assert main(["devices", "--timeout", "3"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [r[4] for r in rows] == ["frames=0"] * 5
    assert rows[0][5] == 'params=["adc_bits","pixel_pitch_um","sensor_shape"]'
    assert len(OPENED) == 5 and not any(d.is_open for d in OPENED.values())
    assert {d.timeout_s for d in OPENED.values()} == {3.0}
    assert [e for e, _ in EVENTS] == ["open"] * 5 + ["close"] * 5


def test_devices_lab_file_needs_simulate(capsys):
    rc = main(["devices", LAB])  # a driver not installed (2), or no such hardware here (1)
    err = capsys.readouterr().err
    assert (rc == 2 and "unknown driver" in err) or (rc == 1 and "opening device" in err)
    assert main(["devices", LAB, "--simulate"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith(f"from {LAB} (simulated twins):")
    assert [line.split()[:4] for line in out[1:]] == [
        ["camera", "camera", "simulated-camera", "open"],
        ["source_stage", "stage", "simulated-stage", "open"],
        ["led_array", "led_array", "simulated-led-array", "open"],
        ["slm", "slm", "simulated-slm", "open"],
        ["mask_stage", "stage", "simulated-stage", "open"],
    ]


def test_devices_open_failure_exits_1_and_closes_the_others(fakes, capsys, tmp_path):
    text = to_toml(default_bench()).replace(
        "resolution = [96, 120]", "resolution = [96, 120]\nfail_open = true"
    )
    assert main(["devices", write(tmp_path, text)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith(
        "diffuserlab: error: opening device 'slm' (driver 'simulated-slm') failed: TimeoutError"
    )
    assert "closed again: camera, source_stage, led_array" in captured.err
    assert not any(d.is_open for d in OPENED.values())
    assert EVENTS[-3:] == [("close", "led_array"), ("close", "source_stage"), ("close", "camera")]


def test_devices_bad_input_exits_2(fakes, capsys, tmp_path):
    assert main(["devices", str(tmp_path / "missing.toml")]) == 2
    assert capsys.readouterr().err.startswith("diffuserlab: error: ")
    assert main(["devices", "--timeout", "0"]) == 2
    assert "--timeout must be a finite number of seconds > 0" in capsys.readouterr().err
    assert OPENED == {}


def test_existing_subcommands_still_parse():
    parser = build_parser()
    assert parser.parse_args(["recon", "--psf", "p", "--raw", "r"]).command == "recon"
    assert parser.parse_args(["demo"]).command == "demo"
    assert parser.parse_args(["benchmark", "recon", "--quick"]).quick is True
    args = parser.parse_args(["devices", "b.toml", "--simulate"])
    assert (args.bench, args.simulate, args.timeout_s) == ("b.toml", True, 10.0)
    # validate without a file: refused (exit 2) unless --simulate picks the built-in bench
    assert main(["validate"]) == 2
