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

from .base import BRANCHES, KINDS, SIMULATED_DRIVERS, STAGE_AXES, TWIN_PARAM_ALIASES
from .defaults import default_bench, simulated_twin, with_simulated_drivers
from .loading import load_bench, parse_bench
from .models import BenchConfig, CalibrationDefaults, DeviceConfig, GeometryConfig
from .problems import BenchConfigError, Problem
from .writer import to_toml

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
