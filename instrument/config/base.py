"""Shared constants, unit handling and the pydantic base section of bench files.

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, get_origin

from pydantic import (
    BaseModel,
    ConfigDict,
    ValidationInfo,
    field_validator,
)
from pydantic_core import PydanticCustomError

#: Device kinds, as drivers declare them in their class attribute ``kind``.
KINDS: tuple[str, ...] = ("camera", "stage", "led_array", "slm", "dmd")
#: Valid stage axis names (translations, then rotations of a 6-axis mount).
STAGE_AXES: tuple[str, ...] = ("x", "y", "z", "tip", "tilt", "rotation")
#: Optical branches a bench can have.
BRANCHES: tuple[str, ...] = ("lensless", "holography")
#: The simulated twin of each kind (registry names).
SIMULATED_DRIVERS: dict[str, str] = {
    "camera": "simulated-camera",
    "stage": "simulated-stage",
    "led_array": "simulated-led-array",
    "slm": "simulated-slm",
    "dmd": "simulated-dmd",
}
#: Parameter names a simulated twin takes under another name, per kind:
#: ``{twin name: (names in a bench file, first found wins)}``.
TWIN_PARAM_ALIASES: dict[str, dict[str, tuple[str, ...]]] = {
    "camera": {
        "sensor_shape": ("sensor_shape", "sensor_shape_px", "shape_px", "size_px"),
        "adc_bits": ("adc_bits", "bit_depth"),
    },
    "stage": {"velocity": ("velocity", "speed_mm_s")},
    "led_array": {"shape": ("shape", "shape_px")},
    "slm": {"resolution": ("resolution", "resolution_px", "shape_px")},
    "dmd": {"resolution": ("resolution", "resolution_px", "shape_px")},
}

#: What a device id may be: 1-64 of ``a-z``, ``0-9``, ``_``, ``-``.
ID_RE = re.compile(r"^[a-z0-9_-]{1,64}$")

# --------------------------------------------------------------------------- units

_UNIT_WORDS = {
    "nm": "nanometres",
    "um": "micrometres",
    "mm": "millimetres",
    "m": "metres",
    "s": "seconds",
    "ms": "milliseconds",
    "us": "microseconds",
    "hz": "hertz",
    "deg": "degrees",
    "rad": "radians",
    "px": "pixels",
}
# (dimension, factor to the SI base unit)
_UNIT_SCALE = {
    "nm": ("length", 1e-9),
    "um": ("length", 1e-6),
    "µm": ("length", 1e-6),
    "μm": ("length", 1e-6),
    "micron": ("length", 1e-6),
    "microns": ("length", 1e-6),
    "mm": ("length", 1e-3),
    "cm": ("length", 1e-2),
    "m": ("length", 1.0),
    "ns": ("time", 1e-9),
    "us": ("time", 1e-6),
    "µs": ("time", 1e-6),
    "μs": ("time", 1e-6),
    "ms": ("time", 1e-3),
    "s": ("time", 1.0),
    "sec": ("time", 1.0),
    "min": ("time", 60.0),
    "h": ("time", 3600.0),
    "hz": ("frequency", 1.0),
    "khz": ("frequency", 1e3),
    "deg": ("angle", math.pi / 180),
    "rad": ("angle", 1.0),
    "mrad": ("angle", 1e-3),
    "px": ("pixels", 1.0),
}
_QUANTITY_RE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-zµμ]*)\s*$")


def unit_of(key: str) -> str | None:
    """The unit suffix of a key name.

    Parameters
    ----------
    key : str
        A TOML key such as ``distance_mm`` or ``speed_mm_s``.

    Returns
    -------
    str or None
        ``"mm"``, ``"mm/s"``, ...; None without a unit suffix (also for ``..._per_s``
        rates of unnamed quantities).
    """
    parts = key.lower().split("_")
    if len(parts) < 2 or parts[-1] not in _UNIT_WORDS:
        return None
    if parts[-1] == "s" and len(parts) >= 3:
        if parts[-2] == "per":
            return None
        if parts[-2] in _UNIT_WORDS and parts[-2] not in ("s", "px"):
            return f"{parts[-2]}/s"
    return parts[-1]


def unit_word(unit: str) -> str:
    """The unit spelled out for messages (``"mm/s"`` -> ``"millimetres per second"``).

    Parameters
    ----------
    unit : str
        A unit returned by :func:`unit_of`.

    Returns
    -------
    str
    """
    if unit.endswith("/s"):
        return f"{_UNIT_WORDS[unit[:-2]]} per second"
    return _UNIT_WORDS[unit]


def short_repr(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters, so that a message stays one readable
    line whatever a file holds (a 4000-digit number, a deeply nested table).

    Parameters
    ----------
    value : object
    limit : int

    Returns
    -------
    str
    """
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _fmt_number(x: float) -> str:
    return f"{x:.12g}"


def unit_fix(key: str, unit: str, got: str) -> str:
    """The fix for a string given where a number in ``unit`` is expected.

    Parameters
    ----------
    key : str
        The key (its name carries the unit).
    unit : str
        The key's unit (:func:`unit_of`).
    got : str
        The string given, e.g. ``"5 cm"``.

    Returns
    -------
    str
        The fix, with the value converted to ``unit`` when the string's unit is of
        the same dimension (``"'5 cm' is 50 mm: write distance_mm = 50"``).
    """
    m = _QUANTITY_RE.match(got)
    if m:
        value, given = float(m.group(1)), m.group(2)
        if not given:
            return f"write {key} = {_fmt_number(value)} (a number, without quotes)"
        src = _UNIT_SCALE.get(given) or _UNIT_SCALE.get(given.lower())
        dst = _UNIT_SCALE.get(unit)
        if src and dst and src[0] == dst[0]:
            converted = value * src[1] / dst[1]
            if given.lower() == unit:
                return f"write {key} = {_fmt_number(converted)} (the unit is in the key name)"
            return f"{got!r} is {_fmt_number(converted)} {unit}: write {key} = " + _fmt_number(
                converted
            )
    return f"write {key} as a plain number in {unit_word(unit)}"


def _check_number(key: str, value: Any, *, integer: bool = False, in_pair: bool = False) -> None:
    """Refuse strings (naming the unit) and booleans where a number is expected
    (``in_pair``: an element of a ``[a, b]`` pair)."""
    unit = unit_of(key)
    what = "an integer" if integer else "a number"
    if isinstance(value, str):
        if unit:
            fix = unit_fix(key, unit, value)
            if in_pair:  # "write z_range_mm = 20" would drop the other value
                fix = fix.replace(f"write {key} = ", "write that value as ")
            raise PydanticCustomError(
                "unit",
                "expected {unit_word} as a number, got {got}",
                {
                    "unit_word": unit_word(unit),
                    "got": short_repr(value),
                    "fix": fix,
                },
            )
        raise PydanticCustomError(
            "number",
            "expected {what}, got {got}",
            {
                "what": what,
                "got": repr(value),
                "fix": f"write {key} = <{what[2:].strip()}> without quotes",
            },
        )
    if isinstance(value, bool):
        raise PydanticCustomError(
            "number",
            "expected {what}, got {got}",
            {
                "what": what,
                "got": str(value).lower(),
                "fix": f"write {key} as {what}, not true/false",
            },
        )


@dataclass(frozen=True)
class Range:
    """Annotated marker: the plausible range of a numeric field (each element of a pair)."""

    lo: float
    hi: float
    lo_open: bool = True
    integer: bool = False

    def text(self) -> str:
        left = "(" if self.lo_open else "["
        return f"{left}{_fmt_number(self.lo)}, {_fmt_number(self.hi)}]"

    def contains(self, x: float) -> bool:
        above = x > self.lo if self.lo_open else x >= self.lo
        return bool(above and x <= self.hi)


@dataclass(frozen=True)
class Ordered:
    """Annotated marker: a (minimum, maximum) pair must be ordered (``strict``: min < max)."""

    strict: bool


class Section(BaseModel):
    """Base of the TOML tables: unknown keys refused, numbers checked for units and range
    (:class:`Range`), (minimum, maximum) pairs for order (:class:`Ordered`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @classmethod
    def _marker(cls, name: str, marker: type) -> Any:
        field = cls.model_fields.get(name)
        if field is None:
            return None
        return next((m for m in field.metadata if isinstance(m, marker)), None)

    @classmethod
    def _range(cls, name: str) -> Range | None:
        return cls._marker(name, Range)

    @field_validator("*", mode="before")
    @classmethod
    def _strict_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        rng = cls._range(info.field_name)
        if rng is None:
            return value
        pair = get_origin(cls.model_fields[info.field_name].annotation) is tuple
        if pair and isinstance(value, str):
            unit = unit_of(info.field_name)
            raise PydanticCustomError(
                "number",
                "expected two numbers{in_unit}, got {got}",
                {
                    "in_unit": f" in {unit_word(unit)}" if unit else "",
                    "got": short_repr(value),
                    "fix": f"write {info.field_name} = [a, b] (an array of two plain numbers)",
                },
            )
        items = value if isinstance(value, list | tuple) else [value]
        for item in items:
            _check_number(info.field_name, item, integer=rng.integer, in_pair=pair)
        return value

    @field_validator("*", mode="after")
    @classmethod
    def _in_range(cls, value: Any, info: ValidationInfo) -> Any:
        rng = cls._range(info.field_name)
        if rng is None or value is None:
            return value
        items = value if isinstance(value, tuple) else (value,)
        unit = unit_of(info.field_name)
        unit_text = f" {unit}" if unit and unit != "px" else ""
        for x in items:
            if not (math.isfinite(x) and rng.contains(x)):
                got = short_repr(value if len(items) == 1 else list(value))
                raise PydanticCustomError(
                    "range",
                    "out of range: expected {each}{range}{unit}, got {got}",
                    {
                        "each": "each value in " if len(items) > 1 else "a value in ",
                        "range": rng.text(),
                        "unit": unit_text,
                        "got": got,
                        "fix": f"set {info.field_name} within {rng.text()}{unit_text}",
                    },
                )
        order = cls._marker(info.field_name, Ordered)
        if order is not None:
            _check_ordered(info.field_name, value, strict=order.strict)
        return value


def _check_ordered(name: str, pair: tuple[float, float], *, strict: bool) -> None:
    """Refuse a (minimum, maximum) pair out of order (a field validator's helper)."""
    lo, hi = pair
    if lo < hi or (not strict and lo == hi):
        return
    rel = "<" if strict else "<="
    raise PydanticCustomError(
        "order",
        "the first value (minimum) must be {rel} the second (maximum), got [{lo}, {hi}]",
        {
            "rel": rel,
            "lo": _fmt_number(lo),
            "hi": _fmt_number(hi),
            "fix": f"write {name} = [{_fmt_number(min(lo, hi))}, {_fmt_number(max(lo, hi))}]",
        },
    )


def dotted(loc: tuple | list) -> str:
    """A validation location as a dotted path: ``("devices", 1, "driver")`` ->
    ``"devices[1].driver"``.

    Parameters
    ----------
    loc : tuple or list of str and int

    Returns
    -------
    str
    """
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out
