"""Bench-file values that are numbers of the right type but cannot describe the bench.

Part of :mod:`instrument.config`. The models check types and ranges; these rules catch
what those let through and a lab gets wrong in practice, each reported on its TOML
line with the fix (:func:`instrument.config.problems.locate`):

* :func:`param_value_problems` - a device's speeds and rates (``*_mm_s``, ``*_deg_s``,
  ``*_um_s``, ``*_hz``, ``speed*``) and encoder scales (``counts_per_unit``,
  ``*_per_unit``) must be positive and finite; two axes of one stage cannot share a
  controller serial number (``serial_numbers``, ``device_numbers``; a multi-bay
  controller lists its ``bays``); an LED array's ``pitch_mm`` / ``distance_mm`` below
  :data:`MIN_LENGTH_MM` is a length written in metres;
* :func:`metres_problem` - the same for the geometry's lengths in millimetres;
* :func:`camera_geometry_problems` - the camera's own sensor shape and pixel pitch
  (its ``params``) must be the geometry's (``sensor_shape_px``,
  ``sensor_pixel_pitch_um``): the geometry describes that camera.
"""

from __future__ import annotations

import math
from typing import Any

from .base import TWIN_PARAM_ALIASES, short_repr

__all__ = ["ID_TABLES", "MIN_LENGTH_MM", "camera_geometry_problems", "metres_problem",
           "param_value_problems"]

#: A macroscopic length (a distance, an aperture, an LED pitch) below this many mm is
#: taken for one written in metres (8.9 mm written 0.0089).
MIN_LENGTH_MM = 0.1

_RATE_SUFFIXES = ("_mm_s", "_deg_s", "_um_s", "_hz")
#: Parameters that say which controller drives which axis: a device whose table has a
#: problem is not constructed without it (another controller layout would be checked).
ID_TABLES = ("serial_numbers", "device_numbers", "bays")
_LED_LENGTHS = ("pitch_mm", "distance_mm")

Triple = tuple[tuple, str, str]


def _positive_key(key: str) -> bool:
    k = key.lower()
    return k.endswith(_RATE_SUFFIXES) or k.startswith("speed") or k == "counts_per_unit" \
        or k.endswith("_per_unit")


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def metres_problem(loc: tuple, key: str, value: Any) -> Triple | None:
    """A length in mm below :data:`MIN_LENGTH_MM` (a value written in metres), or None."""
    items = value if isinstance(value, list | tuple) else [value]
    if not items or not all(_number(v) for v in items):
        return None
    small = [v for v in items if 0 < v < MIN_LENGTH_MM]
    if not small:
        return None
    fixed = [round(v * 1000, 6) for v in items] if len(items) > 1 else round(items[0] * 1000, 6)
    return (loc, f"{short_repr(value)} mm is {small[0] * 1000:g} um: a length in metres, "
            "not millimetres?", f"write {key} = {fixed} (the unit is in the key name: mm)")


def param_value_problems(params: dict[str, Any], kind: str | None) -> list[Triple]:
    """The rules of the module notes on one device's ``params`` (locations relative to
    ``params``)."""
    out: list[Triple] = []

    def walk(table: dict, loc: tuple, rule_key: str | None) -> None:
        for key, value in table.items():
            here = (*loc, key)
            governing = key if _positive_key(key) else rule_key
            if isinstance(value, dict):
                walk(value, here, governing)
                continue
            if governing is None:
                continue
            for v in value if isinstance(value, list) else [value]:
                if _number(v) and not (math.isfinite(v) and v > 0):
                    what = "an encoder scale" if "per_unit" in governing else "a speed or rate"
                    out.append((here, f"{governing} = {short_repr(v)}: {what} must be a "
                                f"finite number > 0",
                                f"give the positive value (e.g. {governing} = 2.0), or leave "
                                "it out for the driver's default"))
                    break

    walk(params, (), None)
    for name in ID_TABLES[:2]:
        table = params.get(name)
        if not isinstance(table, dict) or "bays" in params:
            continue
        owners: dict[str, list[str]] = {}
        for axis, number in table.items():
            owners.setdefault(str(number), []).append(str(axis))
        for number, axes in owners.items():
            if len(axes) > 1:
                out.append(((name, axes[1]),
                            f"axes {', '.join(axes)} share {name[:-1].replace('_', ' ')} "
                            f"{number!r}: one controller drives one axis",
                            f"give each axis its own controller's {name[:-1].replace('_', ' ')}"
                            " (or, for one multi-bay controller, list the axes' bays in bays)"))
    if kind == "led_array":
        for key in _LED_LENGTHS:
            if key in params:
                found = metres_problem((key,), key, params[key])
                if found:
                    out.append(found)
    return out


def camera_geometry_problems(devices: Any, geometry: Any) -> list[Triple]:
    """The camera's sensor shape and pixel pitch against the geometry's (locations
    relative to the bench; a bench of one camera only)."""
    if not isinstance(devices, list) or not isinstance(geometry, dict):
        return []
    out: list[Triple] = []
    shape, pitch = geometry.get("sensor_shape_px"), geometry.get("sensor_pixel_pitch_um")
    cameras = [(i, d) for i, d in enumerate(devices)
               if isinstance(d, dict) and d.get("kind") == "camera"]
    if len(cameras) != 1:  # none, or several (a problem of its own): which one is meant?
        return []
    for i, dev in cameras:
        params = dev.get("params") if isinstance(dev.get("params"), dict) else {}
        if "binning" in params:  # a binned camera's shape is the geometry's over the binning
            continue
        for key in TWIN_PARAM_ALIASES["camera"]["sensor_shape"]:
            given = params.get(key)
            valid = isinstance(given, list) and len(given) == 2 and \
                all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in given)
            if valid and isinstance(shape, list | tuple) and list(given) != list(shape):
                out.append((("devices", i, "params", key),
                            f"the camera's {key} {short_repr(given)} contradicts "
                            f"geometry.sensor_shape_px {short_repr(list(shape))}: the geometry "
                            "describes this camera",
                            "make them agree (the camera's sensor, rows then cols)"))
        given = params.get("pixel_pitch_um")
        valid = _number(given) and math.isfinite(given) and given > 0  # else: the driver's
        if valid and _number(pitch) and not math.isclose(given, pitch, rel_tol=1e-6):
            out.append((("devices", i, "params", "pixel_pitch_um"),
                        f"the camera's pixel_pitch_um {given:g} contradicts "
                        f"geometry.sensor_pixel_pitch_um {pitch:g}: the geometry describes "
                        "this camera", "make them agree (the camera's pixel pitch, um)"))
    return out
