"""Device settings declared once (drivers/settings.py): the validation, the
machine-readable description and the documentation all come from the declarations."""

from __future__ import annotations

import json

import pytest

from drivers.base import Device
from drivers.camera import Camera
from drivers.dmd import Dmd
from drivers.errors import DeviceStateError, DeviceValueError
from drivers.settings import (
    Setting,
    info,
    setting_property,
    settings_markdown,
    with_settings,
)
from drivers.settings_doc import DEFAULT_PAGE, KINDS, page
from drivers.simulated import SimulatedCamera, SimulatedDmd, SimulatedLedArray, SimulatedStage
from instrument.writer.docpage import main


def test_settings_page_matches_the_declarations(tmp_path):
    assert DEFAULT_PAGE.read_text(encoding="utf-8") == page(), (
        "docs/drivers/settings.md is out of date: run python -m instrument.writer.docpage")
    assert main(["--check"]) == 0
    stale = tmp_path / "settings.md"
    stale.write_text(page().replace("exposure time", "exposure"), encoding="utf-8")
    assert main(["--check", "--page", str(stale)]) == 1
    assert main(["--page", str(stale)]) == 0 and stale.read_text(encoding="utf-8") == page()


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_kind_declares_its_settings_once(kind):
    cls = KINDS[kind]
    assert cls.kind == kind and cls.SETTINGS
    assert cls._SETTINGS == tuple(s.name for s in cls.SETTINGS if not s.read_only)
    for s in cls.SETTINGS:
        assert s.description and s.dtype, s.name
        assert cls.setting(s.name) is s
        assert f"`{s.name}`" in page()
    json.dumps(cls.setting_specs())  # machine-readable without a device


def test_specs_of_an_open_device_carry_its_limits():
    with SimulatedCamera("cam0") as cam:
        specs = {s["name"]: s for s in cam.setting_specs(cam.info)}
        lo, hi = cam.info["exposure_range_s"]
        assert (specs["exposure_s"]["low"], specs["exposure_s"]["high"]) == (lo, hi)
        assert specs["exposure_s"]["limits"] == f"{lo:g} to {hi:g} s"
        assert specs["pixel_format"]["choices"] == cam.info["pixel_formats"]
        assert specs["roi"]["limits"] == "within 640 x 480 px"
        assert specs["gain"]["unit"] == "dB" and "stream_locked" in specs["roi"]["tags"]
        json.dumps(specs)
    with SimulatedStage("stage") as stage:
        spec = stage.setting_specs(stage.info)[1]
        assert spec["name"] == "velocity" and spec["per"] == "axes"
        assert spec["high"] == {a: v["max_velocity"] for a, v in stage.info["axes"].items()}
        assert Camera.setting_specs()[3]["high"] == {"info": "info.exposure_range_s[1]"}
        assert "z 0 (excl.) to 50 mm/s" in spec["limits"]
    with SimulatedDmd("dmd") as dmd:
        spec = dmd.setting_specs(dmd.info)[2]
        assert spec["name"] == "led_currents" and spec["per"] == "colours"
        assert spec["high"] == 1.0 and spec["limits"] == "red 0 to 1; green 0 to 1; blue 0 to 1"
    with SimulatedLedArray("leds") as leds:
        assert leds.setting_specs(leds.info)[1]["limits"].startswith("one of red, green")


@pytest.mark.parametrize(("cls", "name"), [
    (Camera, "exposure_s"), (Camera, "frame_rate_hz"), (Camera, "gain"),
    (Camera, "pixel_format"), (Camera, "roi"), (Camera, "binning"),
    (Camera, "trigger_mode"), (Dmd, "exposure_s"), (Dmd, "period_s")])
def test_setting_properties_are_made_once_and_documented(cls, name):
    attr = vars(cls)[name]
    made = setting_property(name, "doc")
    assert attr.fget.__code__ is made.fget.__code__ and attr.fset.__code__ is made.fset.__code__
    assert attr.__doc__ and attr.__doc__ != "doc"


def test_a_setting_property_reads_open_and_writes_through_validation():
    cam = SimulatedCamera("cam0")
    with pytest.raises(DeviceStateError):
        _ = cam.exposure_s
    with cam:
        cam.exposure_s = 0.02
        assert cam.exposure_s == 0.02 and cam.settings()["exposure_s"] == 0.02
        with pytest.raises(DeviceValueError):
            cam.exposure_s = -1.0
        assert cam.exposure_s == 0.02
    with SimulatedDmd("dmd") as dmd:
        dmd.period_s = 0.5
        with pytest.raises(DeviceValueError):
            dmd.exposure_s = 0.6
        assert dmd.period_s == 0.5


class _CappedGain(SimulatedCamera):
    """A driver that narrows its kind's gain and adds a setting of its own."""

    SETTINGS = with_settings(
        Camera.SETTINGS, Camera.setting("gain").replace(high=3.0),
        Setting("black_level", "int", "DN", "offset added to every pixel", low=0,
                high=info("max_binning", transform=lambda b: 100 * b)),
        Setting("temperature_c", "float", "degC", "sensor temperature", read_only=True))

    def _do_get_settings(self):
        return {**super()._do_get_settings(), "black_level": 0}

    def _do_apply(self, name, value):
        return None if name == "black_level" else super()._do_apply(name, value)


def test_a_driver_narrows_and_extends_its_kinds_settings():
    assert _CappedGain._SETTINGS == Camera._SETTINGS + ("black_level",)
    with _CappedGain("cam0") as cam:
        with pytest.raises(DeviceValueError, match=r"use a finite number with 0 <= gain <= 3"):
            cam.gain = 5.0
        cam.gain = 2.0
        with pytest.raises(DeviceValueError, match=r"black_level=900"):
            cam.apply_settings({"black_level": 900})  # max_binning 8 -> 800
        cam.apply_settings({"black_level": 800})
        assert cam.settings()["black_level"] == 800
        with pytest.raises(DeviceValueError, match=r"\['temperature_c'\] are read-only"):
            cam.apply_settings({"temperature_c": 20.0})
        specs = {s["name"]: s for s in cam.setting_specs(cam.info)}
        assert specs["temperature_c"]["read_only"] and specs["black_level"]["high"] == 800
    text = settings_markdown(KINDS, (_CappedGain,))
    section = text.split("_CappedGain")[1]
    assert "| `gain` | `float` | dB | 0 to 3 dB |" in section
    assert "`black_level`" in section and "read-only" in section
    assert "`exposure_s`" not in section  # unchanged rows are not repeated


def test_a_setting_declared_twice_is_refused():
    with pytest.raises(TypeError, match="declares a name twice"):
        type("Twice", (Device,), {"SETTINGS": (Setting("a", "int"), Setting("a", "float"))})


def test_messages_name_the_setting_the_key_and_the_fix():
    with SimulatedStage("stage") as stage:
        with pytest.raises(DeviceValueError, match=r"velocity\[z\]=1000.0 is not a number in "
                           r"range.*Fix: use a finite number with 0 < velocity\[z\] <= 50"):
            stage.velocity = {"z": 1000.0}
        with pytest.raises(DeviceValueError, match=r"velocity 2.0 is not one value per axis"
                           r".*Fix: give a value for each axis to change \(x, y, z\), "
                           r"e.g. \{'x': \.\.\.\}"):
            stage.velocity = 2.0
        with pytest.raises(DeviceValueError, match=r"unknown axis 'w'.*\['x', 'y', 'z'\]"):
            stage.backlash = {"w": 0.1}
    with SimulatedDmd("dmd") as dmd:
        with pytest.raises(DeviceValueError, match=r"unknown colour 'uv'"):
            dmd.led_currents = {"uv": 0.5}
    with SimulatedCamera("cam0") as cam:
        with pytest.raises(DeviceValueError, match=r"exposure_s=-1 .*0 < exposure_s"):
            cam.exposure_s = -1  # "> 0" named before the sensor's range
        with pytest.raises(DeviceValueError, match=r"1e-06 <= exposure_s <= 60"):
            cam.exposure_s = 100.0


def test_settings_model_is_a_schema_of_the_declarations():
    import pydantic

    from drivers.settings import settings_model
    from drivers.slm import Slm

    model = settings_model(Camera)
    schema = model.model_json_schema()
    assert list(schema["properties"]) == list(Camera._SETTINGS)
    assert "[s]" in schema["properties"]["exposure_s"]["description"]
    assert "info.exposure_range_s[0]" in schema["properties"]["exposure_s"]["description"]
    with SimulatedCamera("cam0") as cam:
        assert model.model_validate(cam.settings()).exposure_s == cam.exposure_s
    for bad in ({"exposure_s": -1.0}, {"trigger_mode": "sometimes"}, {"no_such": 1},
                {"binning": 0}):
        with pytest.raises(pydantic.ValidationError):
            model.model_validate(bad)
    slm = settings_model(Slm)
    with pytest.raises(pydantic.ValidationError):
        slm.model_validate({"settle_s": 61.0})  # the declared 60 s limit, in one place
    assert slm.model_validate({"settle_s": 60.0}).settle_s == 60.0
    stage = settings_model(SimulatedStage)
    assert stage.model_validate({"velocity": {"x": 2.0}}).velocity == {"x": 2.0}
    with pytest.raises(pydantic.ValidationError):
        stage.model_validate({"velocity": {"x": 0.0}})
    assert "temperature_c" not in settings_model(_CappedGain).model_fields  # read-only
