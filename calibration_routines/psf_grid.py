"""Lateral PSF grid for spatially varying models (Sec. 5.2-5.3).

PSFs of a point source at several lateral positions of one depth, from either

* ``mode="stage"``: the pinhole on the source stage moved over a raster at depth
  ``z_mm`` (backlit by the LED array), or
* ``mode="leds"``: single LEDs of the array at their known positions, the pinhole
  removed (the LED plane's depth is the array's ``distance_mm``).

Per position: light, auto-expose, ``frames_per_point`` frames, lights off, as many
darks. Products (:meth:`PsfGridPlan.reduce`):

* ``psf_grid``: dark-subtracted PSFs per second of exposure, background removed
  (Sec. 6.4), with the positions;
* the registered shifts: the translation of each PSF that maximises its
  cross-correlation with the PSF nearest the axis (Sec. 5.2; chained outwards
  through neighbours, :func:`recon.spatial.register_psfs`), in sensor pixels
  ``(dy, dx)``, and the magnification fitted to them (a lateral source shift
  ``dx`` moves the caustics by ``-m dx`` on the sensor, ``m = d/z``, Eq. 3.1);
* ``psf_grid_registered``: each PSF shifted back by its registered shift
  (Eq. 5.2 at a single depth, ``s_i = 1``), ready for interpolation (Eq. 5.3);
* the Nyquist check of Sec. 5.3: the grid spacing against
  :func:`recon.analysis.lateral_calibration_spacing_mm` for the measured sensor
  fall-off ``falloff_sigma_deg`` (from an angular-response run).
"""

from __future__ import annotations

import math

import numpy as np

from instrument.acquisition.plan import (
    Light,
    Move,
    Plan,
    PlanError,
    PlanPoint,
    Prompt,
    register_plan,
)
from recon.analysis import lateral_calibration_spacing_mm, remove_background_dct
from recon.spatial import register_psfs

from ._common import backlight_leds, lit_capture_steps, sensor_geometry, signal_minus_dark

__all__ = ["PsfGridPlan"]


def _check_grid_numbers(*, n, spacing_mm, z_mm, led_step, falloff_sigma_deg) -> None:
    """PlanError naming the option of a grid number that makes no sense (before any
    run is created)."""
    def whole(v, low):
        return not isinstance(v, bool) and isinstance(v, int | np.integer) and v >= low

    def positive(v):
        return isinstance(v, int | float) and math.isfinite(v) and v > 0

    if not whole(n, 2):
        raise PlanError(f"n={n!r} (--n): a grid needs a whole number >= 2 of positions a side")
    if not whole(led_step, 1):
        raise PlanError(f"led_step={led_step!r} (--led-step): use every k-th LED, k >= 1")
    for name, value in (("spacing_mm", spacing_mm), ("falloff_sigma_deg", falloff_sigma_deg)):
        if value is not None and not positive(value):
            raise PlanError(f"{name}={value!r} (--{name.replace('_', '-')}): give a "
                            "number > 0")
    if not positive(z_mm):
        raise PlanError(f"z_mm={z_mm!r} (--z-mm): the pinhole depth must be > 0 mm")


def _check_on_sensor(xy: np.ndarray, z_mm: float, d_mm: float, pitch_mm: float,
                     sensor: tuple[int, int], step_mm: float) -> None:
    """PlanError when the outermost grid position moves the PSF's centre off the
    sensor: a pinhole at lateral x shifts the caustic by ``x d / z`` (Sec. 5.2; the
    magnification m = d/z), and a PSF off the sensor leaves nothing to register."""
    half_mm = np.array([sensor[1], sensor[0]]) * pitch_mm / 2  # (x, y) half widths
    reach = np.abs(xy).max(axis=0) * d_mm / z_mm
    if np.any(reach > half_mm):
        k = int(np.argmax(reach / half_mm))
        limit = step_mm * half_mm[k] / reach[k]
        raise PlanError(
            f"at z = {z_mm:g} mm the outer grid positions shift the PSF by "
            f"{reach[k]:.2f} mm along {'xy'[k]}, beyond the sensor's half width "
            f"{half_mm[k]:.2f} mm: those PSFs would leave the sensor; use a spacing of at "
            f"most {limit:.3g} mm (--spacing-mm), fewer points or a larger z")


@register_plan
class PsfGridPlan(Plan):
    """The lateral PSF grid (module docstring).

    Parameters
    ----------
    mode : {"stage", "leds"}
    positions_mm : list of (x, y)
        Lateral source positions, mm (filled in by :meth:`for_bench`).
    z_mm : float
        Depth of the grid, mm from the diffuser (the LED plane's in ``leds`` mode).
    led_indices : list of int, optional
        ``leds`` mode: the LED of each position.
    led_positions_mm : list of (x, y), optional
        ``stage`` mode: LED positions, to choose the backlight.
    backlight_radius_mm : float
    frames_per_point : int
    d_mm, pitch_mm : float
        Geometry (diffuser-sensor distance, sensor pixel pitch), mm.
    falloff_sigma_deg : float, optional
        Measured sensor fall-off sigma for the Nyquist check (None: not checked).
    dct_n_low : int
        Background removal (Sec. 6.4).
    """

    name = "psf-grid"

    def __init__(self, *, mode: str, positions_mm, z_mm: float, d_mm: float, pitch_mm: float,
                 led_indices=None, led_positions_mm=None, backlight_radius_mm: float = 32.0,
                 frames_per_point: int = 4, falloff_sigma_deg: float | None = None,
                 dct_n_low: int = 5) -> None:
        pos = np.asarray(positions_mm, float).reshape(-1, 2)
        if mode not in ("stage", "leds"):
            raise PlanError(f"mode {mode!r}: use 'stage' (pinhole raster) or 'leds'")
        if len(pos) < 2:
            raise PlanError("a PSF grid needs at least two positions")
        if mode == "leds" and (led_indices is None or len(led_indices) != len(pos)):
            raise PlanError("leds mode needs one LED index per position")
        if mode == "stage" and led_positions_mm is None:
            raise PlanError("stage mode needs the LED positions for the backlight")
        if frames_per_point < 1:
            raise PlanError(f"frames_per_point={frames_per_point}: need at least 1")
        super().__init__(mode=mode, positions_mm=pos.tolist(), z_mm=float(z_mm),
                         d_mm=float(d_mm), pitch_mm=float(pitch_mm),
                         led_indices=None if led_indices is None else [int(i) for i in
                                                                       led_indices],
                         led_positions_mm=None if led_positions_mm is None
                         else np.asarray(led_positions_mm, float).tolist(),
                         backlight_radius_mm=backlight_radius_mm,
                         frames_per_point=frames_per_point,
                         falloff_sigma_deg=falloff_sigma_deg, dct_n_low=dct_n_low)

    @classmethod
    def for_bench(cls, bench, *, mode: str = "leds", n: int = 3, spacing_mm: float | None = None,
                  z_mm: float = 40.0, led_step: int = 2, **params) -> PsfGridPlan:
        """An ``n x n`` grid centred on the axis.

        ``stage`` mode: raster of ``spacing_mm`` (default 2 mm) at depth ``z_mm``.
        ``leds`` mode: every ``led_step``-th LED around the one nearest the axis,
        at the array's depth.

        Raises
        ------
        PlanError
            The grid leaves the stage travel or the LED array.
        """
        _check_grid_numbers(n=n, spacing_mm=spacing_mm, z_mm=z_mm, led_step=led_step,
                            falloff_sigma_deg=params.get("falloff_sigma_deg"))
        d_mm, pitch_mm, sensor = sensor_geometry(bench.config)
        params.setdefault("frames_per_point", bench.config.calibration.frames_per_point)
        offsets = np.arange(n) - (n - 1) / 2
        if mode == "stage":
            step = 2.0 if spacing_mm is None else float(spacing_mm)
            xy = np.array([(x * step, y * step) for y in offsets for x in offsets])
            travel = bench.source_stage.travel
            for k, axis in enumerate("xy"):
                lo, hi = travel[axis]
                if xy[:, k].min() < lo or xy[:, k].max() > hi:
                    raise PlanError(f"the grid spans {axis} {xy[:, k].min():g}..."
                                    f"{xy[:, k].max():g} mm, outside the stage travel "
                                    f"{lo:g}..{hi:g} mm; use fewer points or a smaller spacing")
            _check_on_sensor(xy, z_mm, d_mm, pitch_mm, sensor, step)
            return cls(mode="stage", positions_mm=xy, z_mm=z_mm, d_mm=d_mm, pitch_mm=pitch_mm,
                       led_positions_mm=bench.led_array.positions_mm, **params)
        leds = bench.led_array
        pos = np.asarray(leds.positions_mm)
        pitch = float(leds.pitch_mm)
        centre = pos[np.argmin(np.hypot(pos[:, 0], pos[:, 1]))]
        indices, xy = [], []
        for oy in offsets:
            for ox in offsets:
                want = centre + np.array([ox, oy]) * led_step * pitch
                k = int(np.argmin(np.hypot(*(pos - want).T)))
                if np.hypot(*(pos[k] - want)) > 0.25 * pitch:
                    raise PlanError(f"no LED at ({want[0]:g}, {want[1]:g}) mm; use fewer "
                                    "points or a smaller led_step")
                indices.append(k)
                xy.append(pos[k])
        return cls(mode="leds", positions_mm=np.array(xy), z_mm=float(leds.distance_mm),
                   d_mm=d_mm, pitch_mm=pitch_mm, led_indices=indices, **params)

    # ------------------------------------------------------------------ plan
    def points(self) -> list[PlanPoint]:
        n = self.params["frames_per_point"]
        leds = self.params["led_indices"] or [-1] * len(self.params["positions_mm"])
        return [PlanPoint({"x_mm": x, "y_mm": y, "z_mm": self.params["z_mm"], "led": led},
                          ("psf",) * n + ("dark",) * n)
                for (x, y), led in zip(self.params["positions_mm"], leds, strict=True)]

    def setup(self):
        if self.params["mode"] == "leds":
            yield Light(())
            yield Prompt("remove_pinhole", "Remove the pinhole: the camera must see single "
                         "LEDs of the array through the diffuser")

    def teardown(self):
        if self.params["mode"] == "leds":
            yield Prompt("install_pinhole", "Put the pinhole back in front of the LED array")

    def steps(self, index, point):
        p, c = self.params, point.coords
        n = p["frames_per_point"]
        if p["mode"] == "stage":
            yield Move("source_stage", {"x": c["x_mm"], "y": c["y_mm"], "z": c["z_mm"]})
            leds = backlight_leds(np.asarray(p["led_positions_mm"]), (c["x_mm"], c["y_mm"]),
                                  p["backlight_radius_mm"])
            if not leds:
                raise PlanError(f"no LED within {p['backlight_radius_mm']} mm of the pinhole "
                                f"at ({c['x_mm']}, {c['y_mm']}) mm")
            yield from lit_capture_steps(n, leds)
        else:
            yield from lit_capture_steps(n, [c["led"]])

    # ------------------------------------------------------------------ products
    def grid_spacing_mm(self) -> float:
        """Smallest distance between two grid positions, mm."""
        pos = np.asarray(self.params["positions_mm"])
        dist = np.hypot(*(pos[:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
        return float(dist[dist > 0].min())

    def nyquist_check(self) -> dict:
        """Sec. 5.3: the grid spacing against the spacing the fall-off needs."""
        sigma = self.params["falloff_sigma_deg"]
        spacing = self.grid_spacing_mm()
        if sigma is None:
            return {"checked": False, "grid_spacing_mm": spacing,
                    "reason": "no measured fall-off: run angular-response and pass its sigma"}
        need = lateral_calibration_spacing_mm(sigma, self.params["z_mm"])
        return {"checked": True, "grid_spacing_mm": spacing, "nyquist_spacing_mm": need,
                "falloff_sigma_deg": sigma, "ok": spacing <= need * (1 + 1e-9)}

    def reduce(self, store) -> dict:
        """Write ``psf_grid`` and ``psf_grid_registered``; return shifts, fitted
        magnification and the Nyquist check."""
        p = self.params
        psfs = np.stack([signal_minus_dark(store, i)[0] for i in range(store.n_points)])
        psfs = remove_background_dct(psfs, p["dct_n_low"])
        pos = np.asarray(p["positions_mm"])
        # (dy, dx) px, registered outwards from the PSF nearest the axis (Sec. 5.2)
        registered, shifts, ref = register_psfs(psfs, positions=pos)
        delta = pos - pos[ref]  # (dx, dy) mm
        moved_mm = shifts[:, ::-1] * p["pitch_mm"]  # (dx, dy) on the sensor, mm
        m_fit = float(-np.sum(moved_mm * delta) / np.sum(delta * delta))
        residual_px = float(np.sqrt(np.mean((moved_mm + m_fit * delta) ** 2)) / p["pitch_mm"])
        nyquist = self.nyquist_check()
        attrs = {"positions_mm": pos.tolist(), "z_mm": p["z_mm"], "units": "DN/s",
                 "shifts_px": shifts.tolist(), "reference_index": ref}
        store.write_product("psf_grid", psfs.astype(np.float32), **attrs)
        store.write_product("psf_grid_registered", registered.astype(np.float32), **attrs)
        return {"positions_mm": pos.tolist(), "z_mm": p["z_mm"], "shifts_px": shifts.tolist(),
                "magnification_fit": m_fit, "magnification_expected": p["d_mm"] / p["z_mm"],
                "shift_residual_px": residual_px, "nyquist": nyquist}
