"""Axial PSF sweep (Sec. 4.3): a point source moved along z, one PSF per depth.

Per depth: move the pinhole (source stage) to ``(x, y, z)``, backlight it with the
LED array, auto-expose (peak in 40-80 % of full scale, never saturated; the
exposure is recorded), capture ``frames_per_point`` frames, LEDs off, capture as
many dark frames at the same exposure. The products (:meth:`PsfSweepPlan.reduce`):

* ``psf_stack_raw``: mean PSF minus mean dark, per second of exposure (DN/s), so
  depths are comparable;
* ``psf_stack``: the same with the background removed by zeroing the lowest
  ``dct_n_low x dct_n_low`` DCT coefficients and clipping negatives (Sec. 6.4);
  attributes ``depths_mm`` (ascending), exposures, peak fractions, and whether each
  PSF fits on the sensor;
* the minimum z at which the PSF still fits on the sensor (App. A.2): the nearest
  calibrated depth from which on every PSF keeps less than ``1e-3`` of its energy
  (pixels above 5 % of its peak) within 2 pixels of the sensor edge.

Depths: uniform in z, or constant spacing in 1/z (Eq. 4.7, Eq. 5.10) with the
constant given or derived from the depth sensitivity of a measured PSF
(:func:`probe_inverse_depth_step`).
"""

from __future__ import annotations

import math

import numpy as np

from instrument.acquisition.exposure import autoexpose, average_frames
from instrument.acquisition.plan import Move, Plan, PlanError, PlanPoint, register_plan
from recon.analysis import (
    border_energy_fraction,
    inverse_depth_step_per_mm,
    inverse_depths,
    remove_background_dct,
    uniform_depths,
)

from ._common import backlight_leds, lit_capture_steps, sensor_geometry, signal_minus_dark

__all__ = ["PsfSweepPlan", "probe_inverse_depth_step", "sweep_depths"]

#: A PSF "fits" when less than this fraction of its energy is near the sensor edge,
#: counting only pixels above SUPPORT_LEVEL of its peak (caustics, not noise or
#: background-removal residue).
FIT_BORDER_FRACTION = 1e-3
FIT_BORDER_PX = 2
SUPPORT_LEVEL = 0.05


def _support(psf: np.ndarray) -> np.ndarray:
    """``psf`` with everything below SUPPORT_LEVEL of its 99.99th percentile zeroed."""
    level = SUPPORT_LEVEL * float(np.percentile(psf, 99.99))
    return np.where(psf >= level, psf, 0.0)


def sweep_depths(z_min_mm: float, z_max_mm: float, *, spacing: str = "inverse",
                 n_depths: int | None = None, c_per_mm: float | None = None) -> np.ndarray:
    """Depths of a sweep, mm ascending: ``spacing`` "uniform" (needs ``n_depths``) or
    "inverse" (constant in 1/z, Eq. 4.7; ``n_depths`` or the step ``c_per_mm``).

    Raises
    ------
    PlanError
        Bad range, unknown spacing, or the wrong combination of n and c.
    """
    if not (0 < z_min_mm < z_max_mm) or not math.isfinite(z_max_mm):
        raise PlanError(f"z range ({z_min_mm}, {z_max_mm}) mm: need 0 < z_min < z_max")
    if n_depths is not None and (isinstance(n_depths, bool) or n_depths != int(n_depths)
                                 or n_depths < 2):
        raise PlanError(f"n_depths={n_depths!r} (--n-depths): a sweep needs a whole number "
                        ">= 2 of depths")
    if c_per_mm is not None and not (math.isfinite(c_per_mm) and c_per_mm > 0):
        raise PlanError(f"c_per_mm={c_per_mm!r} (--c-per-mm): give a step in 1/z > 0 per mm")
    if spacing == "uniform":
        if n_depths is None or c_per_mm is not None:
            raise PlanError("uniform spacing takes n_depths (not c_per_mm)")
        return uniform_depths(z_min_mm, z_max_mm, int(n_depths))
    if spacing == "inverse":
        if (n_depths is None) == (c_per_mm is None):
            raise PlanError("inverse spacing takes exactly one of n_depths or c_per_mm")
        return inverse_depths(z_min_mm, z_max_mm, n=n_depths, c_per_mm=c_per_mm)
    raise PlanError(f"spacing {spacing!r}: use 'uniform' or 'inverse'")


@register_plan
class PsfSweepPlan(Plan):
    """The axial PSF sweep (module docstring).

    Parameters
    ----------
    z_min_mm, z_max_mm : float
        Depth range, mm from the diffuser.
    spacing : {"inverse", "uniform"}
    n_depths : int, optional
    c_per_mm : float, optional
        Step in 1/z (1/mm) for inverse spacing.
    frames_per_point : int
        Frames averaged per depth (and as many darks).
    x_mm, y_mm : float
        Lateral position of the source.
    backlight_radius_mm : float
        LEDs within this radius of the pinhole are lit (a uniform backlight).
    led_positions_mm : list of (x, y), optional
        The LED array's positions; needed to choose the backlight (filled in by
        :meth:`for_bench`).
    dct_n_low : int
        Background removal: lowest DCT coefficients zeroed per axis (Sec. 6.4).
    d_mm, pitch_mm : float, optional
        Geometry, for reports (filled in by :meth:`for_bench`).
    depth_step_source : str
        Where ``c_per_mm`` came from (recorded with the run).
    """

    name = "psf-sweep"

    def __init__(self, *, z_min_mm: float, z_max_mm: float, spacing: str = "inverse",
                 n_depths: int | None = None, c_per_mm: float | None = None,
                 frames_per_point: int = 4, x_mm: float = 0.0, y_mm: float = 0.0,
                 backlight_radius_mm: float = 32.0, led_positions_mm=None,
                 dct_n_low: int = 5, d_mm: float | None = None, pitch_mm: float | None = None,
                 depth_step_source: str = "given") -> None:
        if frames_per_point < 1:
            raise PlanError(f"frames_per_point={frames_per_point}: need at least 1")
        depths = sweep_depths(z_min_mm, z_max_mm, spacing=spacing, n_depths=n_depths,
                              c_per_mm=c_per_mm)
        leds = [] if led_positions_mm is None else backlight_leds(
            np.asarray(led_positions_mm), (x_mm, y_mm), backlight_radius_mm)
        if led_positions_mm is not None and not leds:
            raise PlanError(f"no LED within {backlight_radius_mm} mm of the pinhole at "
                            f"({x_mm}, {y_mm}) mm; raise backlight_radius_mm")
        super().__init__(z_min_mm=z_min_mm, z_max_mm=z_max_mm, spacing=spacing,
                         n_depths=n_depths, c_per_mm=c_per_mm,
                         frames_per_point=frames_per_point, x_mm=x_mm, y_mm=y_mm,
                         backlight_radius_mm=backlight_radius_mm,
                         led_positions_mm=None if led_positions_mm is None
                         else np.asarray(led_positions_mm, float).tolist(),
                         dct_n_low=dct_n_low, d_mm=d_mm, pitch_mm=pitch_mm,
                         depth_step_source=depth_step_source)
        self.depths_mm = depths
        self._leds = leds or "all"

    @classmethod
    def for_bench(cls, bench, **params) -> PsfSweepPlan:
        """The plan with the bench's LED positions and geometry, and the calibration
        defaults of its config for whatever ``params`` leaves out (z range, number
        of depths, frames per point)."""
        cal = bench.config.calibration
        params.setdefault("z_min_mm", cal.z_range_mm[0])
        params.setdefault("z_max_mm", cal.z_range_mm[1])
        if params.get("c_per_mm") is None:
            params.setdefault("n_depths", cal.n_depths)
        params.setdefault("frames_per_point", cal.frames_per_point)
        d_mm, pitch_mm, _ = sensor_geometry(bench.config)
        params.setdefault("d_mm", d_mm)
        params.setdefault("pitch_mm", pitch_mm)
        if bench.has("led_array"):
            params.setdefault("led_positions_mm", bench.led_array.positions_mm)
        return cls(**params)

    def points(self) -> list[PlanPoint]:
        n = self.params["frames_per_point"]
        return [PlanPoint({"z_mm": float(z)}, ("psf",) * n + ("dark",) * n)
                for z in self.depths_mm]

    def steps(self, index, point):
        p = self.params
        yield Move("source_stage", {"x": p["x_mm"], "y": p["y_mm"], "z": point.coords["z_mm"]})
        yield from lit_capture_steps(p["frames_per_point"], self._leds)

    def reduce(self, store) -> dict:
        """Write ``psf_stack_raw``, ``psf_stack`` and return the sweep's summary."""
        raw, exposures, peaks = [], [], []
        for i in range(store.n_points):
            img, exposure, peak = signal_minus_dark(store, i)
            raw.append(img)
            exposures.append(exposure)
            peaks.append(peak)
        raw = np.stack(raw)
        clean = remove_background_dct(raw, self.params["dct_n_low"])
        fractions = [border_energy_fraction(_support(r), FIT_BORDER_PX) for r in clean]
        fits = [f < FIT_BORDER_FRACTION for f in fractions]
        depths = [float(z) for z in self.depths_mm]
        # nearest depth from which on every PSF fits (depths ascend); the true minimum
        # lies between it and the depth before it
        min_z, below = None, None
        for k in range(len(depths) - 1, -1, -1):
            if not fits[k]:
                below = depths[k]
                break
            min_z = depths[k]
        attrs = {"depths_mm": depths, "exposure_s": exposures, "peak_fraction": peaks,
                 "units": "DN/s", "fits_on_sensor": fits, "border_energy_fraction": fractions,
                 "min_z_fit_mm": min_z, "min_z_bracket_mm": [below, min_z],
                 "x_mm": self.params["x_mm"], "y_mm": self.params["y_mm"],
                 "frames_per_point": self.params["frames_per_point"]}
        store.write_product("psf_stack_raw", raw.astype(np.float32), **attrs,
                            processing="mean(psf) - mean(dark), / exposure")
        store.write_product("psf_stack", clean.astype(np.float32), **attrs,
                            processing="psf_stack_raw with the lowest "
                            f"{self.params['dct_n_low']}x{self.params['dct_n_low']} DCT "
                            "coefficients zeroed and negatives clipped (Sec. 6.4)")
        dim = [z for z, p in zip(depths, peaks, strict=True) if p < 0.4]
        return {"depths_mm": depths, "exposure_s": exposures, "min_z_fit_mm": min_z,
                "min_z_bracket_mm": [below, min_z],
                "depths_not_fitting": [z for z, f in zip(depths, fits, strict=True) if not f],
                "depths_below_40pct_full_scale": dim,
                "depth_step_source": self.params["depth_step_source"]}


def probe_inverse_depth_step(bench, z_mm: float, *, frames: int = 4, threshold: float = 0.8,
                             x_mm: float = 0.0, y_mm: float = 0.0, dct_n_low: int = 5,
                             timeout_s: float = 10.0) -> float:
    """Measure one PSF at ``z_mm`` and derive the Nyquist step in 1/z for the sweep.

    The depth sensitivity (Sec. 3.2) of the measured PSF gives the 1/z difference
    ``c`` at which two depths become distinguishable (normalised inner product
    ``threshold``, Sec. 6.4; :func:`recon.analysis.inverse_depth_step_per_mm`); the
    sweep samples at half that step (Nyquist), so the return value is ``c / 2``.
    The PSF is measured at the nearest depth of the sweep, where ``c`` is smallest in
    the paraxial model, so the step is safe for the whole range.

    Returns
    -------
    float
        Step in 1/z, 1/mm.

    Raises
    ------
    drivers.errors.DeviceError
        A device failed; the bench is left with the LEDs off.
    """
    cam, stage = bench.camera, bench.source_stage
    d_mm, _, _ = sensor_geometry(bench.config)
    leds = bench.led_array
    try:
        stage.move_to({"x": x_mm, "y": y_mm, "z": z_mm}, timeout_s=60.0)
        bench.sleep(bench.config.calibration.settle_s)
        leds.set_leds(np.arange(leds.n_leds))
        autoexpose(cam, target=0.6, tolerance=0.2,
                   bounds_s=tuple(bench.config.calibration.exposure_bounds_s),
                   timeout_s=timeout_s)
        signal, _ = average_frames(cam, frames, timeout_s)
        leds.all_off()
        dark, _ = average_frames(cam, frames, timeout_s)
    finally:
        bench.safe_state()
    psf = remove_background_dct(signal - dark, dct_n_low)
    return inverse_depth_step_per_mm(psf, d_mm, z_mm, threshold) / 2.0
