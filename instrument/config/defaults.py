"""The built-in simulated bench.

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

from .models import BenchConfig, CalibrationDefaults, DeviceConfig, GeometryConfig

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
