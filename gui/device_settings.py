"""What the device panel shows about each setting: its label, unit and limits.

The limits come from the device itself (:attr:`drivers.base.Device.info`, the ranges
its interface validates against); the panel only shows them. Whether a value is
accepted is decided by the device interface (:meth:`drivers.base.Device.apply_settings`),
whose message the panel shows when it refuses one.
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["SETTINGS", "limits_text", "parse_value", "value_text"]

#: ``{kind: {setting: (label, unit)}}`` for the settings the panel edits.
SETTINGS: dict[str, dict[str, tuple[str, str]]] = {
    "camera": {
        "exposure_s": ("exposure", "s"),
        "frame_rate_hz": ("frame rate", "Hz"),
        "gain": ("gain", "dB"),
        "pixel_format": ("pixel format", ""),
        "binning": ("binning", "x"),
        "roi": ("ROI (x, y, width, height)", "px"),
        "trigger_mode": ("trigger", ""),
    },
    "stage": {
        "velocity": ("velocity", "per axis"),
        "backlash": ("backlash", "per axis"),
        "limits": ("soft limits", "per axis"),
    },
    "led_array": {
        "brightness": ("brightness", "0-1"),
        "na_illum": ("illumination NA", ""),
        "colour": ("colour", ""),
    },
    "slm": {
        "settle_s": ("settle time", "s"),
    },
}


def _range(pair: Any, unit: str) -> str:
    lo, hi = pair
    return f"{lo:g} to {hi:g} {unit}".rstrip()


def limits_text(device, name: str) -> str:
    """The limits of setting ``name`` of an open ``device``, as the panel shows them.

    Parameters
    ----------
    device : drivers.base.Device
        An open device.
    name : str
        One of its settings.

    Returns
    -------
    str
        E.g. ``"1e-05 to 10 s"``, ``"one of mono8, mono12"``; ``""`` when the
        interface states no range.
    """
    info = device.info
    kind = device.kind
    if kind == "camera":
        if name == "exposure_s":
            return _range(info["exposure_range_s"], "s")
        if name == "frame_rate_hz":
            return _range(info["frame_rate_range_hz"], "Hz")
        if name == "gain":
            return _range((0.0, info["gain_range_db"][1]), "dB")
        if name == "pixel_format":
            return "one of " + ", ".join(info["pixel_formats"])
        if name == "binning":
            return f"1 to {info['max_binning']}"
        if name == "trigger_mode":
            return "free_run, software or hardware"
        if name == "roi":
            rows, cols = info["sensor_shape"]
            return f"within {cols} x {rows} px"
    if kind == "stage":
        from drivers.stage import AXIS_UNITS

        axes = info["axes"]
        if name == "velocity":
            return "; ".join(f"{a} <= {v['max_velocity']:g} {AXIS_UNITS[a]}/s"
                             for a, v in axes.items())
        return "; ".join(f"{a} {v['travel'][0]:g}..{v['travel'][1]:g} {AXIS_UNITS[a]}"
                         for a, v in axes.items())
    if kind == "led_array":
        if name == "colour":
            return "one of " + ", ".join(info["colours"])
        return "0 to 1" if name == "brightness" else "0 (excl.) to 1"
    if kind == "slm" and name == "settle_s":
        return "0 to 60 s"
    return ""


def value_text(value: Any) -> str:
    """A setting's value as the panel's text field shows it (JSON for mappings)."""
    if isinstance(value, dict | list | tuple):
        return json.dumps(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def parse_value(text: str) -> Any:
    """The operator's text as a setting value: JSON (numbers, lists, mappings) when it
    parses, else the text itself (the device interface then names what it expects)."""
    text = text.strip()
    try:
        return json.loads(text)
    except ValueError:
        return text
