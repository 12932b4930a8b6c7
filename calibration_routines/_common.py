"""Pieces shared by the calibration plans: per-point signal minus dark, the standard
point-source acquisition steps, and geometry from the bench config."""

from __future__ import annotations

import numpy as np

from instrument.acquisition.plan import AutoExposure, Capture, Expose, Light, PlanError
from instrument.runs.runstore import RunStore

#: Auto-exposure of every calibration point: the peak between 40 % and 80 % of full
#: scale (never saturated), so PSFs are bright yet comparable via their exposure.
CALIBRATION_EXPOSURE = AutoExposure(target=0.6, tolerance=0.2, required=False)


def lit_capture_steps(n: int, leds="all", *, signal_tag: str = "psf",
                      dark_tag: str = "dark", exposure: AutoExposure = CALIBRATION_EXPOSURE):
    """Light, auto-expose, capture ``n`` signal frames, lights off, capture ``n`` darks
    at the same exposure (so the dark matches the signal's exposure exactly)."""
    yield Light(leds)
    yield Expose(auto=exposure)
    yield Capture(n, signal_tag)
    yield Light(())
    yield Capture(n, dark_tag)


def signal_minus_dark(store: RunStore, point: int, signal_tag: str = "psf",
                      dark_tag: str = "dark") -> tuple[np.ndarray, float, float]:
    """Mean signal frame minus mean dark frame of one point, per second of exposure.

    Returns
    -------
    image : ndarray, float64, (rows, cols)
        DN / s.
    exposure_s : float
    peak_fraction : float
        99.99th percentile of the dark-subtracted mean as a fraction of the camera's
        full scale (what auto-exposure aimed at).

    Raises
    ------
    PlanError
        The point's frames do not share one exposure (signal vs dark).
    """
    sig, sc = store.point_frames(point, signal_tag)
    dark, dc = store.point_frames(point, dark_tag)
    exposures = {c["exposure_s"] for c in sc} | {c["exposure_s"] for c in dc}
    if len(exposures) != 1:
        raise PlanError(f"point {point}: signal and dark frames have exposures "
                        f"{sorted(exposures)}; they must match")
    exposure = exposures.pop()
    diff = sig.astype(np.float64).mean(axis=0) - dark.astype(np.float64).mean(axis=0)
    full = float(store.attrs.get("camera", {}).get("full_scale_dn", np.iinfo(sig.dtype).max))
    peak = float(np.percentile(diff, 99.99)) / full
    return diff / exposure, float(exposure), peak


def backlight_leds(positions_mm: np.ndarray, xy_mm, radius_mm: float) -> list[int]:
    """Indices of LEDs within ``radius_mm`` of ``xy_mm`` (a backlight for the pinhole)."""
    pos = np.asarray(positions_mm, float)
    r = np.hypot(pos[:, 0] - xy_mm[0], pos[:, 1] - xy_mm[1])
    return [int(i) for i in np.flatnonzero(r <= radius_mm)]


def sensor_geometry(config) -> tuple[float, float, tuple[int, int]]:
    """``(d_mm, pitch_mm, (rows, cols))`` from a bench config's geometry.

    Raises
    ------
    PlanError
        The bench config has no geometry table.
    """
    geo = getattr(config, "geometry", None)
    if geo is None:
        raise PlanError("this calibration needs the bench's [geometry] (diffuser-sensor "
                        "distance, pixel pitch); add it to the bench TOML")
    return (float(geo.diffuser_sensor_distance_mm), float(geo.sensor_pixel_pitch_um) * 1e-3,
            tuple(geo.sensor_shape_px))
