"""The built-in simulated bench and simulated twins of devices.

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

from typing import Any

from .base import SIMULATED_DRIVERS, TWIN_PARAM_ALIASES
from .models import _DEFAULT_TRAVEL, BenchConfig, CalibrationDefaults, DeviceConfig, GeometryConfig

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
                        "z": [-5.0, 5.0],
                        "tip": [-5.0, 5.0],
                        "tilt": [-5.0, 5.0],
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
