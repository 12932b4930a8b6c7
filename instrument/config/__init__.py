"""Bench configuration: a TOML file validated into pydantic models.

A bench file describes the devices (each with an id, a kind, a driver name looked up
in :mod:`instrument.devices.registry`, and driver parameters), the optical geometry and the
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
  parameters given (checked by :func:`instrument.devices.bench_setup.load_bench` unless
  ``check_drivers=False``; ``construct=True`` also constructs each device, unopened,
  to check the values).

Every problem found is reported at once in one :class:`BenchConfigError`, each with
its location (dotted path, TOML line where known) and a fix.

This package needs no driver: :func:`validate_bench_text` checks the models and the
bench rules. Loading a bench file with the driver checks (``load_bench``,
``parse_bench``) and the simulated twins (``simulated_twin``,
``with_simulated_drivers``) are in :mod:`instrument.devices.bench_setup`, above both this
package and :mod:`instrument.devices.registry`.
"""


from __future__ import annotations

from .base import BRANCHES, KINDS, SIMULATED_DRIVERS, STAGE_AXES, TWIN_PARAM_ALIASES
from .defaults import default_bench
from .loading import raise_problems, read_bench_text, validate_bench_text
from .models import DEFAULT_TRAVEL, BenchConfig, CalibrationDefaults, DeviceConfig, GeometryConfig
from .problems import BenchConfigError, Problem, within
from .writer import to_toml

__all__ = [
    "BRANCHES",
    "DEFAULT_TRAVEL",
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
    "raise_problems",
    "read_bench_text",
    "to_toml",
    "validate_bench_text",
    "within",
]
