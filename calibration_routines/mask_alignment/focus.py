"""Step 5 of the mask alignment: focus and tip/tilt of the mask (stage z, tip, tilt).

docs/protocols.md, "Mask alignment", step 5 (slmsuite's Zernike-sweep style): sweep the
stage z over ``+-range`` in ``focus_steps`` steps; at every z show each section's
spot pattern and read eta; fit a parabola to each section's eta(z) near its top
(:func:`.fitting.fit_parabola`). A fit counts only if it has a maximum inside the
sweep. If fewer than ``focus_min_fraction`` of the sections give one, the range is
doubled (at most twice, centred on the best z seen) and then the focus axis fails
(the lateral alignment is kept; the record says what to check). Otherwise:

* per-section optima ``z_j`` are fitted by a plane ``z0 + b_x x + b_y y`` over the
  section centres (mm from the optical axis; :func:`.fitting.fit_plane`); ``z0`` is
  the best stage z on the axis;
* with the stage's convention (:class:`recon.optics.holo_display.StagePose`: the local
  defocus is ``dz + rx y - ry x``) the optima lie on ``z0 - rx y + ry x``, so the
  stage's tip (rx) moves by ``b_y`` and its tilt (ry) by ``-b_x``. A tilt is
  corrected only when it is at least 2 sigma and defocuses the footprint's corner by
  at least 0.1 of the sweep step; if a correction makes the slope on that axis grow
  (about doubled, same sign) the axis runs the other way on this stage and its
  direction is reversed for the next moves (recorded);
* stop when the move of z0 is below DOF/10 (DOF: the median full width of the
  sections' parabolas at 0.8 of their peak) and no tilt needs correcting, or after
  ``max_focus_rounds``; a round that needed a widened sweep never ends the step
  (its coarse sampling; the next round sweeps the first range around the new z).

Afterwards step 3 is repeated as a differential measurement: the central patch's
offset measured before the focus step and after it; an image motion of at least the
translation tolerance and 2 sigma is taken out by the stage (the central patch's
absolute offset carries a bias of its own random metric, which the difference
cancels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from instrument.acquisition.plan import PlanError
from recon.optics.holo_display import MaskModel, RelayModel

from .config import AlignmentConfig
from .errors import AlignmentFailed
from .fitting import TriangleFit, fit_parabola, fit_plane
from .spotmeter import SpotReading

__all__ = ["FocusHost", "FocusStep"]


@dataclass
class _TiltState:
    """Tip/tilt decisions across focus rounds: axis directions and the last slopes."""

    can: dict
    sign: dict = field(default_factory=lambda: {"rx": 1.0, "ry": 1.0})
    last: dict = field(default_factory=dict)
    applied: dict = field(default_factory=lambda: {"rx": 0.0, "ry": 0.0})
    reversed: list = field(default_factory=list)

    def moves(self, plane, edge_mm: dict, min_corner_mm: float, on_reverse) -> dict:
        """Stage rotations (rad) for this round's plane (None: no tilt information).

        An axis moves when its slope is at least 2 sigma and defocuses the footprint's
        edge by ``min_corner_mm``; a slope that about doubled with the same sign after
        a correction reverses that axis's direction (``on_reverse(axis)``).
        """
        move = {"rx": 0.0, "ry": 0.0}
        if plane is not None:
            slopes = {"rx": plane.slope_y, "ry": -plane.slope_x}
            sig = {"rx": plane.sigmas[2], "ry": plane.sigmas[1]}
            for ax, slope in slopes.items():
                prev = self.last.get(ax)
                if (prev is not None and self.applied[ax] != 0.0 and slope * prev > 0
                        and abs(slope) > 1.5 * abs(prev)):
                    self.sign[ax] = -self.sign[ax]
                    self.reversed.append(ax)
                    on_reverse(ax)
                if (self.can[ax] and abs(slope) >= 2 * sig[ax]
                        and abs(slope) * edge_mm[ax] >= min_corner_mm):
                    move[ax] = self.sign[ax] * slope
            self.last = slopes
        self.applied = dict(move)
        return move


class FocusHost(Protocol):
    """What the focus step uses of the aligner (:class:`.procedure.MaskAligner` is one).

    Attributes
    ----------
    cfg : AlignmentConfig
        Its ``focus*`` options, ``relay_na`` and ``translation_tol_px``.
    mm : recon.optics.holo_display.MaskModel
        The mask model: SLM and mask pitches (um), ``half_size`` (mask px).
    relay : recon.optics.holo_display.RelayModel
        Its ``wavelength_um`` (the default sweep range).
    mask_stage : drivers.stage.Stage
        Read only: ``axes``, ``limits``, ``position(axis)``, ``positions()`` (moves go
        through :meth:`move`).
    sections : list of (int, int, int, int)
        Section bounds ``(r0, r1, c0, c1)`` on the SLM.
    central : (int, int, int, int)
        The central patch (step 3's).
    shift : numpy.ndarray
        (2,) int64, the model's global software shift (mask px); the step adds the
        whole pixels of the image motion it measures.
    section_fits : list of dict or None
        Step 4's per-section fits (``"offset"``: (x, y) mask px), None before step 4;
        their offsets take the same whole pixels.
    stage_px_total : numpy.ndarray
        (2,) float, stage translation applied so far (mask px); the step's sub-pixel
        correction is subtracted.
    """

    cfg: AlignmentConfig
    mm: MaskModel
    relay: RelayModel
    mask_stage: Any
    sections: list
    central: tuple
    shift: np.ndarray
    section_fits: list | None
    stage_px_total: np.ndarray

    def patch_centre(self, patch) -> tuple[float, float]:
        """Centre of an SLM patch on the mask plane, (x, y) mask px from the axis."""

    def read(self, patch, shift, **context) -> SpotReading:
        """One spot reading of ``patch`` with the model shifted by ``shift`` (mask px);
        ``context`` goes to the record."""

    def cross(self, patch, centre, step: str, rnd: int) -> tuple[TriangleFit, TriangleFit,
                                                                   float]:
        """Separable cross of software shifts around ``centre``: (fit x, fit y, peak eta)."""

    def move(self, **deltas: float) -> None:
        """Move the mask stage by plane deltas: ``x_px``, ``y_px`` (mask px), ``rx``,
        ``ry``, ``rz`` (rad), ``z_mm``."""

    def event(self, step: str, message: str, **data) -> None:
        """Report progress."""

    def save_step(self, name: str, result: dict) -> None:
        """Keep a step's result (and save the record)."""


class FocusStep:
    """Step 5 of the mask alignment on a host aligner (see the module docstring).

    ``FocusStep(aligner).run()`` sweeps, fits and moves the mask stage through the
    aligner (``aligner.focus()`` does this).

    Parameters
    ----------
    host : FocusHost
        The aligner: configuration, mask model, stage, sections and its readings.
    """

    def __init__(self, host: FocusHost):
        self.host = host
        self.cfg = host.cfg
        self.stage = host.mask_stage

    def default_range_mm(self) -> float:
        """Half-range of the first z sweep (mm): the relay's depth of field
        ``lambda / NA^2`` when its NA is configured, else ``2 Delta^2 / lambda`` (the
        defocus over which an SLM pixel of pitch ``Delta`` blurs by about its size)."""
        lam_mm = self.host.relay.wavelength_um / 1000.0
        if self.cfg.relay_na is not None:
            return lam_mm / self.cfg.relay_na**2
        pitch_mm = self.host.mm.slm_pitch_um / 1000.0
        return 2.0 * pitch_mm**2 / lam_mm

    def _section_shifts(self) -> list[np.ndarray]:
        fits = self.host.section_fits
        if fits is None:
            return [np.asarray(self.host.shift, np.int64)] * len(self.host.sections)
        return [np.round(np.asarray(f["offset"])).astype(np.int64) for f in fits]

    def _sweep(self, zs, shifts, rnd: int, widen: int) -> np.ndarray:
        """eta of every section at every z (stage moved in ascending z): (sections, z)."""
        st = self.stage
        out = np.empty((len(self.host.sections), len(zs)))
        for i, z in enumerate(zs):
            self.host.move(z_mm=float(z) - st.position("z"))
            for j, patch in enumerate(self.host.sections):
                out[j, i] = self.host.read(patch, shifts[j], step="focus", round=rnd,
                                           widen=widen, section=j, z_mm=float(z)).eta
        return out

    def _check_travel(self, zs) -> None:
        lo, hi = self.stage.limits["z"]
        if zs[0] < lo or zs[-1] > hi:
            raise AlignmentFailed(
                f"focus sweep z {zs[0]:.3f}..{zs[-1]:.3f} mm leaves the mask stage's z travel "
                f"[{lo:g}, {hi:g}] mm; centre the stage's z near focus before aligning, or "
                "lower focus_range_mm")

    def run(self) -> dict:
        """Step 5: z sweeps per section, parabola vertices, plane fit -> z, tip, tilt.

        Returns
        -------
        dict
            The step's record (also saved as ``steps["focus"]``): ``rounds`` (per
            round the sweep ``z_mm`` (n,), ``eta`` (sections, n), accepted fits,
            vertices and their sigmas in mm, ``dof_mm``, the plane and the tilt
            correction in rad), ``stop`` ("converged", "max rounds" or "failed"),
            ``error`` (why the axis failed, or None), ``z_mm`` and
            ``tilt_applied_deg`` (stage pose after the step), ``reversed_axes``,
            ``image_motion`` (the differential step 3); or ``skipped`` with the reason.

        Raises
        ------
        AlignmentFailed
            A sweep would leave the stage's z travel (the message names the fix).
        drivers.errors.DeviceError
            A stage move fails (e.g. a tilt correction beyond the stage's limits).
        instrument.acquisition.runner.RunAborted
            The operator aborted between readings.
        """
        cfg, st = self.cfg, self.stage
        skip = ("focus step turned off (focus = false)" if not cfg.focus else
                None if "z" in st.axes else f"the mask stage has no z axis (axes {list(st.axes)})")
        if skip is not None:
            self.host.save_step("focus", {"skipped": skip})
            self.host.event("focus", skip)
            return {"skipped": skip}
        half = base_half = float(cfg.focus_range_mm or self.default_range_mm())
        shifts = self._section_shifts()
        pitch_mm = self.host.mm.mask_pitch_um / 1000.0
        centres = np.array([self.host.patch_centre(p) for p in self.host.sections]) * pitch_mm
        hx, hy = (h * pitch_mm for h in self.host.mm.half_size)
        need = max(3, math.ceil(cfg.focus_min_fraction * len(self.host.sections)))
        tilt = _TiltState(can={"rx": "tip" in st.axes, "ry": "tilt" in st.axes})
        ref = self.host.cross(self.host.central, self.host.shift, "focus_reference", 0)
        z_start = z_centre = st.position("z")
        rounds: list[dict] = []
        reason, failed, widen, rnd = "max rounds", None, 0, 0
        while rnd < cfg.max_focus_rounds:
            zs = z_centre + np.linspace(-half, half, cfg.focus_steps)
            self._check_travel(zs)
            etas = self._sweep(zs, shifts, rnd + 1, widen)
            fits = [fit_parabola(zs, e) for e in etas]
            ok = np.array([f.accepted for f in fits])
            if ok.sum() < need:
                peak_z = float(zs[int(np.argmax((etas / np.maximum(
                    etas.max(axis=1, keepdims=True), 1e-30)).mean(axis=0)))])
                self.host.event("focus", f"{int(ok.sum())}/{len(fits)} sections peak inside "
                                f"+-{half:.3f} mm" + (", widening" if widen < 2 else ""))
                rounds.append({"round": rnd + 1, "z_mm": zs, "eta": etas, "accepted": ok,
                               "widened": widen < 2, "reasons": [f.reason for f in fits]})
                if widen >= 2:
                    failed = (f"no focus maximum for {len(fits) - int(ok.sum())} of "
                              f"{len(fits)} sections over +-{half:.3f} mm around z = "
                              f"{z_centre:.3f} mm; check the relay focus and the stage's z "
                              "travel, or set focus_range_mm")
                    break
                widen += 1
                half *= 2.0
                z_centre = peak_z
                continue
            rnd += 1
            swept = half
            half = base_half  # a widened sweep found the focus: back to the fine range
            zv = np.array([f.vertex for f in fits])[ok]
            sv = np.array([max(f.vertex_sigma, 1e-9) for f in fits])[ok]
            dof = float(np.median([f.width_80 for f, a in zip(fits, ok, strict=True) if a]))
            try:
                plane = fit_plane(centres[ok], zv, sv)
            except PlanError:  # the accepted sections lie on a line: z from their mean only
                plane = None
            z_star = plane.z0 if plane is not None else float(np.mean(zv))
            step = 2.0 * swept / (cfg.focus_steps - 1)
            move_tilt = tilt.moves(plane, {"rx": hy, "ry": hx}, 0.1 * step,
                                   lambda ax: self.host.event(
                                       "focus", f"{ax}: the correction made the tilt worse; "
                                       "the stage axis runs the other way, reversed"))
            slopes = {} if plane is None else tilt.last
            dz = z_star - z_centre
            rounds.append({"round": rnd, "z_mm": zs, "eta": etas, "accepted": ok,
                           "range_mm": swept, "vertices_mm": [f.vertex for f in fits],
                           "vertex_sigmas_mm": [f.vertex_sigma for f in fits],
                           "dof_mm": dof, "z_star_mm": z_star, "dz_mm": dz,
                           "plane": None if plane is None else {
                               "z0_mm": plane.z0, "slope_x": plane.slope_x,
                               "slope_y": plane.slope_y, "sigmas": plane.sigmas,
                               "residual_rms_mm": plane.residual_rms},
                           "tilt_correction_rad": move_tilt})
            self.host.event("focus", f"round {rnd}: best z {z_star:+.4f} mm (move "
                            f"{dz * 1e3:+.1f} um, DOF {dof * 1e3:.0f} um), tilt slopes "
                            + ", ".join(f"{a} {v * 1e3:+.2f} mrad" for a, v in slopes.items()))
            self.host.move(z_mm=z_star - st.position("z"), rx=move_tilt["rx"],
                           ry=move_tilt["ry"])
            z_centre = z_star
            if swept == base_half and abs(dz) < dof / 10.0 and not any(move_tilt.values()):
                reason = "converged"
                break
        if failed is not None:
            self.host.move(z_mm=z_start - st.position("z"))
            reason = "failed"
        motion = self._image_motion(ref)
        res = {"rounds": rounds, "stop": reason, "error": failed, "range_mm": base_half,
               "z_start_mm": z_start, "z_mm": st.position("z"),
               "tilt_applied_deg": {a: st.position(a) for a in ("tip", "tilt") if a in st.axes},
               "reversed_axes": tilt.reversed, "dof_mm": rounds[-1].get("dof_mm") if rounds
               else None, "image_motion": motion}
        self.host.save_step("focus", res)
        return res

    def _image_motion(self, ref) -> dict:
        """Step 3 again, differentially: the central patch's offset before vs after."""
        fx0, fy0, _ = ref
        fx, fy, _ = self.host.cross(self.host.central, self.host.shift, "focus_check", 0)
        d = np.array([fx.offset - fx0.offset, fy.offset - fy0.offset])
        sig = np.hypot([fx.offset_sigma, fy.offset_sigma], [fx0.offset_sigma, fy0.offset_sigma])
        move = np.where((np.abs(d) >= self.cfg.translation_tol_px) & (np.abs(d) >= 2 * sig),
                        d, 0.0)
        whole = np.round(move).astype(np.int64)
        frac = move - whole
        if np.any(frac != 0.0):
            self.host.move(x_px=-frac[0], y_px=-frac[1])
            self.host.stage_px_total -= frac
        if np.any(whole != 0):  # whole pixels stay in the model's shifts
            self.host.shift = np.asarray(self.host.shift) + whole
            for f in self.host.section_fits or []:
                f["offset"] = tuple(np.asarray(f["offset"]) + whole)
        return {"offset_change_px": d, "sigma_px": sig, "stage_move_px": -frac,
                "shift_change_px": whole}
