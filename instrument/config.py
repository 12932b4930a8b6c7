"""Bench configuration: a TOML file validated into pydantic models.

A bench file describes the devices (each with an id, a kind, a driver name looked up
in :mod:`instrument.registry`, and driver parameters), the optical geometry and the
calibration defaults::

    name = "lab-1"
    branches = ["lensless"]

    [geometry]
    sensor_pixel_pitch_um = 3.45
    ...

    [[devices]]
    id = "camera"
    kind = "camera"
    driver = "simulated-camera"

    [devices.params]
    sensor_shape = [480, 640]

Units are in the key names (``_um``, ``_mm``, ``_nm``, ``_s``, ``_px``): a value is a
plain number in that unit. Strings such as ``"5 cm"`` are refused with a message
naming the expected unit and the converted number to write instead. Driver
parameters whose names end in a unit suffix follow the same rule.

Bench rules (checked across fields):

* device ids are unique and use only ``a-z``, ``0-9``, ``_`` and ``-``;
* a bench with the ``"lensless"`` branch has exactly one camera: the diffuser camera
  the geometry describes, which plans take their frames from without naming it;
* a bench with the ``"holography"`` branch has at least one SLM;
* every stage lists its axes in ``params.axes``: a table of travel ranges
  ``{x = [low, high], ...}`` (mm for x, y, z; degrees for tip, tilt, rotation) or an
  array of names, names from :data:`STAGE_AXES`;
* every driver is known to the registry, drives the device's kind and takes the
  parameters given (checked by :func:`load_bench` unless ``check_drivers=False``;
  ``construct=True`` also constructs each device, unopened, to check the values).

Every problem found is reported at once in one :class:`BenchConfigError`, each with
its location (dotted path, TOML line where known) and a fix.
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

__all__ = [
    "BRANCHES",
    "KINDS",
    "SIMULATED_DRIVERS",
    "STAGE_AXES",
    "TWIN_PARAM_ALIASES",
    "BenchConfig",
    "BenchConfigError",
    "CalibrationDefaults",
    "DeviceConfig",
    "GeometryConfig",
    "Problem",
    "default_bench",
    "load_bench",
    "parse_bench",
    "simulated_twin",
    "to_toml",
    "with_simulated_drivers",
]

#: Device kinds, as drivers declare them in their class attribute ``kind``.
KINDS: tuple[str, ...] = ("camera", "stage", "led_array", "slm")
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
}
#: Parameter names a simulated twin takes under another name, per kind:
#: ``{twin name: (names in a bench file, first found wins)}``.
TWIN_PARAM_ALIASES: dict[str, dict[str, tuple[str, ...]]] = {
    "camera": {
        "sensor_shape": ("sensor_shape", "sensor_shape_px", "shape_px"),
        "adc_bits": ("adc_bits", "bit_depth"),
    },
    "stage": {},
    "led_array": {"shape": ("shape", "shape_px")},
    "slm": {"resolution": ("resolution", "resolution_px", "shape_px")},
}

_ID_RE = re.compile(r"^[a-z0-9_-]{1,64}$")

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


def _unit_of(key: str) -> str | None:
    """The unit suffix of a key name (``distance_mm`` -> ``mm``, ``speed_mm_s`` ->
    ``mm/s``), or None (also for ``..._per_s`` rates of unnamed quantities)."""
    parts = key.lower().split("_")
    if len(parts) < 2 or parts[-1] not in _UNIT_WORDS:
        return None
    if parts[-1] == "s" and len(parts) >= 3:
        if parts[-2] == "per":
            return None
        if parts[-2] in _UNIT_WORDS and parts[-2] not in ("s", "px"):
            return f"{parts[-2]}/s"
    return parts[-1]


def _unit_word(unit: str) -> str:
    if unit.endswith("/s"):
        return f"{_UNIT_WORDS[unit[:-2]]} per second"
    return _UNIT_WORDS[unit]


def _fmt_number(x: float) -> str:
    return f"{x:.12g}"


def _unit_fix(key: str, unit: str, got: str) -> str:
    """The fix for a string given where a number in ``unit`` is expected."""
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
    return f"write {key} as a plain number in {_unit_word(unit)}"


def _check_number(key: str, value: Any, *, integer: bool = False) -> None:
    """Refuse strings (naming the unit) and booleans where a number is expected."""
    unit = _unit_of(key)
    what = "an integer" if integer else "a number"
    if isinstance(value, str):
        if unit:
            raise PydanticCustomError(
                "unit",
                "expected {unit_word} as a number, got {got}",
                {
                    "unit_word": _unit_word(unit),
                    "got": repr(value),
                    "fix": _unit_fix(key, unit, value),
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


class _Section(BaseModel):
    """Base of the TOML tables: unknown keys refused, numbers checked for units and range."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @classmethod
    def _range(cls, name: str) -> Range | None:
        field = cls.model_fields.get(name)
        if field is None:
            return None
        return next((m for m in field.metadata if isinstance(m, Range)), None)

    @field_validator("*", mode="before")
    @classmethod
    def _strict_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        rng = cls._range(info.field_name)
        if rng is None:
            return value
        items = value if isinstance(value, list | tuple) else [value]
        for item in items:
            _check_number(info.field_name, item, integer=rng.integer)
        return value

    @field_validator("*", mode="after")
    @classmethod
    def _in_range(cls, value: Any, info: ValidationInfo) -> Any:
        rng = cls._range(info.field_name)
        if rng is None or value is None:
            return value
        items = value if isinstance(value, tuple) else (value,)
        unit = _unit_of(info.field_name)
        unit_text = f" {unit}" if unit and unit != "px" else ""
        for x in items:
            if not (math.isfinite(x) and rng.contains(x)):
                got = value if len(items) == 1 else list(value)
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
        return value


def _pair_ordered(model: _Section, name: str, *, strict: bool) -> None:
    lo, hi = getattr(model, name)
    if lo < hi or (not strict and lo == hi):
        return
    rel = "<" if strict else "<="
    raise PydanticCustomError(
        "bench_rules",
        "{summary}",
        {
            "summary": f"{name}: the first value must be {rel} the second, got [{lo}, {hi}]",
            "problems": [
                (
                    (name,),
                    f"the first value (minimum) must be {rel} the second (maximum), "
                    f"got [{_fmt_number(lo)}, {_fmt_number(hi)}]",
                    f"write {name} = [{_fmt_number(min(lo, hi))}, {_fmt_number(max(lo, hi))}]",
                )
            ],
        },
    )


# ------------------------------------------------------------------------- models


class GeometryConfig(_Section):
    """Optical geometry of the lensless camera (SI-prefixed units in the names)."""

    sensor_pixel_pitch_um: Annotated[float, Range(0, 50)] = Field(
        description="sensor pixel pitch, micrometres"
    )
    sensor_shape_px: Annotated[tuple[int, int], Range(8, 32768, False, True)] = Field(
        description="sensor size in pixels, (rows, cols)"
    )
    diffuser_sensor_distance_mm: Annotated[float, Range(0, 500)] = Field(
        description="distance from the diffuser to the sensor, millimetres"
    )
    aperture_mm: Annotated[tuple[float, float], Range(0, 200)] = Field(
        description="clear aperture in front of the diffuser, (width, height) millimetres"
    )
    diffuser_kind: Literal["smooth", "microlens"] = Field(
        description='"smooth" (random smooth surface) or "microlens" (random microlens array)'
    )
    wavelength_nm: Annotated[float, Range(200, 2000, False)] = Field(
        532.0, description="design wavelength, nanometres"
    )


class CalibrationDefaults(_Section):
    """Defaults of the calibration plans (each plan may override them)."""

    z_range_mm: Annotated[tuple[float, float], Range(0, 10000)] = Field(
        (20.0, 200.0), description="point-source distances of the PSF z-sweep, (min, max) mm"
    )
    n_depths: Annotated[int, Range(1, 10000, False, True)] = Field(
        32, description="number of depths in the PSF z-sweep"
    )
    frames_per_point: Annotated[int, Range(1, 10000, False, True)] = Field(
        4, description="frames averaged at each sweep point"
    )
    dark_frames: Annotated[int, Range(0, 100000, False, True)] = Field(
        32, description="frames of the dark calibration"
    )
    exposure_bounds_s: Annotated[tuple[float, float], Range(0, 3600)] = Field(
        (1e-5, 1.0), description="auto-exposure limits, (min, max) seconds"
    )
    settle_s: Annotated[float, Range(0, 600, False)] = Field(
        0.2, description="wait after each stage move before the next frame, seconds"
    )

    @model_validator(mode="after")
    def _ordered(self) -> CalibrationDefaults:
        _pair_ordered(self, "z_range_mm", strict=True)
        _pair_ordered(self, "exposure_bounds_s", strict=False)
        return self


class DeviceConfig(_Section):
    """One device: id, kind, driver (registry name) and driver parameters."""

    id: str = Field(description="unique device id: a-z, 0-9, _ and -")
    kind: Literal["camera", "stage", "led_array", "slm"] = Field(description="device kind")
    driver: str = Field(description="driver name in the registry (diffuserlab.drivers)")
    params: dict[str, Any] = Field(default_factory=dict, description="driver parameters")

    @field_validator("id", mode="after")
    @classmethod
    def _id_ok(cls, value: str) -> str:
        if not _ID_RE.match(value):
            suggestion = re.sub(r"[^a-z0-9_-]+", "_", value.lower()).strip("_")[:64] or "camera"
            raise PydanticCustomError(
                "device_id",
                "invalid device id {got}: use 1-64 characters from a-z, 0-9, '_' and '-'",
                {"got": repr(value), "fix": f'write id = "{suggestion}"'},
            )
        return value

    @field_validator("driver", mode="after")
    @classmethod
    def _driver_ok(cls, value: str) -> str:
        if not value.strip():
            raise PydanticCustomError(
                "driver",
                "empty driver name",
                {"fix": 'write a registry name, e.g. driver = "simulated-camera"'},
            )
        return value

    @field_validator("params", mode="after")
    @classmethod
    def _param_units(cls, value: dict[str, Any]) -> dict[str, Any]:
        problems = []

        def walk(d: dict[str, Any], loc: tuple) -> None:
            for key, v in d.items():
                if isinstance(v, dict):
                    walk(v, (*loc, key))
                    continue
                unit = _unit_of(key)
                items = v if isinstance(v, list) else [v]
                if unit and any(isinstance(x, str) for x in items):
                    bad = next(x for x in items if isinstance(x, str))
                    problems.append(
                        (
                            (*loc, key),
                            f"expected {_unit_word(unit)} as a number, got {bad!r}",
                            _unit_fix(key, unit, bad),
                        )
                    )

        walk(value, ())
        if problems:
            raise PydanticCustomError(
                "bench_rules",
                "{summary}",
                {
                    "summary": "; ".join(f"{'.'.join(p[0])}: {p[1]}" for p in problems),
                    "problems": problems,
                },
            )
        return value

    @model_validator(mode="after")
    def _stage_axes(self) -> DeviceConfig:
        if self.kind != "stage":
            return self
        problems = _axes_problems(self.params.get("axes"))
        if problems:
            raise PydanticCustomError(
                "bench_rules",
                "{summary}",
                {
                    "summary": "; ".join(f"{_dotted(p[0])}: {p[1]}" for p in problems),
                    "problems": problems,
                },
            )
        return self


def _axes_problems(axes: Any) -> list[tuple[tuple, str, str]]:
    """Problems of a stage's ``params.axes``: a table ``{name = [low, high]}`` of travel
    ranges (mm for x, y, z; degrees for tip, tilt, rotation) or an array of names."""
    valid = ", ".join(STAGE_AXES)
    example = "axes = { x = [-25, 25], y = [-25, 25], z = [0, 50] }"
    loc = ("params", "axes")
    if axes is None:
        return [
            (
                loc,
                "a stage lists its axes in params.axes",
                f"add {example} under [devices.params] (travel in mm for x, y, z, degrees for "
                f"tip, tilt, rotation; names from {valid})",
            )
        ]
    if isinstance(axes, dict):
        names = list(axes)
    elif isinstance(axes, list) and all(isinstance(a, str) for a in axes):
        names = axes
    else:
        names = []
    if not names:
        return [
            (
                loc,
                f"expected a table of axis travel ranges or an array of axis names, got {axes!r}",
                f'write {example} (or axes = ["x", "y", "z"])',
            )
        ]
    bad = [a for a in names if a not in STAGE_AXES]
    if bad:
        close = {a: difflib.get_close_matches(a, STAGE_AXES, 1) for a in bad}
        hint = ", ".join(f"{a!r} -> {c[0]!r}" for a, c in close.items() if c)
        return [
            (
                loc,
                f"unknown stage axis name(s) {bad}",
                f"use names from {valid}" + (f" ({hint})" if hint else ""),
            )
        ]
    dup = sorted({a for a in names if names.count(a) > 1})
    if dup:
        return [(loc, f"duplicate stage axis name(s) {dup}", "list each axis once")]
    out = []
    if isinstance(axes, dict):
        for name, travel in axes.items():
            unit = "mm" if name in ("x", "y", "z") else "deg"
            items = travel if isinstance(travel, list) else [travel]
            text = next((t for t in items if isinstance(t, str)), None)
            if text is not None:
                out.append(
                    (
                        (*loc, name),
                        f"expected {_unit_word(unit)} as a number, got {text!r}",
                        f"travel of {name} is [low, high] in {_unit_word(unit)}: "
                        + _unit_fix(name + "_" + unit, unit, text).replace(f"{name}_{unit} = ", ""),
                    )
                )
                continue
            ok = (
                isinstance(travel, list)
                and len(travel) == 2
                and all(isinstance(t, int | float) and not isinstance(t, bool) for t in travel)
                and all(math.isfinite(t) for t in travel)
                and travel[0] < travel[1]
            )
            if not ok:
                out.append(
                    (
                        (*loc, name),
                        f"travel of axis {name!r} must be [low, high] with low < high, "
                        f"got {travel!r}",
                        f"write {name} = [low, high] in {_unit_word(unit)}, e.g. "
                        f"{name} = {list(_DEFAULT_TRAVEL[name])}",
                    )
                )
    return out


#: Travel given to a simulated twin's axis when the bench file lists only names.
_DEFAULT_TRAVEL: dict[str, tuple[float, float]] = {
    "x": (-25.0, 25.0),
    "y": (-25.0, 25.0),
    "z": (0.0, 50.0),
    "tip": (-5.0, 5.0),
    "tilt": (-5.0, 5.0),
    "rotation": (-180.0, 180.0),
}


def bench_rule_problems(devices: list[Any], branches: Any) -> list[tuple[tuple, str, str]]:
    """Cross-device rules (unique ids, one camera, an SLM) on possibly malformed raw data.

    Returns ``(location, message, fix)`` triples, the location relative to the bench.
    """
    out: list[tuple[tuple, str, str]] = []
    if not isinstance(devices, list):
        return out
    entries = [
        (i, d.get("id"), d.get("kind")) for i, d in enumerate(devices) if isinstance(d, dict)
    ]
    first: dict[str, int] = {}
    for i, dev_id, _ in entries:
        if not isinstance(dev_id, str):
            continue
        if dev_id in first:
            out.append(
                (
                    ("devices", i, "id"),
                    f"duplicate device id {dev_id!r} (already used by devices[{first[dev_id]}])",
                    f'give each device its own id, e.g. id = "{dev_id}_2"',
                )
            )
        else:
            first[dev_id] = i
    branch_list = branches if isinstance(branches, list) else []
    cameras = [(i, dev_id) for i, dev_id, kind in entries if kind == "camera"]
    if "lensless" in branch_list:
        if not cameras:
            out.append(
                (
                    ("devices",),
                    "a lensless bench has exactly one camera (the diffuser camera), found none",
                    'add a [[devices]] table with kind = "camera" (e.g. driver = '
                    '"simulated-camera")',
                )
            )
        for i, dev_id in cameras[1:]:
            others = ", ".join(f"devices[{j}] {d!r}" for j, d in cameras)
            out.append(
                (
                    ("devices", i, "kind"),
                    f"a lensless bench has exactly one camera (the diffuser camera the geometry "
                    f"describes), found {len(cameras)}: {others}",
                    f"remove camera {dev_id!r} or describe it in a bench file of its own",
                )
            )
    if "holography" in branch_list and not any(k == "slm" for _, _, k in entries):
        out.append(
            (
                ("devices",),
                "a holography bench needs at least one SLM, found none",
                'add a [[devices]] table with kind = "slm" (e.g. driver = "simulated-slm"), '
                'or remove "holography" from branches',
            )
        )
    return out


class BenchConfig(_Section):
    """A whole bench: devices, optical geometry and calibration defaults."""

    name: str = Field(description="bench name")
    description: str = Field("", description="free text")
    branches: list[Literal["lensless", "holography"]] = Field(
        default_factory=lambda: ["lensless"],
        description='optical branches: "lensless" and/or "holography"',
    )
    devices: list[DeviceConfig] = Field(description="the devices, one [[devices]] table each")
    geometry: GeometryConfig = Field(description="optical geometry")
    calibration: CalibrationDefaults = Field(
        default_factory=CalibrationDefaults, description="calibration defaults"
    )

    @field_validator("name", mode="after")
    @classmethod
    def _name_ok(cls, value: str) -> str:
        if not value.strip():
            raise PydanticCustomError("name", "empty bench name", {"fix": 'write name = "lab-1"'})
        return value

    @model_validator(mode="after")
    def _rules(self) -> BenchConfig:
        problems = bench_rule_problems(
            [{"id": d.id, "kind": d.kind} for d in self.devices], list(self.branches)
        )
        if problems:
            raise PydanticCustomError(
                "bench_rules",
                "{summary}",
                {
                    "summary": "; ".join(f"{_dotted(p[0])}: {p[1]}" for p in problems),
                    "problems": problems,
                },
            )
        return self

    def device(self, device_id: str) -> DeviceConfig:
        """The device with this id (KeyError naming the ids if absent)."""
        for d in self.devices:
            if d.id == device_id:
                return d
        raise KeyError(f"no device {device_id!r}; ids: {[d.id for d in self.devices]}")


# ------------------------------------------------------------------------ problems


def _dotted(loc: tuple | list) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


@dataclass(frozen=True)
class Problem:
    """One problem in a bench file: where (dotted path, TOML line), what, and the fix."""

    location: str
    message: str
    fix: str
    line: int | None = None
    column: int | None = None

    def format(self, source: str | None = None) -> str:
        """``source:line: location: message; fix: ...`` (parts omitted when unknown)."""
        where = ""
        if source:
            where = str(source)
            if self.line is not None:
                where += f":{self.line}"
                if self.column is not None:
                    where += f":{self.column}"
            where += ": "
        elif self.line is not None:
            where = f"line {self.line}: "
        return f"{where}{self.location}: {self.message}; fix: {self.fix}"

    def __str__(self) -> str:
        return self.format()


class BenchConfigError(ValueError):
    """A bench file or configuration with problems; ``problems`` lists every one of them."""

    def __init__(self, problems: list[Problem], source: str | None = None):
        self.problems = list(problems)
        self.source = source
        n = len(self.problems)
        head = f"{source}: " if source else ""
        super().__init__(
            f"{head}{n} problem{'s' if n != 1 else ''} in the bench configuration:\n"
            + "\n".join(p.format(source) for p in self.problems)
        )

    def lines(self) -> list[str]:
        """One line per problem, with the file, line, location and fix."""
        return [p.format(self.source) for p in self.problems]


_TABLE_MODELS: dict[str, type[_Section]] = {
    "": BenchConfig,
    "geometry": GeometryConfig,
    "calibration": CalibrationDefaults,
    "devices": DeviceConfig,
}


def _model_for(loc: tuple) -> type[_Section] | None:
    names = [p for p in loc if isinstance(p, str)]
    return _TABLE_MODELS.get(".".join(names))


def _example(loc: tuple) -> str | None:
    """An example value (TOML) for a key, taken from the default bench."""
    names = [p for p in loc if isinstance(p, str)]
    if not names:
        return None
    if names[0] == "devices":
        return {
            "id": '"camera"',
            "kind": '"camera"',
            "driver": '"simulated-camera"',
        }.get(names[-1])
    node: Any = default_bench().model_dump()
    for name in names:
        if not isinstance(node, dict) or name not in node:
            return None
        node = node[name]
    if isinstance(node, dict | list) and names[-1] in ("devices", "geometry", "calibration"):
        return None
    return _toml_value(node)


def _table_hint(loc: tuple) -> str:
    parent = loc[:-1]
    names = [p for p in parent if isinstance(p, str)]
    if not names:
        return "at the top of the file"
    if names[0] == "devices":
        idx = next((p for p in parent if isinstance(p, int)), None)
        where = f"[[devices]] table number {idx + 1}" if idx is not None else "[[devices]] table"
        return f"in the {where}" if len(names) == 1 else f"under [devices.{'.'.join(names[1:])}]"
    return f"under [{'.'.join(names)}]"


def _problems_from_validation(exc: ValidationError) -> list[Problem]:
    problems: list[Problem] = []
    for err in exc.errors(include_url=False):
        loc = tuple(err["loc"])
        typ = err["type"]
        ctx = err.get("ctx") or {}
        key = next((p for p in reversed(loc) if isinstance(p, str)), "")
        got = err.get("input")
        if "problems" in ctx:
            base = loc  # () for the bench-level rules
            for sub, msg, fix in ctx["problems"]:
                problems.append(Problem(_dotted(base + tuple(sub)), msg, fix))
            continue
        if "fix" in ctx:
            problems.append(Problem(_dotted(loc), err["msg"], ctx["fix"]))
            continue
        # Built-in pydantic errors, reworded with a fix.
        if typ == "missing":
            if loc and isinstance(loc[-1], int):  # short tuple
                msg, fix = "too few values", f"write two values, e.g. {_example(loc[:-1])}"
                loc = loc[:-1]
            else:
                ex = _example(loc)
                if key in ("devices", "geometry", "calibration"):
                    header = "[[devices]]" if key == "devices" else f"[{key}]"
                    msg = f"missing required table {header}"
                    fix = f"add a {header} table (see examples/bench-simulated.toml)"
                else:
                    msg = "missing required key"
                    fix = f"add {key} = {ex if ex else '...'} {_table_hint(loc)}"
        elif typ == "extra_forbidden":
            model = _model_for(loc[:-1])
            known = list(model.model_fields) if model else []
            close = difflib.get_close_matches(key, known, 1)
            msg = f"unknown key {key!r}"
            fix = f"did you mean {close[0]!r}?" if close else "remove it"
            if known:
                fix += f" (known keys: {', '.join(known)})"
            if model is DeviceConfig:
                fix += "; driver parameters go under [devices.params]"
        elif typ == "literal_error":
            msg = f"expected {ctx.get('expected')}, got {got!r}"
            fix = f"write {key} = one of {ctx.get('expected')}"
        elif typ == "too_long" or typ == "too_short":
            msg = f"expected {ctx.get('max_length', ctx.get('min_length'))} values, got {got!r}"
            fix = f"write {key} = {_example(loc) or '[a, b]'}"
        elif typ == "list_type" and loc == ("devices",):
            msg = "devices must be an array of tables"
            fix = "write each device as its own [[devices]] table (double brackets)"
        elif typ in ("model_type", "dict_type"):
            msg = f"expected a table, got {got!r}"
            fix = f"write [{_dotted(loc)}] as a table with its keys below it"
        elif typ in ("string_type",):
            msg = f"expected a string, got {got!r}"
            fix = f'write {key} = "..." (in quotes)'
        elif typ.startswith(("int_", "float_")) or typ in ("tuple_type", "list_type"):
            unit = _unit_of(key)
            in_unit = f" in {_unit_word(unit)}" if unit else ""
            msg = f"{err['msg'].lower()}, got {got!r}"
            fix = f"write {key} as {'numbers' if 'tuple' in typ else 'a number'}{in_unit}"
            ex = _example(loc)
            if ex:
                fix += f", e.g. {key} = {ex}"
        else:
            msg, fix = err["msg"], "see examples/bench-simulated.toml"
        problems.append(Problem(_dotted(loc), msg, fix))
    return problems


# ------------------------------------------------------------- TOML line locator

_HEADER_RE = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY_RE = re.compile(
    r"""^\s*((?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*'))*)\s*="""
)  # noqa: E501


def _split_key(text: str) -> list[str]:
    parts = re.findall(r"""[A-Za-z0-9_-]+|"[^"]*"|'[^']*'""", text)
    return [p.strip("\"'") for p in parts]


def _line_index(text: str) -> dict[str, int]:
    """Best-effort map from dotted paths (``devices[1].driver``) to 1-based line numbers."""
    index: dict[str, int] = {}
    counts: dict[str, int] = {}
    prefix: list[str] = []

    def resolve(parts: list[str]) -> list[str]:
        out: list[str] = []
        for p in parts:
            path = _join(out + [p])
            out.append(f"{p}[{counts[path] - 1}]" if path in counts else p)
        return out

    for n, line in enumerate(text.splitlines(), 1):
        m = _HEADER_RE.match(line)
        if m and not _KEY_RE.match(line):
            parts = _split_key(m.group(2))
            if m.group(1) == "[[":
                parent = resolve(parts[:-1])
                path = _join(parent + [parts[-1]])
                counts[path] = counts.get(path, 0) + 1
                index.setdefault(path, n)
                prefix = parent + [f"{parts[-1]}[{counts[path] - 1}]"]
            else:
                prefix = resolve(parts)
            index.setdefault(_join(prefix), n)
            continue
        k = _KEY_RE.match(line)
        if k:
            index.setdefault(_join(prefix + _split_key(k.group(1))), n)
    return index


def _join(parts: list[str]) -> str:
    return ".".join(parts).replace(".[", "[")


def _locate(problem: Problem, index: dict[str, int]) -> Problem:
    if problem.line is not None:
        return problem
    path = problem.location
    while path:
        if path in index:
            return Problem(problem.location, problem.message, problem.fix, index[path])
        cut = max(path.rfind("."), path.rfind("["))
        path = path[:cut] if cut > 0 else ""
    return problem


# ---------------------------------------------------------------------- loading

_TOML_POS_RE = re.compile(r"\(at line (\d+), column (\d+)\)")


_NUMBER_WITH_UNIT_RE = re.compile(r"=\s*[-+]?\d[\d._eE+-]*\s*[A-Za-zµμ]+\s*(#.*)?$")


def _syntax_fix(msg: str, line_text: str = "") -> str:
    low = msg.lower()
    if _NUMBER_WITH_UNIT_RE.search(line_text):
        return "write the number without its unit: the unit is in the key name (e.g. _mm, _s)"
    if "expected newline" in low or "end of line" in low:
        return "one key = value per line; put comments after #"
    if "invalid value" in low:
        return (
            'quote strings ("..."), write numbers without units (the unit is in the key '
            "name), arrays as [a, b]"
        )
    if "cannot overwrite" in low or "cannot declare" in low or "duplicate" in low:
        return "a key or table is defined twice: keep one (repeated devices use [[devices]])"
    if "expected '=' after a key" in low:
        return "write key = value"
    if "unclosed" in low or "end of" in low:
        return "close the string, array or table header"
    return "correct the TOML syntax at that position"


def _syntax_problem(exc: tomllib.TOMLDecodeError, text: str) -> Problem:
    msg = str(exc)
    m = _TOML_POS_RE.search(msg)
    line = col = None
    if m:
        line, col = int(m.group(1)), int(m.group(2))
        msg = msg[: m.start()].strip()
    elif msg.endswith("(at end of document)"):
        line = max(1, len(text.splitlines()))
        msg = msg[: -len("(at end of document)")].strip() + " (at the end of the file)"
    snippet = line_text = ""
    lines = text.splitlines()
    if line is not None and 1 <= line <= len(lines):
        line_text = lines[line - 1]
        snippet = f": {line_text.strip()!r}"
    where = f"line {line}" + (f", column {col}" if col is not None else "")
    if line is None:
        where = "unknown position"
    return Problem(
        "(TOML syntax)", f"{msg} at {where}{snippet}", _syntax_fix(msg, line_text), line, col
    )


def parse_bench(
    text: str,
    *,
    source: str | None = None,
    check_drivers: bool = True,
    simulate: bool = False,
    construct: bool = False,
) -> BenchConfig:
    """Validate TOML text as a bench; raises :class:`BenchConfigError` with every problem.

    Parameters
    ----------
    text : str
        The TOML document.
    source : str, optional
        Name used in messages (a file path).
    check_drivers : bool
        Also check every driver name in the registry and its kind (imports the
        drivers).
    simulate : bool
        Return the bench with every device swapped for its simulated twin
        (:func:`with_simulated_drivers`); the drivers checked are then the twins, so a
        lab file validates on a machine without its hardware drivers.
    construct : bool
        Also construct every device (without opening it), so parameter values the
        driver refuses are reported here rather than at open (``validate`` does).
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BenchConfigError([_syntax_problem(exc, text)], source) from None
    problems: list[Problem] = []
    config = None
    try:
        config = BenchConfig.model_validate(raw)
    except ValidationError as exc:
        problems = _problems_from_validation(exc)
        if not any(
            p.message.startswith(("duplicate device id", "a lensless bench", "a holography"))
            for p in problems
        ):
            problems += [
                Problem(_dotted(loc), msg, fix)
                for loc, msg, fix in bench_rule_problems(
                    raw.get("devices"), raw.get("branches", ["lensless"])
                )
            ]
    if check_drivers:
        from instrument.registry import driver_problems

        devices = raw.get("devices")
        if simulate and config is not None:  # the twins, with their translated params
            devices = [d.model_dump() for d in with_simulated_drivers(config).devices]
        elif simulate and isinstance(devices, list):  # invalid file: check the twins' names
            devices = [
                {"id": d.get("id"), "kind": d["kind"], "driver": SIMULATED_DRIVERS[d["kind"]]}
                if isinstance(d, dict) and d.get("kind") in SIMULATED_DRIVERS
                else d
                for d in devices
            ]
        problems += driver_problems(devices)
    if construct and config is not None and not problems:
        from instrument.registry import construction_problems

        problems += construction_problems(with_simulated_drivers(config) if simulate else config)
    if problems:
        index = _line_index(text)
        located = [_locate(p, index) for p in problems]
        located.sort(key=lambda p: (p.line is None, p.line or 0))
        raise BenchConfigError(located, source)
    assert config is not None
    return with_simulated_drivers(config) if simulate else config


def load_bench(
    path: str | Path,
    *,
    check_drivers: bool = True,
    simulate: bool = False,
    construct: bool = False,
) -> BenchConfig:
    """Read and validate a bench TOML file (options as in :func:`parse_bench`).

    Raises
    ------
    BenchConfigError
        Unreadable file, TOML syntax error (line and column), missing keys, unknown
        keys, wrong units or ranges, duplicate ids, bench rules, unknown drivers or a
        driver of another kind: every problem found, each with location and fix.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        fix = "check the path" if isinstance(exc, FileNotFoundError) else "check the file"
        if isinstance(exc, IsADirectoryError):
            fix = "give the path of a .toml file, not a directory"
        elif isinstance(exc, PermissionError):
            fix = "make the file readable (chmod) or copy it"
        problem = Problem("(file)", f"cannot read: {reason}", fix)
        raise BenchConfigError([problem], str(path)) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise BenchConfigError(
            [Problem("(file)", "not UTF-8 text", "save the file as UTF-8 TOML", line)], str(path)
        ) from None
    return parse_bench(
        text,
        source=str(path),
        check_drivers=check_drivers,
        simulate=simulate,
        construct=construct,
    )


# ------------------------------------------------------------------- default bench


def default_bench() -> BenchConfig:
    """The built-in simulated bench (what ``examples/bench-simulated.toml`` holds).

    A simulated camera (256 x 320 pixels of 13 um: a PCO.edge's 6.5 um pixels binned
    2 x 2 as in Ch. 4; the aperture lets the PSF of a source at 20 mm just fill it), a 3-axis
    stage (x, y, z; z travel covers the calibration z range) carrying the point
    source, a 32x32 LED array, a 96 x 120 SLM and a 6-axis mask stage (x, y, z, tip,
    tilt, rotation) for the holography branch. Parameters are the simulated drivers'
    constructor arguments.
    """
    return BenchConfig(
        name="simulated",
        description=(
            "Built-in simulated bench: diffuser camera with a point source on an xyz "
            "stage and a 32x32 LED array; holography branch with an SLM and a 6-axis "
            "mask stage."
        ),
        branches=["lensless", "holography"],
        devices=[
            DeviceConfig(
                id="camera",
                kind="camera",
                driver="simulated-camera",
                params={"sensor_shape": [256, 320], "pixel_pitch_um": 13.0, "adc_bits": 12},
            ),
            DeviceConfig(
                id="source_stage",
                kind="stage",
                driver="simulated-stage",
                params={"axes": {"x": [-25.0, 25.0], "y": [-25.0, 25.0], "z": [0.0, 250.0]}},
            ),
            DeviceConfig(
                id="led_array",
                kind="led_array",
                driver="simulated-led-array",
                params={"shape": [32, 32], "pitch_mm": 4.0, "distance_mm": 50.0},
            ),
            DeviceConfig(
                id="slm",
                kind="slm",
                driver="simulated-slm",
                params={"resolution": [96, 120], "pixel_pitch_um": 8.0, "wavelength_nm": 532.0},
            ),
            DeviceConfig(
                id="mask_stage",
                kind="stage",
                driver="simulated-stage",
                params={
                    "axes": {
                        "x": [-5.0, 5.0],
                        "y": [-5.0, 5.0],
                        "z": [0.0, 10.0],
                        "tip": [-2.0, 2.0],
                        "tilt": [-2.0, 2.0],
                        "rotation": [-180.0, 180.0],
                    }
                },
            ),
        ],
        geometry=GeometryConfig(
            sensor_pixel_pitch_um=13.0,
            sensor_shape_px=(256, 320),
            diffuser_sensor_distance_mm=8.9,
            aperture_mm=(2.67, 2.11),
            diffuser_kind="smooth",
            wavelength_nm=532.0,
        ),
        calibration=CalibrationDefaults(),
    )


def simulated_twin(
    device: DeviceConfig, geometry: GeometryConfig | None = None
) -> tuple[DeviceConfig, list[str]]:
    """The simulated twin of one device, and the names of the parameters it dropped.

    The twin keeps the id and kind and takes the driver :data:`SIMULATED_DRIVERS`
    names for the kind. Parameters are translated where they mean the same thing:

    * names in :data:`TWIN_PARAM_ALIASES` are renamed (``bit_depth`` -> ``adc_bits``,
      an SLM's ``shape_px`` -> ``resolution``, ...);
    * a camera without ``sensor_shape``/``pixel_pitch_um`` takes them from the
      geometry, an SLM without ``wavelength_nm`` the geometry's wavelength;
    * a stage whose ``axes`` is an array of names gets travel ranges from
      ``limits_mm``/``limits_deg`` (``{axis = [low, high]}``) or defaults;
    * any other parameter is kept if the twin's constructor takes it by that name,
      otherwise dropped (ports, serial numbers, ...). If the twin cannot be imported,
      only the translated parameters are kept.
    """
    from instrument.registry import RegistryError, accepted_params, resolve

    kind = device.kind
    driver = SIMULATED_DRIVERS[kind]
    rest = dict(device.params)
    out: dict[str, Any] = {}
    for name, sources in TWIN_PARAM_ALIASES[kind].items():
        found = [src for src in sources if src in rest]
        if found:
            out[name] = rest[found[0]]
            for src in found:
                rest.pop(src)
    if kind == "camera" and geometry is not None:
        out.setdefault("sensor_shape", list(geometry.sensor_shape_px))
        out.setdefault("pixel_pitch_um", rest.pop("pixel_pitch_um", geometry.sensor_pixel_pitch_um))
    if kind == "slm" and geometry is not None:
        out.setdefault("wavelength_nm", rest.pop("wavelength_nm", geometry.wavelength_nm))
    if kind == "stage" and isinstance(rest.get("axes"), list):
        limits = {**_as_dict(rest.pop("limits_mm", {})), **_as_dict(rest.pop("limits_deg", {}))}
        out["axes"] = {
            a: list(limits.get(a, _DEFAULT_TRAVEL.get(a, (-1.0, 1.0)))) for a in rest.pop("axes")
        }
    try:
        accepted = accepted_params(resolve(driver, kind))
    except RegistryError:
        accepted = set()
    dropped = []
    for key, value in rest.items():
        if accepted is None or key in accepted:
            out.setdefault(key, value)
        else:
            dropped.append(key)
    twin = device.model_copy(update={"driver": driver, "params": out})
    return twin, dropped


def _as_dict(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}


def with_simulated_drivers(config: BenchConfig) -> BenchConfig:
    """The same bench with every device driven by its simulated twin.

    Ids, kinds, geometry and calibration are kept; parameters are translated as in
    :func:`simulated_twin` (shapes, pitches, stage travel kept; ports, serial numbers
    and other hardware addresses dropped).
    """
    devices = [simulated_twin(d, config.geometry)[0] for d in config.devices]
    return config.model_copy(update={"devices": devices})


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


def _toml_value(v: Any) -> str:
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
        return "[" + ", ".join(_toml_value(x) for x in v if x is not None) + "]"
    if isinstance(v, dict):
        items = [f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items() if x is not None]
        return "{" + ", ".join(items) + "}" if items else "{}"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _toml_table(model: _Section, data: dict[str, Any], *, comments: bool) -> list[str]:
    lines = []
    for key, value in data.items():
        if value is None:
            continue
        field = type(model).model_fields.get(key)
        if comments and field is not None and field.description:
            lines.append(f"# {field.description}")
        lines.append(f"{_toml_key(key)} = {_toml_value(value)}")
    return lines


def to_toml(config: BenchConfig, *, comments: bool = True) -> str:
    """The bench as TOML text that :func:`parse_bench` reads back to an equal config.

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
            out += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in params.items()]
    return "\n".join(out) + "\n"
