"""What the device panel shows about each setting: its label, unit and limits.

The limits come from the device itself (:attr:`drivers.base.Device.info`, the ranges
its interface validates against); the panel only shows them. Whether a value is
accepted is decided by the device interface (:meth:`drivers.base.Device.apply_settings`),
whose message the panel shows when it refuses one.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

__all__ = ["SETTINGS", "limits_text", "parse_duration_s", "parse_value", "value_text"]

#: ``{kind: {setting: (label, unit)}}`` for the settings the panel edits.
SETTINGS: dict[str, dict[str, tuple[str, str]]] = {
    "camera": {
        "exposure_s": ("exposure", "ms or s"),
        "frame_rate_hz": ("frame rate", "Hz"),
        "gain": ("gain", "dB"),
        "pixel_format": ("pixel format", ""),
        "binning": ("binning", "x"),
        "roi": ("ROI x, y, w, h", "px"),
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
    lo, hi = (float(v) for v in pair)
    if math.isinf(lo) and math.isinf(hi):
        return "no limit"
    if math.isinf(hi):
        return f"{lo:g} {unit} or more".replace("  ", " ")
    if math.isinf(lo):
        return f"up to {hi:g} {unit}".rstrip()
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
        return "; ".join(f"{a} {_range(v['travel'], AXIS_UNITS[a])}"
                         for a, v in axes.items())
    if kind == "led_array":
        if name == "colour":
            return "one of " + ", ".join(info["colours"])
        return "0 to 1" if name == "brightness" else "0 (excl.) to 1"
    if kind == "slm" and name == "settle_s":
        return "0 to 60 s"
    return ""


def value_text(value: Any, name: str | None = None) -> str:
    """A setting's value as the panel's text field shows it (JSON for mappings; a time
    below a second in ms, with its unit)."""
    if isinstance(value, dict | list | tuple):
        return json.dumps(value)
    if isinstance(value, float):
        if name is not None and name.endswith("_s"):
            return f"{1e3 * value:.6g} ms" if abs(value) < 1.0 else f"{value:.6g} s"
        return f"{value:.6g}"
    return str(value)


#: Time units an operator may type, in seconds.
TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6,
              "min": 60.0}
_DURATION = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµμ]*)\s*$")


def parse_duration_s(text: str, what: str = "exposure") -> float | None:
    """A time typed by the operator, in seconds: ``"20 ms"``, ``"0.02 s"``, ``"20000
    us"``, ``"0.02"`` (a bare number is seconds); None for an empty field.

    Raises
    ------
    gui.workers.InputError
        Not a number with one of :data:`TIME_UNITS` (the message names ``what`` and
        shows examples).
    """
    from .workers import InputError

    if not text.strip():
        return None
    m = _DURATION.match(text.strip().lower())
    if m is None or m.group(2) not in ("", *TIME_UNITS):
        raise InputError(f"{what} {text.strip()!r}: give a time such as 20 ms, 0.02 s or "
                         "500 us")
    return float(m.group(1)) * TIME_UNITS.get(m.group(2) or "s", 1.0)


def parse_value(text: str, name: str | None = None) -> Any:
    """The operator's text as a setting value: a time with its unit for a setting in
    seconds (``exposure_s``: ``"20 ms"``), else JSON (numbers, lists, mappings) when it
    parses, else the text itself (the device interface then names what it expects).

    Raises
    ------
    gui.workers.InputError
        A time setting that is not a time (:func:`parse_duration_s`).
    """
    text = text.strip()
    if name is not None and name.endswith("_s"):
        return parse_duration_s(text, name.removesuffix("_s").replace("_", " "))
    try:
        return json.loads(text)
    except ValueError:
        return text
