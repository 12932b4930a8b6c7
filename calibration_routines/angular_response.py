"""Sensor angular response (Fig. 3.5, Fig. 5.3a): intensity against incidence angle.

With the diffuser and its aperture removed, the bare sensor looks at the pinhole
(source stage, role ``source_stage``) at depth ``z`` in front of the diffuser plane,
i.e. at ``D = z + d`` from the sensor (``d`` the diffuser-sensor distance). The
pinhole is moved laterally along x and along y so that the centre of the sensor
sees it at incidence angle ``theta``::

    x = D tan(theta)        (and likewise y; stage y runs along the sensor rows)

Per point: move, backlight the pinhole with every LED (``Light("all")``: the LED
coupling of the virtual bench, and of a real diffused array, does not depend on
where the pinhole sits within the array), auto-expose (the shared
``CALIBRATION_EXPOSURE`` of ``calibration_routines._common``), capture
``frames_per_point`` frames, LEDs off, as many dark frames at the same exposure.

Reduction (:meth:`AngularResponsePlan.reduce`):

1. ``I(theta)`` = mean over a central ``roi_px x roi_px`` window of
   ``(mean(signal) - mean(dark)) / exposure`` (DN/s);
2. a point source onto a plane delivers ``cos(theta) / (4 pi r^2)`` per unit area
   with ``r = D / cos(theta)``, i.e. ``cos^3(theta) / (4 pi D^2)``: the obliquity and
   inverse-square factors are divided out, ``C(theta) = I(theta) / cos^3(theta)``,
   leaving the pixel angular response ``f(theta)`` (Eq. 5.1) up to a constant;
3. both are normalised by the largest ``C`` (normal incidence);
4. per axis a Gaussian ``A exp(-theta^2 / (2 sigma^2))`` is fitted to the
   normalised ``C`` against the signed angle
   (:func:`recon.analysis.fit_gaussian_falloff`), giving ``sigma`` and the 20 %
   cutoff ``alpha_c = sigma sqrt(2 ln 5)`` (Sec. 3.3), and the cutoff read off
   the data directly;
5. the angular half field of view per axis (Eq. 3.12 / Eq. 4.6,
   :func:`recon.analysis.fov_half_angle_deg`)::

       alpha = beta + min(alpha_c, atan((sensor width + PSF width) / (2 d)))

   with ``alpha_c`` that axis's fitted cutoff; ``beta`` (the diffuser's largest
   deflection) is *not* measured by this plan (the diffuser is out) and is a
   parameter, default 0; the sensor width along the axis is ``cols * pitch`` (x)
   or ``rows * pitch`` (y) from the bench config's geometry; the PSF width
   defaults to the aperture's width along the axis, because the PSF of a distant
   source is about the footprint of the aperture on the sensor (the caustics fill
   the aperture's shadow).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from instrument.acquisition.plan import Move, Plan, PlanError, PlanPoint, Prompt, register_plan
from recon.analysis import fit_gaussian_falloff, fov_half_angle_deg
from recon.errors import ReconInputError

from ._common import lit_capture_steps, sensor_geometry, signal_minus_dark

__all__ = ["AXIS_CODES", "AngularResponsePlan", "reachable_range_mm"]

#: Axis code of the ``angular_response`` product's first column.
AXIS_CODES = {"x": 0, "y": 1}

#: Peak fraction of full scale below which a point is flagged as dim in the summary
#: (auto-exposure hit its longest exposure).
DIM_PEAK_FRACTION = 0.4


def reachable_range_mm(stage) -> dict[str, tuple[float, float]]:
    """Where a stage can be sent, per axis: ``{axis: (low, high)}``.

    The soft limits (which lie within the mechanical travel; the travel when the
    stage has no limits), narrowed by the backlash overshoot: with backlash
    ``b`` a move that ends against ``b`` first goes to ``target - b``, which must
    lie within the limits, so the safe targets are ``[low + max(b, 0),
    high + min(b, 0)]``.
    """
    travel = {a: tuple(float(v) for v in r) for a, r in stage.travel.items()}
    limits = getattr(stage, "limits", None) or travel
    backlash = getattr(stage, "backlash", None) or {}
    out = {}
    for axis, (lo, hi) in travel.items():
        llo, lhi = limits.get(axis, (lo, hi))
        lo, hi = max(lo, float(llo)), min(hi, float(lhi))
        b = float(backlash.get(axis, 0.0))
        out[axis] = (lo + max(b, 0.0), hi + min(b, 0.0))
    return out


def _nan_to_none(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


@register_plan
class AngularResponsePlan(Plan):
    """The sensor angular-response sweep (module docstring).

    Parameters
    ----------
    d_mm : float
        Diffuser-sensor distance, mm: the pinhole at depth ``z_mm`` is ``z_mm +
        d_mm`` from the sensor (filled in by :meth:`for_bench`).
    z_mm : float
        Depth of the pinhole in front of the (removed) diffuser's plane, mm.
    axes : sequence of {"x", "y"}
        Lateral axes swept, in order.
    max_angle_deg : float
        Largest incidence angle, degrees, in (0, 85); each axis is sampled at
        ``n_angles`` angles evenly spanning ``[-max_angle_deg, +max_angle_deg]``.
    n_angles : int
        Angles per axis (>= 3; odd includes normal incidence).
    frames_per_point : int
        Signal frames averaged per point (and as many darks).
    roi_px : int
        Side of the central square window averaged per frame, pixels.
    beta_deg : float
        Largest deflection angle of the diffuser, degrees, for the field of view
        (Eq. 3.12). Not measured here (the diffuser is removed); default 0.
    sensor_width_mm : mapping {"x": float, "y": float}, optional
        Full sensor width along each axis, mm (``cols * pitch``, ``rows * pitch``;
        filled in by :meth:`for_bench`). Without it no field of view is reported.
    psf_width_mm : mapping {"x": float, "y": float}, optional
        Full PSF width along each axis, mm, for the field of view; :meth:`for_bench`
        defaults it to the aperture (the PSF of a distant source is about the
        aperture's footprint).
    travel_mm : mapping {axis: (low, high)}, optional
        Where the source stage may go (see :func:`reachable_range_mm`; filled in by
        :meth:`for_bench`); every point is checked against it.

    Raises
    ------
    PlanError
        Bad parameters, or a position outside ``travel_mm`` (the message says how
        far the stage reaches and what to change).
    """

    name = "angular-response"

    def __init__(self, *, d_mm: float, z_mm: float = 10.0, axes: Sequence[str] = ("x", "y"),
                 max_angle_deg: float = 50.0, n_angles: int = 21, frames_per_point: int = 4,
                 roi_px: int = 16, beta_deg: float = 0.0,
                 sensor_width_mm: Mapping[str, float] | None = None,
                 psf_width_mm: Mapping[str, float] | None = None,
                 travel_mm: Mapping[str, Sequence[float]] | None = None) -> None:
        axes = [str(a) for a in axes]
        if not axes or any(a not in AXIS_CODES for a in axes) or len(set(axes)) != len(axes):
            raise PlanError(f"axes={axes!r}: give distinct axes from {sorted(AXIS_CODES)}")
        if not (math.isfinite(d_mm) and d_mm > 0):
            raise PlanError(f"d_mm={d_mm!r}: the diffuser-sensor distance must be > 0 mm "
                            "(build the plan with AngularResponsePlan.for_bench)")
        if not (math.isfinite(z_mm) and z_mm > 0):
            raise PlanError(f"z_mm={z_mm!r} (--z-mm): the pinhole must be in front of the "
                            "diffuser, at a depth > 0 mm")
        if not 0 < max_angle_deg < 85:
            raise PlanError(f"max_angle_deg={max_angle_deg!r}: use an angle in (0, 85) deg")
        if int(n_angles) != n_angles or n_angles < 3:
            raise PlanError(f"n_angles={n_angles!r}: the Gaussian fit needs at least 3 angles")
        if int(frames_per_point) != frames_per_point or frames_per_point < 1:
            raise PlanError(f"frames_per_point={frames_per_point!r}: need at least 1")
        if int(roi_px) != roi_px or roi_px < 1:
            raise PlanError(f"roi_px={roi_px!r}: need a window of at least 1 pixel")
        if not 0 <= beta_deg < 90:
            raise PlanError(f"beta_deg={beta_deg!r}: use a deflection in [0, 90) deg")
        for label, widths in (("sensor_width_mm", sensor_width_mm),
                              ("psf_width_mm", psf_width_mm)):
            if widths is not None and any(a not in widths for a in axes):
                raise PlanError(f"{label}={dict(widths)!r}: give a width for each of {axes}")
        super().__init__(
            d_mm=float(d_mm), z_mm=float(z_mm), axes=axes, max_angle_deg=float(max_angle_deg),
            n_angles=int(n_angles), frames_per_point=int(frames_per_point), roi_px=int(roi_px),
            beta_deg=float(beta_deg),
            sensor_width_mm=None if sensor_width_mm is None
            else {a: float(v) for a, v in sensor_width_mm.items()},
            psf_width_mm=None if psf_width_mm is None
            else {a: float(v) for a, v in psf_width_mm.items()},
            travel_mm=None if travel_mm is None
            else {a: [float(v[0]), float(v[1])] for a, v in travel_mm.items()})
        self.angles_deg = np.linspace(-max_angle_deg, max_angle_deg, int(n_angles))
        self._points = self._make_points()
        self._check_travel()

    @property
    def distance_mm(self) -> float:
        """Distance of the pinhole from the sensor, ``z + d``, mm."""
        return self.params["z_mm"] + self.params["d_mm"]

    @classmethod
    def for_bench(cls, bench, **params) -> AngularResponsePlan:
        """The plan for an open bench: ``d_mm``, sensor and aperture widths from its
        config's geometry, ``frames_per_point`` from its calibration defaults, and
        the source stage's reachable range (:func:`reachable_range_mm`), against
        which every position is checked here.

        Raises
        ------
        PlanError
            No geometry in the config, or a position the stage cannot reach.
        """
        d_mm, pitch_mm, (rows, cols) = sensor_geometry(bench.config)
        params.setdefault("d_mm", d_mm)
        params.setdefault("frames_per_point", bench.config.calibration.frames_per_point)
        params.setdefault("sensor_width_mm", {"x": cols * pitch_mm, "y": rows * pitch_mm})
        aw, ah = bench.config.geometry.aperture_mm
        params.setdefault("psf_width_mm", {"x": float(aw), "y": float(ah)})
        params.setdefault("travel_mm", reachable_range_mm(bench.source_stage))
        return cls(**params)

    # ------------------------------------------------------------------ points
    def _make_points(self) -> list[PlanPoint]:
        p = self.params
        n = p["frames_per_point"]
        tags = ("signal",) * n + ("dark",) * n
        out = []
        for axis in p["axes"]:
            for theta in self.angles_deg:
                offset = self.distance_mm * math.tan(math.radians(float(theta)))
                xy = {"x": 0.0, "y": 0.0, axis: round(offset, 9)}
                out.append(PlanPoint({"axis": axis, "angle_deg": float(theta),
                                      "x_mm": xy["x"], "y_mm": xy["y"], "z_mm": p["z_mm"]},
                                     tags))
        return out

    def _check_travel(self) -> None:
        travel = self.params["travel_mm"]
        if travel is None:
            return
        z = self.params["z_mm"]
        if "z" in travel:
            lo, hi = travel["z"]
            if not lo <= z <= hi:
                raise PlanError(f"z_mm={z:g} is outside the source stage's z range "
                                f"[{lo:g}, {hi:g}] mm; choose z_mm within it")
        for axis in self.params["axes"]:
            if axis not in travel:
                raise PlanError(f"the source stage has no {axis} axis (axes "
                                f"{sorted(travel)}); sweep only {sorted(set(travel) & {'x', 'y'})}")
            lo, hi = travel[axis]
            need = self.distance_mm * math.tan(math.radians(self.params["max_angle_deg"]))
            if -need < lo or need > hi:
                reach = min(-lo, hi)
                best = math.degrees(math.atan(reach / self.distance_mm)) if reach > 0 else 0.0
                z_max = (reach / math.tan(math.radians(self.params["max_angle_deg"]))
                         - self.params["d_mm"])
                raise PlanError(
                    f"+/-{self.params['max_angle_deg']:g} deg along {axis} at z = {z:g} mm "
                    f"needs {axis} = +/-{need:.2f} mm but the source stage reaches "
                    f"[{lo:g}, {hi:g}] mm; lower max_angle_deg to {best:.1f} deg or less, "
                    f"or bring the pinhole closer (z_mm <= {z_max:.2f} mm)")

    def points(self) -> list[PlanPoint]:
        return list(self._points)

    def setup(self):
        yield Prompt("remove_diffuser",
                     "Remove the diffuser and its aperture: the bare sensor must see the pinhole")

    def steps(self, index, point):
        c = point.coords
        yield Move("source_stage", {"x": c["x_mm"], "y": c["y_mm"], "z": c["z_mm"]})
        yield from lit_capture_steps(self.params["frames_per_point"], "all",
                                     signal_tag="signal", dark_tag="dark")

    def teardown(self):
        yield Prompt("install_diffuser",
                     "Install the diffuser and its aperture again (as they were before the "
                     "angular-response sweep)")

    # ------------------------------------------------------------------ reduce
    def _roi(self, shape: tuple[int, int]) -> tuple[slice, slice]:
        rows, cols = shape
        k = min(self.params["roi_px"], rows, cols)
        r0, c0 = (rows - k) // 2, (cols - k) // 2
        return slice(r0, r0 + k), slice(c0, c0 + k)

    def reduce(self, store) -> dict:
        """Write the ``angular_response`` product and return the per-axis summary.

        Product ``angular_response``: float64, shape ``(n_points, 4)``, one row per
        point in plan order, columns ``axis code`` (:data:`AXIS_CODES`),
        ``angle_deg`` (signed), ``intensity_normalised`` (``I / max C``) and
        ``corrected`` (``C / max C`` with ``C = I / cos^3(theta)``); attributes:
        the raw ROI intensities (DN/s), exposures, peak fractions, the fits and the
        geometry.

        Returns
        -------
        dict
            ``{"axes": {axis: {"sigma_deg", "cutoff_deg", "cutoff_measured_deg",
            "amplitude", "rms_residual", "fov_half_angle_deg", "fov_limited_by",
            "geometric_limit_deg", "beta_deg", "sensor_width_mm", "psf_width_mm"}},
            ...}`` with the geometry, ROI and dim points.

        Raises
        ------
        PlanError
            The data cannot be fitted (no signal, no fall-off within the range).
        """
        p = self.params
        rs, cs = self._roi(store.frame_shape)
        points = self.points()
        intensity, exposures, peaks = [], [], []
        for i in range(store.n_points):
            img, exposure, peak = signal_minus_dark(store, i, "signal", "dark")
            intensity.append(float(img[rs, cs].mean()))
            exposures.append(exposure)
            peaks.append(peak)
        intensity = np.asarray(intensity)
        axis_of = [pt.coords["axis"] for pt in points]
        angles = np.array([pt.coords["angle_deg"] for pt in points], float)
        corrected = intensity / np.cos(np.radians(angles)) ** 3
        scale = float(corrected.max())
        if not scale > 0:
            raise PlanError("no point received light in the central window; check that the "
                            "LEDs light the pinhole, the camera is uncapped and the diffuser "
                            "is out")
        table = np.column_stack([[AXIS_CODES[a] for a in axis_of], angles,
                                 intensity / scale, corrected / scale]).astype(np.float64)
        per_axis = {}
        for axis in p["axes"]:
            sel = np.array([a == axis for a in axis_of])
            try:
                fit = fit_gaussian_falloff(angles[sel], corrected[sel] / scale)
            except ReconInputError as exc:
                raise PlanError(f"angular response along {axis}: {exc}") from exc
            entry = {"sigma_deg": fit.sigma_deg, "cutoff_deg": fit.cutoff_deg,
                     "cutoff_measured_deg": _nan_to_none(fit.cutoff_measured_deg),
                     "amplitude": fit.amplitude, "rms_residual": fit.rms_residual,
                     "beta_deg": p["beta_deg"], "fov_half_angle_deg": None,
                     "fov_limited_by": None, "geometric_limit_deg": None,
                     "sensor_width_mm": None, "psf_width_mm": None}
            if p["sensor_width_mm"] is not None and p["psf_width_mm"] is not None:
                sw, pw = p["sensor_width_mm"][axis], p["psf_width_mm"][axis]
                alpha_c = min(fit.cutoff_deg, 90.0)
                fov = fov_half_angle_deg(alpha_c, beta_deg=p["beta_deg"], sensor_width_mm=sw,
                                         psf_width_mm=pw, d_mm=p["d_mm"])
                geometric = math.degrees(math.atan((sw + pw) / (2.0 * p["d_mm"])))
                entry.update(fov_half_angle_deg=fov, geometric_limit_deg=geometric,
                             fov_limited_by="sensor cutoff" if alpha_c <= geometric
                             else "geometry", sensor_width_mm=sw, psf_width_mm=pw)
            per_axis[axis] = entry
        dim = [{"axis": a, "angle_deg": float(t)}
               for a, t, pk in zip(axis_of, angles, peaks, strict=True)
               if pk < DIM_PEAK_FRACTION]
        geometry = {"z_mm": p["z_mm"], "d_mm": p["d_mm"], "distance_mm": self.distance_mm,
                    "roi_px": [rs.stop - rs.start, cs.stop - cs.start],
                    "roi_origin_px": [rs.start, cs.start]}
        store.write_product(
            "angular_response", table,
            columns=["axis_code", "angle_deg", "intensity_normalised", "corrected"],
            axis_codes=AXIS_CODES, units={"angle_deg": "deg", "intensity_normalised": "1",
                                          "corrected": "1", "intensity_dn_per_s": "DN/s"},
            processing="I = ROI mean of (mean(signal) - mean(dark)) / exposure; "
                       "C = I / cos^3(theta); both divided by max(C)",
            intensity_dn_per_s=intensity.tolist(), normalisation_dn_per_s=scale,
            exposure_s=exposures, peak_fraction=peaks, fits=per_axis, **geometry)
        return {"axes": per_axis, **geometry, "beta_measured": False,
                "beta_note": "the diffuser's deflection beta is not measured by this plan "
                             "(the diffuser is removed); the field of view uses the beta_deg "
                             "parameter",
                "dim_points": dim}
