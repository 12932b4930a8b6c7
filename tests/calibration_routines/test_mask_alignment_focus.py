"""Step 5 of the mask alignment (focus, tip, tilt): its logic on a synthetic spot
response, and T4 (docs/protocols.md, "Mask alignment") on the virtual bench."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from calibration_routines.mask_alignment import (
    AlignmentConfig,
    AlignmentFailed,
    MaskAligner,
    load_alignment,
)
from calibration_routines.mask_alignment.focus import FocusStep
from calibration_routines.mask_alignment.record import section_bounds
from recon.optics.holo_display import MaskModel, MaskTransform

from .test_mask_alignment import _bench, _model

# ------------------------------------------------------ logic on a synthetic response


class _Stage:
    def __init__(self, axes=("x", "y", "z", "tip", "tilt", "rotation"), z_travel=(-5, 5)):
        self.axes = tuple(axes)
        self.pos = {a: 0.0 for a in axes}
        self.limits = {a: (-5.0, 5.0) for a in axes}
        self.limits["z"] = z_travel

    def position(self, axis):
        return self.pos[axis]

    def positions(self):
        return dict(self.pos)


class _SyntheticAligner:
    """A focus-step host (``focus.FocusHost``) on an analytic bench: each section's eta
    is a Gaussian in its local defocus ``dz + rx y - ry x`` (the display model's
    convention), plus noise. ``tip_sign = -1`` models a stage whose tip axis runs the
    other way."""

    def __init__(self, defocus_mm=0.1, tip=0.0, tilt=0.0, width_mm=0.12, noise=0.01,
                 tip_sign=1.0, flat=False, stage=None, **cfg):
        self.cfg = AlignmentConfig(relay_na=0.05, **cfg)
        self.mm = MaskModel((96, 120), 80.0, 4, 1, 0)  # 10x the pitch: tilts that matter
        self.relay = SimpleNamespace(wavelength_um=0.532)
        self.sections = section_bounds(self.mm.slm_shape, (3, 5))
        self.central = (40, 56, 50, 70)
        self.shift = np.zeros(2, np.int64)
        self.stage_px_total = np.zeros(2)
        self.mask_stage = stage or _Stage()
        self.bench = SimpleNamespace(mask_stage=self.mask_stage)
        self.section_fits = None
        self.truth = (defocus_mm, tip, tilt)
        self.width, self.noise, self.tip_sign, self.flat = width_mm, noise, tip_sign, flat
        self.rng = np.random.default_rng(1)
        self.events, self.saved, self.reads = [], {}, 0

    patch_centre = MaskAligner.patch_centre

    def focus(self):
        return FocusStep(self).run()

    def read(self, patch, shift, **ctx):
        self.reads += 1
        p = self.bench.mask_stage.pos
        x, y = (v * self.mm.mask_pitch_um / 1000.0 for v in self.patch_centre(patch))
        rx = self.truth[1] + self.tip_sign * math.radians(p["tip"])
        ry = self.truth[2] + math.radians(p["tilt"])
        dz = self.truth[0] + p["z"] + rx * y - ry * x
        eta = 1.0 if self.flat else math.exp(-0.5 * (dz / self.width) ** 2)
        return SimpleNamespace(eta=eta * (1 + self.noise * self.rng.normal()))

    def cross(self, patch, centre, step, rnd):
        fit = SimpleNamespace(offset=0.0, offset_sigma=0.01)
        return fit, fit, 1.0

    def move(self, **d):
        p = self.bench.mask_stage.pos
        p["z"] += d.get("z_mm", 0.0)
        p["tip"] += math.degrees(d.get("rx", 0.0))
        p["tilt"] += math.degrees(d.get("ry", 0.0))
        for a in ("z", "tip", "tilt"):
            lo, hi = self.bench.mask_stage.limits[a]
            if not lo <= p[a] <= hi:
                raise AlignmentFailed(f"{a} limit")

    def event(self, step, message, **data):
        self.events.append(message)

    def save_step(self, name, result):
        self.saved[name] = result

    def residual(self):
        p = self.bench.mask_stage.pos
        dz = self.truth[0] + p["z"]
        rx = self.truth[1] + self.tip_sign * math.radians(p["tip"])
        ry = self.truth[2] + math.radians(p["tilt"])
        return dz, rx, ry


def test_focus_converges_in_z_and_tilt_on_a_synthetic_response():
    al = _SyntheticAligner(defocus_mm=0.15, tip=0.02, tilt=-0.015)
    res = al.focus()
    dz, rx, ry = al.residual()
    assert res["stop"] == "converged" and res["error"] is None
    assert abs(dz) < 0.01  # DOF (0.8 width) ~ 0.16 mm here
    assert abs(rx) < 2e-3 and abs(ry) < 2e-3  # from 20 and 15 mrad
    assert res["dof_mm"] == pytest.approx(2 * math.sqrt(2 * math.log(1 / 0.8)) * 0.12, rel=0.15)
    assert len([r for r in res["rounds"] if "z_star_mm" in r]) <= al.cfg.max_focus_rounds
    assert al.reads == len(res["rounds"]) * 15 * 9


def test_focus_reverses_a_tilt_axis_that_runs_the_other_way():
    al = _SyntheticAligner(defocus_mm=0.0, tip=0.02, tip_sign=-1.0, max_focus_rounds=4)
    res = al.focus()
    assert "rx" in res["reversed_axes"]
    _, rx, _ = al.residual()
    assert abs(rx) < 3e-3, rx


def test_focus_widens_the_sweep_when_the_maximum_is_outside():
    al = _SyntheticAligner(defocus_mm=0.55, focus_range_mm=0.2)
    res = al.focus()
    assert any(r.get("widened") for r in res["rounds"])
    assert abs(al.residual()[0]) < 0.01 and res["stop"] == "converged"


def test_focus_without_a_maximum_fails_the_axis_and_returns_the_stage():
    stage = _Stage()
    stage.pos["z"] = 0.3
    al = _SyntheticAligner(flat=True, stage=stage)
    res = al.focus()
    assert res["stop"] == "failed" and "no focus maximum" in res["error"]
    assert stage.pos["z"] == pytest.approx(0.3)
    assert sum(bool(r.get("widened")) for r in res["rounds"]) == 2


def test_focus_sweep_beyond_the_travel_is_refused_with_the_fix():
    al = _SyntheticAligner(stage=_Stage(z_travel=(0.0, 10.0)))
    with pytest.raises(AlignmentFailed, match="z travel.*centre the stage"):
        al.focus()


def test_focus_skipped_without_a_z_axis_or_when_turned_off():
    al = _SyntheticAligner(stage=_Stage(axes=("x", "y", "rotation")))
    assert "no z axis" in al.focus()["skipped"]
    assert "turned off" in _SyntheticAligner(focus=False).focus()["skipped"]


def test_alignment_config_refuses_bad_focus_options():
    with pytest.raises(Exception, match="focus_steps"):
        AlignmentConfig(focus_steps=3)
    with pytest.raises(Exception, match="relay_na"):
        AlignmentConfig(relay_na=1.5)


# --------------------------------------------------------------- T4, virtual bench


def test_t4_focus_and_tilt_recovered_on_the_virtual_bench(tmp_path):
    """T4: truth defocus 0.15 mm (about DOF / 1.4) and a tilted mount; the stage's z
    must end within DOF / 5 of focus (DOF = lambda / NA^2 = 0.21 mm). The mask starts
    within the capture range (the coarse search is T1-T3's) and the translation step
    runs before the focus step, as in the procedure."""
    truth = MaskTransform(translation=(0.4, -0.3), defocus_mm=0.15, tip_rad=0.04,
                          tilt_rad=-0.03)
    bench = _bench(truth)
    al = MaskAligner(bench, _model(bench), AlignmentConfig(relay_na=bench.relay_na))
    al.preflight()
    al.shift = np.zeros(2, np.int64)
    al.translate()
    res = al.focus()
    pose = bench.mask_stage.positions()
    dof = bench.slm.wavelength_nm * 1e-6 / bench.relay_na**2
    assert res["stop"] == "converged", res["stop"]
    assert abs(pose["z"] + truth.defocus_mm) <= dof / 5
    # the tilt left defocuses the footprint's corner by less than DOF / 10
    hx, hy = (h * al.mm.mask_pitch_um / 1000 for h in al.mm.half_size)
    before = abs(truth.tip_rad) * hy + abs(truth.tilt_rad) * hx
    after = (abs(truth.tip_rad + math.radians(pose["tip"])) * hy
             + abs(truth.tilt_rad + math.radians(pose["tilt"])) * hx)
    assert after < min(dof / 10, before), (before, after)
    assert np.all(np.abs(res["image_motion"]["stage_move_px"]) < 0.3)


# ------------------------------------------------------------------ command line


def test_align_mask_cli_pattern_file_errors_and_a_wrong_mask(tmp_path, capsys):
    """``align mask``: a pattern of the wrong shape is bad input (2); a valid pattern
    that is not the installed mask fails the search (1) and keeps the record."""
    from instrument.cli import main

    bench_toml = str(Path(__file__).resolve().parents[2] / "examples" / "bench-simulated.toml")
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((10, 10), np.uint8))
    assert main(["align", "mask", bench_toml, "--simulate", "--mask-pattern", str(bad),
                 "--out", str(tmp_path / "a.align")]) == 2
    assert "bits has shape (10, 10)" in capsys.readouterr().err
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, MaskModel((96, 120), 8.0, 4, 4, seed=99).bits)
    out = tmp_path / "b.align"
    assert main(["align", "mask", bench_toml, "--simulate", "--mask-pattern", str(wrong),
                 "--coarse-range-px", "4", "--sim-translation-px", "1", "1",
                 "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "no spot over" in err and str(out) in err
    assert load_alignment(out)["status"] == "failed"


def test_align_mask_cli_needs_the_mask_on_a_real_bench(tmp_path, capsys):
    from instrument.cli import main

    bench_toml = str(Path(__file__).resolve().parents[2] / "examples" / "bench-simulated.toml")
    assert main(["align", "mask", bench_toml, "--out", str(tmp_path / "c.align")]) == 2
    assert "--mask-pattern" in capsys.readouterr().err
