"""SLM phase look-up table (gray level -> phase) at one wavelength, from binary gratings.

The mask is taken out of the beam (:func:`~calibration_routines.holo_bench.far_field_setup`:
holography branch, ND filter, mask retracted and put back whatever happens), so the
camera in the Fourier plane sees the SLM's own far field. Points, for ``N`` gray
levels ``g_i`` evenly spaced over 0..255 (``g_0 = 0``, ``g_{N-1} = 255``):

* ``0``: uniform gray 0: the zero order's position (brightest spot's centroid) and
  the reference energy; checked at once for saturation and for light;
* ``1 .. N-1`` (pass 1): binary gratings ``(0 | g_i)`` of period ``period_px`` along
  the SLM columns: ``phi(g_i) - phi(0)``;
* ``N``: uniform again (laser drift, and the reference for pass 2's choice);
* ``N+1 .. 2N`` (pass 2): gratings ``(g_ref | g_i)`` with ``g_ref`` the level pass 1
  puts nearest pi/2, chosen from the stored pass-1 frames when pass 2 starts (also
  on resume): where pass 1 is blind (``cos^2`` flat near 0, pi, 2 pi), pass 2 sits
  at pi/2 from its own folds, and vice versa;
* ``2N+1``: uniform (drift).

Each point: show the pattern, auto-expose (no pixel saturated; a spot smaller than
the percentile is backed off to half of full scale), ``frames_per_point`` frames.
:mod:`~calibration_routines.slm_lut_analysis` turns them into phases: zero-order
fraction ``E0 / (E0 + E_orders)`` per frame (laser power and exposure cancel), the
windows' share ``beta`` of the diffracted light fitted once, folded phases, the
pass-1 unfolding by monotonicity, both passes combined by weighted least squares,
then a monotone LUT (isotonic regression + PCHIP) over the 256 levels.

Products: ``slm_lut`` (float64 (256,), rad, ``phi(g) - phi(0)``; attributes:
wavelength, SLM id, reference level, beta, drift, geometry of the orders) and
``slm_phase_measured`` (per measured level). Load a LUT onto an SLM with
:func:`calibration_routines.slm_lut_io.apply_lut` (``apply_lut(bench.slm,
"out/runs/slm-lut.zarr")``; it checks the wavelength).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from instrument.acquisition.plan import (
    AutoExposure,
    Capture,
    Check,
    CheckFailed,
    Expose,
    Plan,
    PlanError,
    PlanPoint,
    ShowSlm,
    register_plan,
)

from . import slm_lut_analysis as ana
from .holo_bench import far_field_setup
from .slm_lut_io import reduce_run, reference_level

__all__ = ["SLM_EXPOSURE", "SlmLutPlan"]

#: Auto-exposure of every point: no saturated pixel, brightest spot backed off to
#: about half of full scale (see :class:`instrument.acquisition.plan.AutoExposure`).
SLM_EXPOSURE = AutoExposure(target=0.6, tolerance=0.2, required=False, headroom=0.5)


@register_plan
class SlmLutPlan(Plan):
    """The SLM phase-LUT calibration (module docstring).

    Parameters
    ----------
    slm_shape : (int, int)
        SLM (rows, cols) (:meth:`for_bench`: the SLM's resolution).
    wavelength_nm : float
        Laser wavelength the LUT is for, nm (:meth:`for_bench`: the SLM's).
    slm_id : str
        Device id (or role) of the SLM.
    n_levels : int
        Gray levels measured, 8..256 (default 48; 32-64 is the useful range).
    period_px : int
        Grating period in SLM pixels, even, 2..cols/4 (default 8: pixel crosstalk
        only blurs the edges, the orders stay well apart).
    frames_per_point : int
        Frames averaged per point (>= 1).
    window_px, ring_px : int
        Odd window around each order and the background ring's width, camera px.
    max_order : int
        Orders ``1 <= |m| <= max_order`` counted as diffracted light (>= 1).
    exposure_bounds_s : (float, float)
        Allowed exposures, s.
    attenuate : bool
        Ask for an ND filter in front of the camera during the run.
    retract_axis : {"x", "y"}
        Mask-stage axis the mask is retracted along.
    retract_mm : float, optional
        Retraction distance (default from the SLM footprint,
        :func:`~calibration_routines.holo_bench.retract_distance_mm`).
    mask_stage : str
        Device id (or role) of the mask stage.

    Raises
    ------
    PlanError
        A parameter out of range (the message names the fix).
    """

    name = "slm-lut"

    def __init__(self, *, slm_shape: Sequence[int], wavelength_nm: float, slm_id: str = "slm",
                 n_levels: int = 48, period_px: int = 8, frames_per_point: int = 4,
                 window_px: int = 5, ring_px: int = 3, max_order: int = 3,
                 exposure_bounds_s: Sequence[float] = (1e-5, 1.0), attenuate: bool = True,
                 retract_axis: str = "x", retract_mm: float | None = None,
                 mask_stage: str = "mask_stage") -> None:
        rows, cols = (int(v) for v in slm_shape)
        if isinstance(n_levels, bool) or int(n_levels) != n_levels or not 8 <= n_levels <= 256:
            raise PlanError(f"n_levels={n_levels!r}: measure 8 to 256 gray levels (32-64 "
                            "follow a smooth response between its folds)")
        if int(period_px) != period_px or period_px < 2 or period_px % 2 or \
                period_px > cols // 4:
            raise PlanError(f"period_px={period_px!r}: use an even grating period from 2 to "
                            f"{cols // 4} SLM pixels (a quarter of the {cols} columns)")
        if int(frames_per_point) != frames_per_point or frames_per_point < 1:
            raise PlanError(f"frames_per_point={frames_per_point!r}: need at least 1")
        if int(window_px) != window_px or window_px < 1 or window_px % 2 == 0:
            raise PlanError(f"window_px={window_px!r}: use an odd window of >= 1 camera px")
        if int(ring_px) != ring_px or ring_px < 1 or int(max_order) != max_order or max_order < 1:
            raise PlanError(f"ring_px={ring_px!r}, max_order={max_order!r}: both must be >= 1")
        lo, hi = (float(v) for v in exposure_bounds_s)
        if not 0 < lo < hi:
            raise PlanError(f"exposure_bounds_s={exposure_bounds_s!r}: give (min, max) > 0 s")
        if not (math.isfinite(wavelength_nm) and wavelength_nm > 0):
            raise PlanError(f"wavelength_nm={wavelength_nm!r}: give the laser wavelength, nm")
        if retract_mm is not None and not retract_mm > 0:
            raise PlanError(f"retract_mm={retract_mm!r}: give a distance > 0 mm or None")
        super().__init__(
            slm_shape=[rows, cols], wavelength_nm=float(wavelength_nm), slm_id=str(slm_id),
            n_levels=int(n_levels), period_px=int(period_px),
            frames_per_point=int(frames_per_point), window_px=int(window_px),
            ring_px=int(ring_px), max_order=int(max_order), exposure_bounds_s=[lo, hi],
            attenuate=bool(attenuate), retract_axis=str(retract_axis),
            retract_mm=None if retract_mm is None else float(retract_mm),
            mask_stage=str(mask_stage))
        self.levels = np.unique(np.round(np.linspace(0, 255, int(n_levels))).astype(int))
        self._exposure = dataclasses.replace(SLM_EXPOSURE, bounds_s=(lo, hi))
        self._reference: int | None = None

    @classmethod
    def for_bench(cls, bench, **params) -> SlmLutPlan:
        """The plan for an open bench: SLM shape, wavelength and id from ``bench.slm``,
        ``frames_per_point`` and ``exposure_bounds_s`` from the bench config's
        calibration defaults, unless ``params`` say otherwise.

        Raises
        ------
        PlanError
            Bad parameters; instrument.devices.bench.BenchRoleError: no SLM.
        """
        slm = bench.slm
        params.setdefault("slm_shape", list(slm.resolution))
        params.setdefault("wavelength_nm", slm.wavelength_nm)
        params.setdefault("slm_id", slm.device_id)
        if bench.config is not None:
            params.setdefault("frames_per_point", bench.config.calibration.frames_per_point)
            params.setdefault("exposure_bounds_s",
                              list(bench.config.calibration.exposure_bounds_s))
        return cls(**params)

    # ------------------------------------------------------------------ points
    @property
    def n(self) -> int:
        """Number of measured gray levels."""
        return int(self.levels.size)

    def points(self) -> list[PlanPoint]:
        f = self.params["frames_per_point"]
        uni, grat = ("uniform",) * f, ("grating",) * f
        out = [PlanPoint({"kind": "uniform", "pass": 0, "gray": 0}, uni)]
        out += [PlanPoint({"kind": "grating", "pass": 1, "gray": int(g), "reference_gray": 0},
                          grat) for g in self.levels[1:]]
        out.append(PlanPoint({"kind": "uniform", "pass": 1, "gray": 0}, uni))
        out += [PlanPoint({"kind": "grating", "pass": 2, "gray": int(g),
                           "reference_gray": "pass-1 level nearest pi/2"}, grat)
                for g in self.levels]
        out.append(PlanPoint({"kind": "uniform", "pass": 2, "gray": 0}, uni))
        return out

    def uniform_points(self) -> list[int]:
        """Indices of the uniform-pattern points."""
        return [0, self.n, 2 * self.n + 1]

    def session(self, bench):
        """The SLM's own far field for the whole run:
        :func:`~calibration_routines.holo_bench.far_field_setup` (holography branch,
        ND filter if ``attenuate``, mask retracted and put back whatever happens)."""
        p = self.params
        return far_field_setup(bench, attenuate=p["attenuate"], axis=p["retract_axis"],
                               distance_mm=p["retract_mm"], stage=p["mask_stage"])

    def steps(self, index, point):
        c = point.coords
        shape = tuple(self.params["slm_shape"])
        f = self.params["frames_per_point"]
        if c["kind"] == "uniform":
            yield ShowSlm(gray=np.zeros(shape, np.uint8), label="uniform 0",
                          device=self.params["slm_id"])
            yield Expose(auto=self._exposure)
            yield Capture(f, "uniform")
            yield Check("zero order visible, not saturated", self._check_uniform)
            return
        if c["pass"] == 2:
            yield Check("pass-2 reference level", self._resolve_reference)
        low = 0 if c["pass"] == 1 else self._reference
        yield ShowSlm(gray=ana.binary_grating(shape, self.params["period_px"], low, c["gray"]),
                      label=f"grating {low}|{c['gray']}", device=self.params["slm_id"])
        yield Expose(auto=self._exposure)
        yield Capture(f, "grating")

    def checked_steps(self, points, indices):
        """Nothing to check ahead: the steps show SLM patterns and auto-expose (and
        the pass-2 gratings depend on a level measured in pass 1, so the step
        generators cannot be walked ahead); the mask retraction of :meth:`session`
        checks its target against the stage limits itself before moving."""
        return iter(())

    def teardown(self):
        shape = tuple(self.params["slm_shape"])
        yield ShowSlm(gray=np.zeros(shape, np.uint8), label="uniform 0",
                      device=self.params["slm_id"])

    # ------------------------------------------------------------------ checks
    def _check_uniform(self, bench, store, index) -> None:
        """Raise CheckFailed (discarding the point's frames, so that a resume measures
        it again) if the uniform pattern saturates or shows no zero-order spot."""
        try:
            self._inspect_uniform(store, index)
        except CheckFailed:
            store.clear_point(index)
            raise

    def _inspect_uniform(self, store, index) -> None:
        frames, coords = store.point_frames(index, "uniform")
        exposure = coords[0]["exposure_s"]
        lo, hi = self.params["exposure_bounds_s"]
        if any(c["saturated_pixels"] > 0 for c in coords):
            if exposure <= lo * (1 + 1e-9):
                raise CheckFailed(
                    f"the SLM's zero order saturates the camera even at the shortest "
                    f"exposure {lo:g} s", "attenuate the beam: an ND filter in front of the "
                    "camera (asked for unless attenuate=False / --no-nd-filter) or a lower "
                    "laser power")
            raise CheckFailed(f"point {index}: saturated pixels at {exposure:.3g} s",
                              "check for a flickering or unstable laser, then resume")
        mean = frames.astype(np.float64).mean(axis=0)
        (x, y), snr = ana.spot_centroid(mean, self.params["window_px"])
        share = _spot_share(mean, (x, y), self.params["window_px"], self.params["ring_px"])
        if snr < 20 or share < 0.5:
            raise CheckFailed(
                f"no zero-order spot: the brightest spot ({x:.0f}, {y:.0f}) px is {snr:.0f} "
                f"noise sigmas above the background and holds {share:.0%} of the light "
                f"above the noise (exposure {exposure:.3g} s, longest allowed {hi:g} s)",
                "check that the laser is on, the camera uncapped and in the Fourier plane "
                "of the SLM, and the beam reaches the SLM")

    def _resolve_reference(self, bench, store, index) -> None:
        """Pass 2's reference level: the one the store recorded (what earlier pass-2
        points used, e.g. before a resume), else :func:`reference_level`, recorded."""
        if self._reference is None:
            stored = store.attrs.get("slm_lut_reference_gray")
            self._reference = int(stored) if stored is not None else reference_level(self, store)
            store.update_attrs(slm_lut_reference_gray=self._reference)

    # ------------------------------------------------------------------ reduce
    def reduce(self, store) -> dict:
        """Write ``slm_lut`` and ``slm_phase_measured`` (module docstring) and return
        the summary: ``wavelength_nm``, ``slm_id``, ``n_levels``, ``reference_gray``,
        ``beta`` (share of the diffracted light in the order windows), ``drift``
        (relative change of the uniform zero order over the run), ``stroke_rad``
        (LUT at gray 255), ``gray_at_2pi`` (first level reaching 2 pi, or None),
        ``passes_rms_rad`` (weighted RMS disagreement of the two passes),
        ``fit_rms_rad`` (LUT minus the combined phases at the measured levels: zero
        unless monotonicity had to be enforced) and the order geometry.

        Raises
        ------
        PlanError
            Saturated frames, orders not found, no modulation (the message names the
            fix).
        """
        return reduce_run(self, store)


def _spot_share(frame: np.ndarray, xy, window_px: int, ring_px: int) -> float:
    """Energy of the spot's window over the energy of every pixel more than 6 noise
    sigmas above the median (light elsewhere, or hot pixels in the dark)."""
    f = np.asarray(frame, np.float64)
    bg = float(np.median(f))
    noise = max(1.4826 * float(np.median(np.abs(f - bg))), 0.5)
    above = f - bg
    total = float(above[above > 6 * noise].sum())
    if not total > 0:
        return 0.0
    return float(ana.order_energies(f, xy, (0.0, 0.0), [0], window_px, ring_px)[0]) / total

