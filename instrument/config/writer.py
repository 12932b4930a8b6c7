"""Writing a BenchConfig back to TOML (with field descriptions as comments).

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

import math
import re
from typing import Any

from .base import Section
from .models import BenchConfig

# ------------------------------------------------------------------------- to_toml

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else _toml_string(key)


def _toml_string(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_value(v: Any) -> str:
    """A value as TOML text (inline arrays and tables; None items are left out).

    Parameters
    ----------
    v : bool, int, float, str, list, tuple or dict

    Returns
    -------
    str

    Raises
    ------
    TypeError
        A value TOML cannot hold.
    """
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v if x is not None) + "]"
    if isinstance(v, dict):
        items = [f"{_toml_key(k)} = {toml_value(x)}" for k, x in v.items() if x is not None]
        return "{" + ", ".join(items) + "}" if items else "{}"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _toml_table(model: Section, data: dict[str, Any], *, comments: bool) -> list[str]:
    lines = []
    for key, value in data.items():
        if value is None:
            continue
        field = type(model).model_fields.get(key)
        if comments and field is not None and field.description:
            lines.append(f"# {field.description}")
        lines.append(f"{_toml_key(key)} = {toml_value(value)}")
    return lines


def to_toml(config: BenchConfig, *, comments: bool = True) -> str:
    """The bench as TOML text that :func:`instrument.devices.bench_setup.parse_bench` reads back to
    an equal config.

    Written by a small serializer (no dependency): top-level keys, ``[geometry]``,
    ``[calibration]``, then one ``[[devices]]`` table per device with its
    ``[devices.params]``. With ``comments``, each key is preceded by its description.
    """
    data = config.model_dump()
    out = _toml_table(
        config,
        {k: data[k] for k in ("name", "description", "branches")},
        comments=comments,
    )
    for section in ("geometry", "calibration"):
        out += ["", f"[{section}]"]
        out += _toml_table(getattr(config, section), data[section], comments=comments)
    for dev, raw in zip(config.devices, data["devices"], strict=True):
        out += ["", "[[devices]]"]
        out += _toml_table(dev, {k: raw[k] for k in ("id", "kind", "driver")}, comments=False)
        params = {k: v for k, v in raw["params"].items() if v is not None}
        if params:
            out += ["", "[devices.params]"]
            out += [f"{_toml_key(k)} = {toml_value(v)}" for k, v in params.items()]
    return "\n".join(out) + "\n"
