"""The device panel's rows are generated from the settings declarations
(drivers/settings.py): every declared setting of every device kind is a row with the
declared unit and the limits of the open device; a limit changed in a declaration
changes the widget; a read-only setting has no Apply."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from drivers.settings import Setting, with_settings  # noqa: E402
from drivers.settings_doc import KINDS  # noqa: E402
from drivers.simulated import (  # noqa: E402
    SimulatedCamera,
    SimulatedDmd,
    SimulatedLedArray,
    SimulatedSlm,
    SimulatedStage,
)
from gui.workers import InputError  # noqa: E402

SIMULATED = {"camera": SimulatedCamera, "stage": SimulatedStage,
             "led_array": SimulatedLedArray, "slm": SimulatedSlm, "dmd": SimulatedDmd}


def _box(device):
    """A device's box, its commands served here by a bench of that one device."""
    from types import SimpleNamespace

    from gui.panels.devices import DeviceBox
    from instrument.bench.bench_service import BenchService, EventLog, device_info

    service = BenchService()
    service.bench = SimpleNamespace(devices={device.device_id: device})
    service.device_events = EventLog()
    return DeviceBox(device_info(device.device_id, device), service, "bench/test-rows")


def test_every_kind_has_a_simulated_driver_here():
    assert set(SIMULATED) == set(KINDS)  # a new kind: add its simulated driver above


@pytest.mark.parametrize("kind", list(SIMULATED))
def test_every_declared_setting_is_a_row_with_its_unit_and_limits(qapp, kind):
    from PySide6.QtWidgets import QFormLayout, QLabel, QPushButton

    with SIMULATED[kind](f"{kind}0") as dev:
        box = _box(dev)
        try:
            assert list(box.fields) == [s.name for s in type(dev).SETTINGS]
            titles = [w.text() for w in box.findChildren(QLabel)]
            for s in type(dev).SETTINGS:
                limits = s.limits_text(dev.info)
                assert box.limit_labels[s.name].text() == (f"limits: {limits}" if limits
                                                           else "")
                row = box.rows[s.name]
                if s.per is None and s.unit:
                    assert row.unit == s.unit and f"({s.unit}):" in " ".join(titles)
                if s.per is not None:
                    assert row.unit.endswith(f"per {s.key_name}")
                assert s.description in box.fields[s.name].toolTip()
                apply = box.findChild(QPushButton, f"{dev.device_id}.{s.name}.apply")
                assert (apply is None) == s.read_only
            forms = [f for f in box.findChildren(QFormLayout)]
            assert sum(f.rowCount() for f in forms) >= len(type(dev).SETTINGS)
        finally:
            box.deleteLater()


def test_the_dmd_has_its_rows_with_per_colour_limits(qapp):
    with SimulatedDmd("dmd") as dmd:
        box = _box(dmd)
        assert box.limit_labels["exposure_s"].text() == "limits: 0 (excl.) to 10 s"
        assert box.limit_labels["led_currents"].text() == (
            "limits: red 0 to 1; green 0 to 1; blue 0 to 1")
        assert box.rows["led_currents"].title == "LED currents (per colour)"
        box.deleteLater()


class _SlowSlm(SimulatedSlm):
    """An SLM whose declaration narrows the settle time and adds a read-only value."""

    SETTINGS = with_settings(SimulatedSlm.SETTINGS,
                             SimulatedSlm.setting("settle_s").replace(high=2.5),
                             Setting("temperature_c", "float", "degC", "panel temperature",
                                     read_only=True))

    def _do_get_settings(self):
        return {**super()._do_get_settings(), "temperature_c": 31.5}


def test_a_limit_changed_in_the_declaration_changes_the_widget(qapp):
    with SimulatedSlm("slm") as plain:
        box = _box(plain)
        assert box.limit_labels["settle_s"].text() == "limits: 0 to 60 s"
        box.deleteLater()
    with _SlowSlm("slm") as slow:
        box = _box(slow)
        assert box.limit_labels["settle_s"].text() == "limits: 0 to 2.5 s"
        assert "limits 0 to 2.5 s" in box.fields["settle_s"].toolTip()
        assert box.fields["temperature_c"].isReadOnly()
        assert box.fields["temperature_c"].text() == "31.5"
        assert box.rows["temperature_c"].title == "temperature c (degC)"
        box.save_preset("p")
        assert "temperature_c" not in box.presets()["p"]  # never applied
        box.deleteLater()


def test_values_are_parsed_by_the_declared_type():
    from gui.device_settings import parse_value

    settle = SimulatedSlm.setting("settle_s")
    assert parse_value("20 ms", "settle_s", settle) == pytest.approx(0.02)
    binning = SimulatedCamera.setting("binning")
    assert parse_value("2", "binning", binning) == 2
    with pytest.raises(InputError, match=r"binning 'two' is not a whole number.*1 to "
                       r"info.max_binning"):
        parse_value("two", "binning", binning)
    gain = SimulatedCamera.setting("gain")
    with pytest.raises(InputError, match=r"gain 'loud' is not a number: give a number in dB"):
        parse_value("loud", "gain", gain)
    assert parse_value('{"x": 2}', "velocity", SimulatedStage.setting("velocity")) == {"x": 2}


def test_per_axis_fields_read_as_words_with_units(qapp):
    with SimulatedStage("stage") as stage:
        box = _box(stage)
        try:
            assert box.fields["limits"].text() == ("x -25 to 25 mm, y -25 to 25 mm, "
                                                   "z 0 to 50 mm")
            assert box.fields["backlash"].text() == "x 0 mm, y 0 mm, z 0 mm"
            assert box.fields["velocity"].text() == "x 5 mm/s, y 5 mm/s, z 5 mm/s"
            assert "{" not in box.limit_labels["limits"].text()
        finally:
            box.deleteLater()


def test_a_refused_value_leaves_the_field_showing_what_the_device_holds(qapp, wait):
    """Backlash 400 mm (beyond 50) is refused: the field goes back to the device's 0,
    and the message says what was refused and what the device keeps; one number sets
    every axis."""
    with SimulatedStage("stage") as stage:
        box = _box(stage)
        try:
            field = box.fields["backlash"]
            field.setText("400")
            field.setModified(True)
            job = box.apply("backlash")
            wait(lambda: job.done, 10, "the refusal")
            assert stage.backlash == {"x": 0.0, "y": 0.0, "z": 0.0}
            assert field.text() == "x 0 mm, y 0 mm, z 0 mm"
            assert not field.isModified()
            assert "'400' refused" in box.error.text()
            assert "keeps backlash x 0 mm" in box.error.text()
            field.setText("x 0.2 mm, z 0.1")
            job = box.apply("backlash")
            wait(lambda: job.done, 10, "the change")
            assert stage.backlash == {"x": 0.2, "y": 0.0, "z": 0.1}
            assert field.text() == "x 0.2 mm, y 0 mm, z 0.1 mm" and box.error.text() == ""
        finally:
            box.deleteLater()
