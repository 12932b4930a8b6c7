"""The pydantic models of a bench file: geometry, calibration defaults, devices, bench.

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

import difflib
import math
import re
from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from .base import (
    ID_RE,
    KINDS,
    STAGE_AXES,
    Ordered,
    Range,
    Section,
    dotted,
    short_repr,
    unit_fix,
    unit_of,
    unit_word,
)
from .rules import camera_geometry_problems, metres_problem, param_value_problems

# ------------------------------------------------------------------------- models


def _rules_error(problems: list[tuple[tuple, str, str]]) -> PydanticCustomError:
    """The validation error carrying bench-rule problems (location, message, fix)."""
    return PydanticCustomError(
        "bench_rules",
        "{summary}",
        {"summary": "; ".join(f"{dotted(p[0])}: {p[1]}" for p in problems),
         "problems": problems},
    )


class GeometryConfig(Section):
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
    sensor_falloff_sigma_deg: Annotated[float, Range(0, 90)] | None = Field(
        None, description="Gaussian sigma of the pixels' angular response, degrees (Eq. 5.1; "
        "what angular-response measures); the virtual twin's sensor (unset: 20 deg)"
    )
    background_light_photons_per_s: Annotated[float, Range(0, 1e18, False)] = Field(
        0.0, description="smooth background light while a source or scene is lit (excitation "
        "leak, filter autofluorescence), photons per second on the whole sensor; the "
        "virtual twin adds it (Eq. 6.1's g)"
    )

    @model_validator(mode="after")
    def _lengths_in_mm(self) -> GeometryConfig:
        problems = [p for p in (
            metres_problem(("diffuser_sensor_distance_mm",), "diffuser_sensor_distance_mm",
                           self.diffuser_sensor_distance_mm),
            metres_problem(("aperture_mm",), "aperture_mm", list(self.aperture_mm)),
        ) if p is not None]
        if problems:
            raise _rules_error(problems)
        return self


class CalibrationDefaults(Section):
    """Defaults of the calibration plans (each plan may override them)."""

    z_range_mm: Annotated[tuple[float, float], Range(0, 10000), Ordered(strict=True)] = Field(
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
    exposure_bounds_s: Annotated[tuple[float, float], Range(0, 3600), Ordered(strict=False)] = (
        Field(
            (1e-5, 1.0), description="auto-exposure limits, (min, max) seconds"
        )
    )
    settle_s: Annotated[float, Range(0, 600, False)] = Field(
        0.2, description="wait after each stage move before the next frame, seconds"
    )


class DeviceConfig(Section):
    """One device: id, kind, driver (registry name) and driver parameters."""

    id: str = Field(description="unique device id: a-z, 0-9, _ and -")
    kind: Literal["camera", "stage", "led_array", "slm", "dmd"] = Field(
        description="device kind")
    driver: str = Field(description="driver name in the registry (diffuserlab.drivers)")
    params: dict[str, Any] = Field(
        default_factory=dict, validate_default=True, description="driver parameters"
    )

    @field_validator("id", mode="after")
    @classmethod
    def _id_ok(cls, value: str) -> str:
        if not ID_RE.match(value):
            suggestion = re.sub(r"[^a-z0-9_-]+", "_", value.lower()).strip("_")[:64] or "camera"
            raise PydanticCustomError(
                "device_id",
                "invalid device id {got}: use 1-64 characters from a-z, 0-9, '_' and '-'",
                {"got": short_repr(value), "fix": f'write id = "{suggestion}"'},
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
    def _params_ok(cls, value: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        """Unit-suffixed parameters are numbers; a stage's axes are valid (checked here,
        not after the whole model, so they are reported with the device's other
        problems: a model validator would not run while any field is invalid)."""
        problems = _param_unit_problems(value, ())
        if info.data.get("kind") == "stage":
            problems += _axes_problems(value.get("axes"))
        problems += param_value_problems(value, info.data.get("kind"))
        if problems:
            raise _rules_error(problems)
        return value


def _param_unit_problems(params: dict[str, Any], loc: tuple) -> list[tuple[tuple, str, str]]:
    """Strings given for unit-suffixed parameters (at any depth of nested tables)."""
    problems = []
    for key, v in params.items():
        if isinstance(v, dict):
            problems += _param_unit_problems(v, (*loc, key))
            continue
        unit = unit_of(key)
        items = v if isinstance(v, list) else [v]
        if unit and any(isinstance(x, str) for x in items):
            bad = next(x for x in items if isinstance(x, str))
            problems.append(
                (
                    (*loc, key),
                    f"expected {unit_word(unit)} as a number, got {short_repr(bad)}",
                    unit_fix(key, unit, bad),
                )
            )
    return problems


def _axes_problems(axes: Any) -> list[tuple[tuple, str, str]]:
    """Problems of a stage's ``params.axes``: a table ``{name = [low, high]}`` of travel
    ranges (mm for x, y, z; degrees for tip, tilt, rotation) or an array of names."""
    valid = ", ".join(STAGE_AXES)
    example = "axes = { x = [-25, 25], y = [-25, 25], z = [0, 50] }"
    loc = ("axes",)
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
                "expected a table of axis travel ranges or an array of axis names, got "
                + short_repr(axes),
                f'write {example} (or axes = ["x", "y", "z"])',
            )
        ]
    out = []
    bad = [a for a in names if a not in STAGE_AXES]
    if bad:
        close = {a: difflib.get_close_matches(a, STAGE_AXES, 1) for a in bad}
        hint = ", ".join(f"{a!r} -> {c[0]!r}" for a, c in close.items() if c)
        out.append(
            (
                loc,
                f"unknown stage axis name(s) {bad}",
                f"use names from {valid}" + (f" ({hint})" if hint else ""),
            )
        )
    dup = sorted({a for a in names if names.count(a) > 1})
    if dup:
        out.append((loc, f"duplicate stage axis name(s) {dup}", "list each axis once"))
    if isinstance(axes, dict):  # the travel of each known axis (unknown ones reported above)
        for name, travel in axes.items():
            if name not in STAGE_AXES:
                continue
            unit = "mm" if name in ("x", "y", "z") else "deg"
            items = travel if isinstance(travel, list) else [travel]
            text = next((t for t in items if isinstance(t, str)), None)
            if text is not None:
                out.append(
                    (
                        (*loc, name),
                        f"expected {unit_word(unit)} as a number, got {short_repr(text)}",
                        f"travel of {name} is [low, high] in {unit_word(unit)}: "
                        + unit_fix(name + "_" + unit, unit, text).replace(f"{name}_{unit} = ", ""),
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
                        f"got {short_repr(travel)}",
                        f"write {name} = [low, high] in {unit_word(unit)}, e.g. "
                        f"{name} = {list(DEFAULT_TRAVEL[name])}",
                    )
                )
    return out


#: Travel given to a simulated twin's axis when the bench file lists only names.
DEFAULT_TRAVEL: dict[str, tuple[float, float]] = {
    "x": (-25.0, 25.0),
    "y": (-25.0, 25.0),
    "z": (0.0, 50.0),
    "tip": (-5.0, 5.0),
    "tilt": (-5.0, 5.0),
    "rotation": (-180.0, 180.0),
}


def bench_rule_problems(devices: list[Any], branches: Any, geometry: Any = None
                        ) -> list[tuple[tuple, str, str]]:
    """Cross-device rules (unique ids, one camera, an SLM; the camera's sensor as the
    geometry describes it, :func:`instrument.config.rules.camera_geometry_problems`) on
    possibly malformed raw data.

    Returns ``(location, message, fix)`` triples, the location relative to the bench.
    """
    out: list[tuple[tuple, str, str]] = []
    if not isinstance(devices, list):
        return out
    out += camera_geometry_problems(devices, geometry)
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
    # "found none" only if every kind is known: a misspelt kind is reported on its own
    all_known = len(entries) == len(devices) and all(
        isinstance(kind, str) and kind in KINDS for _, _, kind in entries
    )
    if "lensless" in branch_list:
        if not cameras and all_known:
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
    if "holography" in branch_list and all_known and not any(k == "slm" for _, _, k in entries):
        out.append(
            (
                ("devices",),
                "a holography bench needs at least one SLM, found none",
                'add a [[devices]] table with kind = "slm" (e.g. driver = "simulated-slm"), '
                'or remove "holography" from branches',
            )
        )
    return out


class BenchConfig(Section):
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
            [{"id": d.id, "kind": d.kind, "params": d.params} for d in self.devices],
            list(self.branches), self.geometry.model_dump(mode="json"),
        )
        if problems:
            raise _rules_error(problems)
        return self

    def device(self, device_id: str) -> DeviceConfig:
        """The device with this id (KeyError naming the ids if absent)."""
        for d in self.devices:
            if d.id == device_id:
                return d
        raise KeyError(f"no device {device_id!r}; ids: {[d.id for d in self.devices]}")
