"""What the device panel shows about each setting, generated from the declarations.

Each row of a device's box is one :class:`~drivers.settings.Setting` its class
declares (:attr:`instrument.bench.bench_service.DeviceInfo.settings_declared`, in the order
they apply): its label comes from the name, its unit, limits (numbers read from the open
device's :attr:`~drivers.base.Device.info`), description and read-only flag from the
declaration, so a new device kind or setting needs no edit here. Whether a value is
accepted is decided by the device interface (:meth:`drivers.base.Device.apply_settings`),
whose message the panel shows when it refuses one.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any

__all__ = ["LIST_SHOWN_MAX", "Row", "label_of", "limits_text", "parse_duration_s",
           "parse_value", "rows", "summarized", "value_text"]

#: Name endings that repeat the unit (``exposure_s``: "exposure", unit s).
_UNIT_SUFFIX = re.compile(r"_(s|hz|db|mm|um|nm|rad|deg|px)$")
#: Abbreviations written in capitals in a label.
_CAPITALS = {"roi": "ROI", "na": "NA", "lut": "LUT", "led": "LED"}


def label_of(name: str) -> str:
    """The row's label for setting ``name``: words, without a unit suffix
    (``"frame_rate_hz"`` -> ``"frame rate"``, ``"na_illum"`` -> ``"NA illum"``)."""
    words = _UNIT_SUFFIX.sub("", name).split("_")
    return " ".join(_CAPITALS.get(w, w) for w in words)


@dataclass(frozen=True)
class Row:
    """One setting as the panel shows it.

    Attributes
    ----------
    name : str
        The setting's key (``device.settings()[name]``).
    label : str
        The row's label (:func:`label_of`).
    unit : str
        The declared unit (``"per axis"`` for a per-axis setting whose unit
        differs per axis, the units then in ``limits``).
    limits : str
        The limits with the open device's numbers
        (:meth:`drivers.settings.Setting.limits_text`).
    tooltip : str
        The declaration's description, type and limits.
    read_only : bool
        Shown, not editable (no Apply).
    spec : drivers.settings.Setting
        The declaration itself.
    """

    name: str
    label: str
    unit: str
    limits: str
    tooltip: str
    read_only: bool
    spec: Any

    @property
    def title(self) -> str:
        """The form's label: ``"exposure (s)"``."""
        return f"{self.label} ({self.unit})" if self.unit else self.label


def rows(device) -> list[Row]:
    """The rows of an open ``device``: one per declared setting, in declaration order.

    Parameters
    ----------
    device : instrument.bench.bench_service.DeviceInfo
        An open device (its info gives the limits' numbers).

    Returns
    -------
    list of Row
    """
    info = device.info
    out = []
    for s in device.settings_declared:
        if s.per is None:
            unit = s.unit_of()
        elif "{unit}" in s.unit:
            unit = f"per {s.key_name}"
        else:
            unit = f"{s.unit} per {s.key_name}".strip()
        limits = s.limits_text(info)
        dtype = s.dtype if s.per is None else f"{{{s.key_name}: {s.dtype}}}"
        tip = "; ".join(p for p in (s.description, f"type {dtype}",
                                    f"limits {limits}" if limits else "",
                                    "read-only" if s.read_only else "") if p)
        if s.unit == "s" and s.per is None:
            tip += "; type a time with its unit: 20 ms, 0.02 s, 500 us"
        out.append(Row(s.name, label_of(s.name), unit, limits, tip, s.read_only, s))
    return out


def limits_text(device, name: str) -> str:
    """The limits of setting ``name`` of an open ``device`` (a
    :class:`~instrument.bench.bench_service.DeviceInfo`), as the panel shows them (from its
    declaration, :meth:`drivers.settings.Setting.limits_text`).

    Returns
    -------
    str
        E.g. ``"1e-05 to 10 s"``, ``"one of mono8, mono12"``; ``""`` when the
        declaration states no range.

    Raises
    ------
    KeyError
        The device declares no setting ``name``.
    """
    return device.driver_class.setting(name).limits_text(device.info)


def _number_text(value: Any) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


#: A list of more numbers than this (an SLM's 256-phase lookup table) is shown as a
#: summary, its count and range, not typed in the panel (:func:`summarized`).
LIST_SHOWN_MAX = 8


def summarized(value: Any) -> bool:
    """Whether :func:`value_text` shows ``value`` as a summary (a long list of
    numbers), which the panel shows read-only."""
    return (isinstance(value, list | tuple) and len(value) > LIST_SHOWN_MAX
            and all(isinstance(v, int | float) for v in value))


def value_text(value: Any, name: str | None = None, spec=None) -> str:
    """A setting's value as the panel's text field shows it.

    A time below a second in ms, with its unit; a per-axis (per-key) setting as the
    operator types it, each key with its value and unit (``"x 0.1 mm, y 0 mm,
    rotation 0 deg"``; a pair as ``"x -25 to 25 mm"``: :func:`parse_value` reads it
    back); a long list of numbers as its count and range (``"256 values, 0 to 6.26
    rad"``: :func:`summarized`); other mappings and lists as JSON.

    Parameters
    ----------
    value : object
    name : str, optional
        The setting's name (a name ending in ``_s`` is a time).
    spec : drivers.settings.Setting, optional
        Its declaration (the per-key units).
    """
    if isinstance(value, dict) and value and all(isinstance(k, str) for k in value) and all(
            isinstance(v, int | float) or (isinstance(v, list | tuple) and len(v) == 2)
            for v in value.values()):
        parts = []
        for key, v in value.items():
            unit = spec.unit_of(key) if spec is not None and spec.per is not None else ""
            number = (f"{_number_text(v[0])} to {_number_text(v[1])}"
                      if isinstance(v, list | tuple) else _number_text(v))
            parts.append(f"{key} {number} {unit}".rstrip())
        return ", ".join(parts)
    if summarized(value):
        unit = spec.unit_of() if spec is not None and spec.per is None else ""
        return f"{len(value)} values, {min(value):.3g} to {max(value):.3g} {unit}".rstrip()
    if isinstance(value, dict | list | tuple):
        return json.dumps(value)
    if isinstance(value, float):
        if name is not None and name.endswith("_s"):
            return f"{1e3 * value:.6g} ms" if abs(value) < 1.0 else f"{value:.6g} s"
        return f"{value:.6g}"
    return str(value)


_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
#: One key of a per-key value: ``x 0.1 mm``, ``x: 0.1``, ``x = -25 to 25 mm``.
_KEYED = re.compile(rf"^\s*(\w+)\s*[:=]?\s*({_NUM})(?:\s*(?:to|\.\.)\s*({_NUM}))?"
                    r"\s*([^\s\d,;]*)\s*$")
#: One value for every key: ``40``, ``0.5 mm``, ``-25 to 25``.
_ALL_KEYS = re.compile(rf"^\s*({_NUM})(?:\s*(?:to|\.\.)\s*({_NUM}))?\s*([^\s\d,;]*)\s*$")


def _per_key_value(text: str, spec, keys) -> dict[str, Any]:
    """``"x 0.1 mm, y 0"`` (the keys given), or one value for every key (``"0.1"``)."""
    from .workers import InputError

    example = f"{keys[0] if keys else 'x'} 0.1, {keys[1] if len(keys) > 1 else 'y'} 0"
    kind = spec.key_name

    def number(key: str | None, low: str, high: str | None, unit: str) -> Any:
        want = spec.unit_of(key) if key is not None else ""
        if unit and key is not None and unit != want:
            raise InputError(f"{spec.name} of {key}: {unit!r} is not its unit; give it in "
                             f"{want or 'plain numbers'}")
        return [float(low), float(high)] if high is not None else float(low)

    whole = _ALL_KEYS.match(text)
    if whole is not None:
        if not keys:
            raise InputError(f"{spec.name}: give a value per {kind}, e.g. {example}")
        return {k: number(k, whole.group(1), whole.group(2), whole.group(3)) for k in keys}
    out: dict[str, Any] = {}
    for part in filter(str.strip, re.split(r"[,;]", text)):
        m = _KEYED.match(part)
        if m is None:
            raise InputError(f"{spec.name} {part.strip()!r}: give a value per {kind}, e.g. "
                             f"{example} (one number sets every {kind})")
        if keys and m.group(1) not in keys:
            raise InputError(f"{spec.name}: there is no {kind} {m.group(1)!r}; the {kind} "
                             f"names are {', '.join(keys)}")
        out[m.group(1)] = number(m.group(1), m.group(2), m.group(3), m.group(4))
    return out


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


def parse_value(text: str, name: str | None = None, spec=None, keys=None) -> Any:
    """The operator's text as a setting value.

    With the setting's declaration ``spec`` (:class:`drivers.settings.Setting`): a
    time with its unit for a setting declared in seconds (``"20 ms"``), a number for a
    ``float``/``int`` setting, per-axis values as :func:`value_text` writes them
    (``"x 0.1 mm, y 0"``: the axes named; one number for all of ``keys``), else JSON
    (lists, mappings), else the text itself (the device interface then names what it
    expects). Without it, a name ending in ``_s`` is taken as a time.

    Parameters
    ----------
    text : str
    name : str, optional
    spec : drivers.settings.Setting, optional
    keys : sequence of str, optional
        The keys of a per-key setting on the open device (its axes).

    Raises
    ------
    gui.workers.InputError
        A time setting that is not a time (:func:`parse_duration_s`); a number setting
        that is not a number (the message names the setting and its limits); a per-axis
        value with an unknown axis or the wrong unit.
    """
    from .workers import InputError

    text = text.strip()
    is_time = (spec.unit == "s" and spec.per is None) if spec is not None else (
        name is not None and name.endswith("_s"))
    if is_time:
        return parse_duration_s(text, (name or spec.name).removesuffix("_s").replace("_", " "))
    try:
        value = json.loads(text)
    except ValueError:
        value = text
    if spec is not None and spec.per is not None and not isinstance(value, dict):
        return _per_key_value(text, spec, list(keys or ()))
    if spec is not None and spec.per is None and spec.dtype in ("float", "int") and (
            isinstance(value, bool) or not isinstance(value, int | float)):
        what = "a whole number" if spec.dtype == "int" else "a number"
        unit = f" in {spec.unit}" if spec.unit else ""
        raise InputError(f"{spec.name} {text!r} is not {what}: give {what}{unit} "
                         f"({spec.limits_text()})".replace(" ()", ""))
    return value
