"""SLM-mask alignment with spot feedback (Kuo 2020 Sec. 7.4; docs/protocols.md).

The bench shows, on the SLM, a pattern that focuses one far-field spot through the
mask *as the model believes it is placed* (:func:`recon.optics.holo_display.spot_phase`)
and measures the spot on the camera (:class:`.SpotMeter`). A true mask offset of
``d`` mask px dims the spot as ``(1 - |d_x|/k)^2 (1 - |d_y|/k)^2``, so the capture
range is one SLM pixel; the search therefore shifts the *model* in software
(integer mask px) before the stage moves. Steps and stopping rules:

0. Pre-flight: dark level; camera <-> far-field affine from blazed-grating spots
   with the mask moved out of the beam; spot frequency ``u0`` off-axis, outside the
   mask-free SLM band, on the camera.
1. (every reading) auto-exposure, frame averaging.
2. Coarse acquisition on a central patch (~10 % of the SLM): software shifts over
   +-``coarse_range_px`` in steps of ``k/2``; a detection needs eta > 20x the scan's
   median |eta| and a second capture that repeats it; otherwise widen once, then
   fail with :class:`MaskNotFound`.
3. Global sub-pixel translation on the central patch: a separable cross of shifts
   (radius ``k + 1``), triangle fits, the stage moves by the fractional part (the
   integer part stays in the model). Stops when the residual is below 0.05 px twice
   in a row, when it is below the fit's own standard error, or after 3 rounds.
4. Rigid pose: offsets of the 3 x 5 sections (software shifts only) fitted by a
   similarity; the stage rotates by ``-theta`` and translates by the sub-pixel move
   that best serves all sections after rounding (the fractional part of the
   whole-aperture ``t`` without distortion; more precise than the central patch: the
   metric of a patch is itself random). Stops when ``|theta|`` is below ``0.05 k / half-diagonal``
   or 2 sigma and the translation residual below 0.05 px or 2 sigma, or after 5
   rounds; the scale error stays as distortion.
5. Focus and tip/tilt (stage z, tip, tilt): per-section z sweeps, parabola vertices,
   a plane through them gives z and the tilts (:mod:`.focus`); then step 3 again,
   differentially, in case z and tilt moved the image.
6. Piecewise integer correction per section (search radius 2, accepted only if eta
   improves by more than 3 sigma of repeated captures); at most 3 passes.
7. Verify: each section's eta against the simulated perfectly aligned eta (>= 0.8),
   residual sub-pixel offsets reported; the corrected mask is written; a test
   hologram computed for it is captured and compared with its simulation (PSNR,
   SSIM, correlation recorded; a correlation below 0.9 is a warning).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from instrument.acquisition.plan import PlanError
from instrument.acquisition.runner import RunAborted, RunControl
from recon.optics.holo_display import (
    CameraMapping,
    HolographicDisplayModel,
    MaskModel,
    RelayModel,
    efficiency,
)
from recon.optics.holo_display import spot_phase as _spot_phase

from .config import AlignmentConfig
from .errors import AlignmentFailed, MaskNotFound
from .fitting import best_subpixel_offset, fit_similarity, fit_triangle
from .focus import FocusStep
from .hologram_check import hologram_check
from .record import AlignmentRecord, corrected_mask, section_bounds
from .spotmeter import SpotMeter, SpotReading, blazed_phase

__all__ = ["AlignmentConfig", "AlignmentFailed", "MaskAligner", "MaskNotFound"]


class MaskAligner:
    """Align the SLM's random mask with camera feedback (see the module docstring).

    Parameters
    ----------
    bench : instrument.devices.bench.Bench
        Open bench with ``camera``, ``slm`` and ``mask_stage`` (axes x, y in mm;
        rotation, tip, tilt in deg; z in mm), the holography branch in the beam.
    mask_model : recon.optics.holo_display.MaskModel
        The software's model of the mask (its bits; its ground truth is ignored).
    config : AlignmentConfig
    record : AlignmentRecord, optional
        Where captures and results go (default: kept in memory only).
    control : instrument.acquisition.runner.RunControl, optional
        Pause / abort between readings (abort raises ``RunAborted``).
    on_event : callable, optional
        ``on_event(step: str, message: str, data: dict)`` for progress.
    retract : callable, optional
        Context-manager factory ``retract(bench)`` taking the mask out of the beam for
        the Fourier calibration (default :func:`calibration_routines.holo_bench.far_field_setup`:
        mask retracted and an ND filter in front of the camera).
    """

    def __init__(self, bench, mask_model: MaskModel, config: AlignmentConfig | None = None, *,
                 record: AlignmentRecord | None = None, control: RunControl | None = None,
                 on_event: Callable | None = None, retract: Callable | None = None):
        if not isinstance(mask_model, MaskModel):
            raise PlanError(f"mask_model must be a MaskModel, got {type(mask_model).__name__}")
        self.bench = bench
        self.mm = mask_model
        self.cfg = config or AlignmentConfig()
        self.k = mask_model.k
        self.control = control or RunControl()
        self.on_event = on_event
        self.record = record
        self._retract = retract
        self.state: dict = record.state if record is not None else {"steps": {}}
        self.meter = SpotMeter(bench, frames=self.cfg.frames, timeout_s=self.cfg.timeout_s,
                               on_reading=self._log_reading,
                               check=self.control.wait_while_paused)
        self._context: dict = {}
        self.sections = section_bounds(mask_model.slm_shape, self.cfg.sections)
        self.stage_px_total = np.zeros(2)  # stage translation applied, mask px
        self.rotation_applied = 0.0  # rad
        self.section_fits: list[dict] | None = None  # step 4's per-section fits
        wavelength_nm = getattr(bench.slm, "wavelength_nm", None)
        if wavelength_nm is None:
            raise PlanError("the SLM does not state its wavelength_nm; set it in the bench "
                            "config (the relay model and the focus sweep need it)")
        self.relay = RelayModel(wavelength_um=float(wavelength_nm) / 1000.0,
                                na=self.cfg.relay_na)

    # -- bookkeeping -------------------------------------------------------------------

    @property
    def mask_stage(self):
        """The bench's mask stage."""
        return self.bench.mask_stage

    def event(self, step: str, message: str, **data) -> None:
        """Report progress to ``on_event(step, message, data)`` (if given)."""
        if self.on_event is not None:
            self.on_event(step, message, data)

    def _log_reading(self, reading) -> None:
        if self.record is not None:
            self.record.log({**self._context, **reading.as_dict(),
                             "pose": self.bench.mask_stage.positions()})

    def save_step(self, name: str, result: dict) -> None:
        """Keep a step's result in ``state["steps"][name]`` and save the record."""
        self.state["steps"][name] = result
        self.state["captures"] = self.meter.captures
        if self.record is not None:
            self.record.save()

    # -- patterns and readings -----------------------------------------------------------

    def patch_centre(self, patch) -> tuple[float, float]:
        """Centre of the SLM patch ``(r0, r1, c0, c1)`` on the mask plane: (x, y) mask px
        from the optical axis."""
        r0, r1, c0, c1 = patch
        x, y = self.mm.slm_to_plane((r0 + r1) / 2.0, (c0 + c1) / 2.0)
        return float(x), float(y)

    def read(self, patch, shift, **context) -> SpotReading:
        """Show the spot pattern of ``patch`` for the model shifted by ``shift`` (integer
        mask px) and read the spot; ``context`` is logged with the reading."""
        self._context = {"patch": list(patch), "shift": [int(shift[0]), int(shift[1])],
                         **context}
        phase = _spot_phase(self.mm, self.u0, patch, shift=(int(shift[0]), int(shift[1])))
        return self.meter.read(phase, self.spot_px)

    def cross(self, patch, centre, step: str, rnd: int):
        """Separable cross of software shifts around ``centre``: triangle fits in x, y.

        Returns
        -------
        (TriangleFit, TriangleFit, float)
            The fits along x and y (offsets in mask px) and the largest eta read.
        """
        rad = self.cfg.cross_radius_px or self.k + 1
        sx, sy = (int(v) for v in centre)
        xs = np.arange(sx - rad, sx + rad + 1)
        ex = [self.read(patch, (x, sy), step=step, round=rnd, axis="x").eta for x in xs]
        fx = fit_triangle(xs, ex, self.k)
        bx = int(round(fx.offset)) if abs(fx.offset - sx) <= rad else sx
        ys = np.arange(sy - rad, sy + rad + 1)
        ey = [self.read(patch, (bx, y), step=step, round=rnd, axis="y").eta for y in ys]
        fy = fit_triangle(ys, ey, self.k)
        return fx, fy, max(max(ex), max(ey))

    # -- step 0: pre-flight --------------------------------------------------------------

    def preflight(self) -> dict:
        """Dark level, camera affine (mask out of the beam), spot frequency, model ceiling."""
        self.event("preflight", "dark frames")
        dark = self.meter.measure_dark()
        cam_map, resid = self._fourier_calibration()
        self.camera_map = cam_map
        self.u0 = self._choose_u0(cam_map) if self.cfg.u0 is None else tuple(self.cfg.u0)
        self.spot_px = tuple(float(v) for v in cam_map.to_camera(self.u0))
        rows, cols = self.mm.slm_shape
        f = math.sqrt(self.cfg.central_fraction)
        h, w = max(1, round(rows * f)), max(1, round(cols * f))
        self.central = ((rows - h) // 2, (rows - h) // 2 + h, (cols - w) // 2, (cols - w) // 2 + w)
        self.eta_model = self._model_efficiencies()
        res = {"dark_dn": dark, "camera_matrix": cam_map.matrix_array, "camera_offset":
               list(cam_map.offset), "affine_rms_px": resid, "u0": list(self.u0),
               "spot_px": list(self.spot_px), "central_patch": list(self.central),
               "eta_model_central": self.eta_model["central"],
               "eta_model_sections": self.eta_model["sections"]}
        self.save_step("preflight", res)
        self.event("preflight", f"affine rms {resid:.3f} px, u0 {self.u0}, spot at "
                   f"({self.spot_px[0]:.1f}, {self.spot_px[1]:.1f}) px")
        return res

    def _retracted(self):
        if self._retract is not None:
            return self._retract(self.bench)
        from ..holo_bench import far_field_setup

        return far_field_setup(self.bench)

    def _fourier_calibration(self) -> tuple[CameraMapping, float]:
        rows, cols = self.mm.slm_shape
        us = [(0.0, 0.0)] + [(a * cols / 4, b * rows / 4) for a in (-1, 0, 1) for b in (-1, 0, 1)
                             if (a, b) != (0, 0)]
        shape = tuple(self.bench.camera.image_shape)
        for attempt in range(1, 4):
            self.event("preflight", f"Fourier calibration, attempt {attempt}")
            pts = []
            with self._retracted():
                zero = None
                for u in us:
                    self._context = {"step": "fourier", "u": list(u), "attempt": attempt}
                    self.meter.show(blazed_phase(self.mm.slm_shape, u))
                    pts.append(self.meter.brightest(exclude_px=zero))
                    if zero is None:
                        zero = pts[0]
            u_arr, c_arr = np.asarray(us), np.asarray(pts)
            design = np.hstack([u_arr, np.ones((len(us), 1))])
            coef, *_ = np.linalg.lstsq(design, c_arr, rcond=None)
            rms = float(np.sqrt(np.mean((design @ coef - c_arr) ** 2)))
            if rms <= self.cfg.fourier_tol_px:
                m = coef[:2].T
                try:
                    return CameraMapping(shape=shape, matrix=m, offset=tuple(coef[2])), rms
                except ValueError as exc:
                    raise AlignmentFailed(f"camera affine is degenerate ({exc}); check that the "
                                          "grating spots reach the camera") from exc
        raise AlignmentFailed(
            f"camera <-> far-field affine residual {rms:.2f} px > {self.cfg.fourier_tol_px} px "
            "after 3 attempts; check that the mask leaves the beam when retracted and that the "
            "camera sees the SLM's first orders")

    def _choose_u0(self, cam: CameraMapping) -> tuple[float, float]:
        rows, cols = self.mm.slm_shape
        ny, nx = cam.shape
        margin = self.meter.window + 2
        fov = (cols * self.k / 2, rows * self.k / 2)
        for fx, fy in ((1.5, 0.5), (1.3, 0.4), (1.15, 0.3), (1.05, 0.2)):
            u = (round(fx * cols / 2), round(fy * rows / 2))
            if u[0] >= fov[0] or u[1] >= fov[1]:
                continue
            c = cam.to_camera(u)
            if margin <= c[0] < nx - margin and margin <= c[1] < ny - margin:
                return (float(u[0]), float(u[1]))
        raise AlignmentFailed("no spot frequency outside the SLM band lands on the camera; "
                              "pass u0 (far-field samples) or widen the camera's view")

    def _model_efficiencies(self) -> dict:
        """eta of each pattern on a perfectly aligned simulation of the model (the ceiling)."""
        mm = self.mm
        ideal = MaskModel(mm.slm_shape, mm.slm_pitch_um, mm.k, mm.q, mm.seed, margin=mm.margin,
                          bits=mm.bits)
        sim = HolographicDisplayModel(ideal, relay=self.relay, camera=self.camera_map)
        out = {}
        for name, patch in [("central", self.central)] + list(enumerate(self.sections)):
            frame = sim.render_phase(_spot_phase(mm, self.u0, patch))
            out[name] = float(efficiency(frame, self.spot_px, self.meter.window))
        return {"central": out.pop("central"), "sections": [out[j] for j in
                                                            range(len(self.sections))]}

    # -- step 2: coarse acquisition -------------------------------------------------------

    def coarse(self) -> dict:
        """Find the spot by software shifts of the model over the mechanical uncertainty."""
        step = self.cfg.coarse_step_px or max(1, self.k // 2)
        scanned: dict[tuple[int, int], float] = {}
        for widen, rng in enumerate((self.cfg.coarse_range_px, 2 * self.cfg.coarse_range_px)):
            grid = np.arange(-rng, rng + 1, step)
            for sy in grid:
                for sx in grid:
                    key = (int(sx), int(sy))
                    if key not in scanned:
                        scanned[key] = self.read(self.central, key, step="coarse",
                                                 widen=widen).eta
            self.event("coarse", f"{len(scanned)} shifts scanned (+-{rng} px)")
            etas = np.array(list(scanned.values()))
            background = float(np.median(np.abs(etas)))
            best = max(scanned, key=scanned.get)
            if scanned[best] > self.cfg.detection_factor * background:
                again = self.read(self.central, best, step="coarse", repeat=True).eta
                if again > self.cfg.detection_factor * background:
                    res = {"shift": list(best), "eta": scanned[best], "eta_repeat": again,
                           "background": background, "scanned": len(scanned),
                           "range_px": rng, "widened": bool(widen)}
                    self.save_step("coarse", res)
                    self.shift = np.array(best, dtype=np.int64)
                    return res
        self.save_step("coarse", {"scanned": len(scanned), "background": background,
                                   "best_eta": scanned[best], "found": False})
        raise MaskNotFound(
            f"no spot over +-{2 * self.cfg.coarse_range_px} mask px of software shift "
            f"({len(scanned)} patterns; best eta {scanned[best]:.3g} vs background "
            f"{background:.3g}): check that the mask is in the beam, the mask model (seed/"
            "pattern file) is the installed mask, and the SLM LUT is calibrated")

    # -- step 3: global translation --------------------------------------------------------

    def move(self, **deltas) -> None:
        """Move the mask stage by plane deltas: x_px, y_px (mask px), rz/rx/ry (rad), z_mm."""
        st = self.bench.mask_stage
        pitch_mm = self.mm.mask_pitch_um / 1000.0
        names = {"x_px": ("x", pitch_mm), "y_px": ("y", pitch_mm), "z_mm": ("z", 1.0),
                 "rz": ("rotation", None), "rx": ("tip", None), "ry": ("tilt", None)}
        move = {}
        for key, val in deltas.items():
            if val == 0.0:
                continue
            axis, scale = names[key]
            if axis not in st.axes:
                raise AlignmentFailed(f"the mask stage has no {axis!r} axis (it has {st.axes}); "
                                      "add it to the bench config or turn the step off")
            if scale is None:
                scale = 180.0 / math.pi if st.units(axis) == "deg" else 1.0
            move[axis] = val * scale
        if not move:
            return
        before = st.positions()
        st.move_by(move, timeout_s=self.cfg.timeout_s)
        self.bench.sleep(self.cfg.settle_s)
        moves = self.state.setdefault("stage_moves", [])
        moves.append({"delta": move, "before": before, "after": st.positions(),
                      "bench_time_s": self.bench.now_s()})

    def translate(self, label: str = "translation") -> dict:
        """Rounds of cross fits on the central patch; the stage takes the fractional part."""
        rounds, stable, reason = [], 0, "max rounds"
        for rnd in range(1, self.cfg.max_translation_rounds + 1):
            fx, fy, peak = self.cross(self.central, self.shift, label, rnd)
            d = np.array([fx.offset, fy.offset])
            sig = max(fx.offset_sigma, fy.offset_sigma)
            target = np.round(d).astype(np.int64)
            frac = d - target
            rounds.append({"offset": d, "sigma": [fx.offset_sigma, fy.offset_sigma],
                           "eta_peak": peak, "shift": target})
            self.shift = target
            self.event(label, f"round {rnd}: offset ({d[0]:+.3f}, {d[1]:+.3f}) px, "
                       f"sigma {sig:.3f}, eta {peak:.3g}")
            if np.max(np.abs(frac)) < self.cfg.translation_tol_px:
                stable += 1
                if stable >= 2 or rnd == self.cfg.max_translation_rounds:
                    reason = "converged"
                    break
                continue
            stable = 0
            if rnd > 1 and sig > np.max(np.abs(frac)):
                reason = "noise-limited"
                break
            if rnd < self.cfg.max_translation_rounds:
                self.move(x_px=-frac[0], y_px=-frac[1])
                self.stage_px_total -= frac
        self.offset = d
        res = {"rounds": rounds, "stop": reason, "shift": self.shift, "offset": d,
               "translation_px": d - self.stage_px_total}
        self.save_step(label, res)
        return res

    # -- step 4: rigid pose -------------------------------------------------------------------

    def measure_sections(self, label: str, rnd: int, centres=None) -> list[dict]:
        """Cross fits on every section (software shifts only)."""
        out = []
        for j, patch in enumerate(self.sections):
            start = self.shift if centres is None else centres[j]
            fx, fy, peak = self.cross(patch, start, label, rnd)
            out.append({"section": j, "centre": self.patch_centre(patch),
                        "offset": (fx.offset, fy.offset),
                        "sigma": (fx.offset_sigma, fy.offset_sigma), "eta_peak": peak})
        return out

    def rigid(self) -> dict:
        """Similarity fit of the section offsets; the stage takes rotation and translation.

        Each round measures every section's offset by software shifts, fits
        ``t + theta (-y, x) + (m - 1)(x, y)`` and moves the stage by ``-theta`` (when
        ``|theta|`` is at least ``rotation_tol_factor k / half-diagonal`` and 2 sigma)
        and by the sub-pixel move that best serves all sections once each is rounded
        to its integer shift (:func:`.fitting.best_subpixel_offset`; minus the
        fractional part of ``t`` when there is no distortion), when at least
        ``translation_tol_px`` and 2 sigma. Sigma is the measurement noise of the
        section offsets (median of their triangle-fit errors) propagated through the
        fit, not the misfit of a distortion. Whole-aperture estimates are several
        times more precise than the central patch's (the metric of one patch is itself
        random, docs/protocols.md). Stops when nothing moves, or after
        ``max_rigid_rounds``.
        """
        half_diag = math.hypot(*self.mm.half_size)
        tol = self.cfg.rotation_tol_factor * self.k / half_diag
        rounds, reason, centres = [], "max rounds", None
        for rnd in range(1, self.cfg.max_rigid_rounds + 1):
            secs = self.measure_sections("rigid", rnd, centres)
            offsets = np.array([s["offset"] for s in secs])
            noise = float(np.median([max(s["sigma"]) for s in secs]))
            fit = fit_similarity([s["centre"] for s in secs], offsets, offset_sigma=noise)
            t = np.asarray(fit.translation)
            # the sub-pixel move that serves all sections once each is rounded (after
            # the rotation about the axis, which leaves the centre in place)
            centres_xy = np.array([s["centre"] for s in secs])
            rot = np.stack([-centres_xy[:, 1], centres_xy[:, 0]], 1)
            rotate = (self.cfg.rotation and abs(fit.theta) >= tol
                      and abs(fit.theta) >= 2 * fit.sigmas[2])
            after = offsets - (fit.theta * rot if rotate else 0.0)
            phi, gain = best_subpixel_offset(after, self.k)
            self.shift = np.round(t).astype(np.int64)
            self.offset = t
            rounds.append({"theta_rad": fit.theta, "theta_sigma": fit.sigmas[2],
                           "translation": t, "translation_sigma": fit.sigmas[:2],
                           "scale_error": fit.scale_error, "offset_noise_px": noise,
                           "subpixel_move_px": phi, "predicted_gain": gain,
                           "residual_rms_px": fit.residual_rms, "sections": secs})
            self.section_fits = secs
            self.event("rigid", f"round {rnd}: t ({t[0]:+.3f}, {t[1]:+.3f}) px, theta "
                       f"{fit.theta * 1e3:+.3f} mrad (sigma {fit.sigmas[2] * 1e3:.3f}), m-1 "
                       f"{fit.scale_error:+.2e}, residual {fit.residual_rms:.3f} px, "
                       f"sub-pixel move ({phi[0]:+.2f}, {phi[1]:+.2f}) px")
            shift = [abs(f) >= self.cfg.translation_tol_px and abs(f) >= 2 * s
                     for f, s in zip(phi, fit.sigmas[:2], strict=True)]
            if not rotate and not any(shift):
                reason = "converged"
                break
            if rnd == self.cfg.max_rigid_rounds:
                break
            dth = -fit.theta if rotate else 0.0
            dxy = np.where(shift, phi, 0.0)
            self.move(x_px=dxy[0], y_px=dxy[1], rz=dth)
            self.rotation_applied += dth
            self.stage_px_total += dxy
            # where each section's offset should now be (rotation about the optical axis)
            centres = [np.round(np.asarray(s["offset"]) + dxy + dth *
                                np.array([-s["centre"][1], s["centre"][0]])).astype(int)
                       for s in secs]
        last = rounds[-1]
        res = {"rounds": rounds, "stop": reason, "tolerance_rad": tol,
               "theta_applied_rad": self.rotation_applied,
               "theta_recovered_rad": last["theta_rad"] - self.rotation_applied,
               "translation_px": np.asarray(last["translation"]) - self.stage_px_total,
               "scale_error": last["scale_error"], "shift": self.shift}
        self.save_step("rigid", res)
        return res

    # -- step 5: focus and tip/tilt ----------------------------------------------------------

    def focus(self) -> dict:
        """Step 5: focus and tip/tilt of the mask (stage z, tip, tilt).

        Runs ``focus.FocusStep`` on this aligner; its ``run`` describes the result (also
        saved as ``steps["focus"]``) and the errors raised.
        """
        return FocusStep(self).run()

    # -- step 6: piecewise integer correction -------------------------------------------------

    def _eta_stats(self, patch, shift, label, **ctx) -> tuple[float, float]:
        vals = [self.read(patch, shift, step=label, **ctx).eta for _ in range(self.cfg.repeats)]
        return float(np.mean(vals)), float(np.std(vals, ddof=1))

    def piecewise(self) -> dict:
        """Per-section integer shifts that beat the global shift by more than 3 sigma."""
        r = self.cfg.piecewise_radius_px
        g = np.asarray(self.shift)
        fits = self.section_fits
        shifts = []
        for j in range(len(self.sections)):
            start = g if fits is None else np.round(np.asarray(fits[j]["offset"])).astype(int)
            shifts.append(np.clip(start, g - r, g + r))
        shifts = np.array(shifts, dtype=np.int64)
        passes, reason = [], "max passes"
        cache: dict[tuple[int, int, int], list[float]] = {}

        def stats(j, s, repeats=self.cfg.repeats):
            key = (j, int(s[0]), int(s[1]))
            have = cache.setdefault(key, [])
            while len(have) < repeats:
                have.append(self.read(self.sections[j], s, step="piecewise", section=j).eta)
            return float(np.mean(have)), float(np.std(have, ddof=1)) if len(have) > 1 else 0.0

        for p in range(1, self.cfg.max_piecewise_passes + 1):
            changed = 0
            for j in range(len(self.sections)):
                cur = shifts[j]
                m_cur, s_cur = stats(j, cur)
                best, m_best = cur, m_cur
                for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    cand = cur + (dx, dy)
                    if np.any(np.abs(cand - g) > r):
                        continue
                    bar = m_best + 3 * max(s_cur, 1e-12)
                    if stats(j, cand, 1)[0] > bar:  # one look, then confirm with repeats
                        m, s = stats(j, cand)
                        if m > m_best + 3 * max(s, s_cur, 1e-12):
                            best, m_best = cand, m
                if not np.array_equal(best, cur):
                    shifts[j] = best
                    changed += 1
            passes.append({"changed": changed, "shifts": shifts.copy()})
            self.event("piecewise", f"pass {p}: {changed} section(s) changed")
            if changed == 0:
                reason = "no change"
                break
        self.section_shifts = shifts
        res = {"passes": passes, "stop": reason, "shifts": shifts,
               "relative_shifts": shifts - g}
        self.save_step("piecewise", res)
        return res

    # -- step 7: verify --------------------------------------------------------------------------

    def verify(self) -> dict:
        """Per-section eta vs the aligned simulation, residual offsets, the corrected mask."""
        etas, resid, ok = [], [], []
        for j, patch in enumerate(self.sections):
            m, _ = self._eta_stats(patch, self.section_shifts[j], "verify", section=j)
            etas.append(m)
            ok.append(m >= self.cfg.verify_fraction * self.eta_model["sections"][j])
        if self.section_fits is not None:
            for j, f in enumerate(self.section_fits):
                resid.append(float(np.max(np.abs(np.asarray(f["offset"])
                                                 - self.section_shifts[j]))))
        ratio = [e / m if m > 0 else float("nan") for e, m in zip(etas, self.eta_model["sections"],
                                                                  strict=True)]
        mask, seam = corrected_mask(self.mm, self.section_shifts, self.cfg.sections,
                                    self.cfg.piecewise_radius_px)
        if self.record is not None:
            self.record.save_mask(mask, seam)
        warnings = [f"section {j}: eta {etas[j]:.3g} is {ratio[j]:.2f} of the aligned simulation "
                    f"(< {self.cfg.verify_fraction})" for j in range(len(etas)) if not ok[j]]
        warnings += [f"section {j}: residual offset {v:.2f} px > {self.cfg.residual_tol_px} px "
                     "(sub-pixel distortion the integer correction cannot remove)"
                     for j, v in enumerate(resid) if v > self.cfg.residual_tol_px]
        focus_error = self.state["steps"].get("focus", {}).get("error")
        if focus_error:
            warnings.append(f"focus: {focus_error}")
        holo = hologram_check(self.meter, self.mm, mask, self.camera_map, self.relay)
        if holo["correlation"] is None:  # no light where the target should be
            warnings.append("test hologram: no light on the target region of the camera")
        elif holo["correlation"] < self.cfg.hologram_min_correlation:
            warnings.append(f"test hologram: correlation {holo['correlation']:.2f} with its "
                            f"simulation (< {self.cfg.hologram_min_correlation}); PSNR "
                            f"{holo['psnr_db']:.1f} dB")
        res = {"eta_sections": etas, "eta_model_sections": self.eta_model["sections"],
               "eta_ratio": ratio, "passed": bool(all(ok)) and not focus_error,
               "residual_px": resid,
               "warnings": warnings, "seam_fraction": float(1.0 - seam.mean()),
               "test_hologram": holo}
        self.save_step("verify", res)
        self.corrected = mask
        return res

    # -- the whole procedure ----------------------------------------------------------------------

    def run(self) -> dict:
        """Steps 0-7; returns the report (also in the record). Errors close the record."""
        status, error = "failed", None
        try:
            self.preflight()
            self.coarse()
            self.translate()
            self.rigid()
            focus = self.focus()
            self.piecewise()
            verify = self.verify()
            status = "completed"
            self.state["summary"] = {
                "translation_px": self.state["steps"]["rigid"]["translation_px"],
                "theta_rad": self.state["steps"]["rigid"]["theta_recovered_rad"],
                "section_shifts": self.section_shifts, "passed": verify["passed"],
                "focus_z_mm": focus.get("z_mm"), "focus_stop": focus.get("stop",
                                                                        focus.get("skipped")),
                "captures": self.meter.captures, "stage_pose": self.bench.mask_stage.positions(),
            }
            return self.state
        except BaseException as exc:
            status = "aborted" if isinstance(exc, RunAborted | KeyboardInterrupt) else "failed"
            error = f"{type(exc).__name__}: {exc}"
            try:
                self.bench.mask_stage.stop()
            except Exception:  # noqa: BLE001 (already handling an error; stop is best effort)
                pass
            raise
        finally:
            self.state["captures"] = self.meter.captures
            if error is not None:
                self.state["error"] = error
            if self.record is not None:
                self.record.close(status)
            else:
                self.state["status"] = status

