"""The diffuser fluorescence microscope (Ch. 6): bench file, virtual twin, calibration
grids at the Eq. 5.9 / 5.10 spacings, and (slow) the end-to-end 3D bead reconstruction."""

from pathlib import Path

import numpy as np
import pytest

from calibration_routines.microscope import (
    calibrate_microscope,
    microscope_depths,
    microscope_grid_plans,
)
from instrument.devices.bench_setup import load_bench
from instrument.devices.virtual_bench import BeadScene, VirtualBench
from recon.analysis import lateral_calibration_spacing_mm

BENCH = Path(__file__).resolve().parents[2] / "examples" / "bench-microscope.toml"


def test_microscope_bench_twin_has_the_chapter_6_optics():
    cfg = load_bench(BENCH)
    assert cfg.geometry.sensor_falloff_sigma_deg == 13.0
    vb = VirtualBench(cfg)
    assert vb.geometry.falloff_sigma_deg == 13.0 and vb.geometry.d_mm == 3.8
    assert vb.geometry.surface.max_deflection_deg() > 5  # lenslets, f = 1.5 mm
    vb.open()
    try:
        empty = np.asarray(vb.irradiance(vb.camera))
        assert not np.any(empty)  # nothing lit: no background either
        vb.set_scene(BeadScene(np.array([[0.0, 0.0, 2.4]]), np.array([1e9])))
        lit = np.asarray(vb.irradiance(vb.camera))
        glow = cfg.geometry.background_light_photons_per_s * vb.stray_light_map()
        assert lit.min() >= glow.min() * 0.999  # the smooth background is everywhere
        assert lit.sum() > glow.sum()
    finally:
        vb.close()


def test_calibration_grids_follow_eq_5_9_and_eq_5_10():
    z = microscope_depths(1.7, 3.0, wavelength_nm=520, lenslet_um=250)
    assert len(z) == 9 and z[0] == 1.7 and z[-1] == 3.0
    assert np.max(np.diff(1 / z[::-1])) <= 4 * 520e-6 / 0.25**2 + 1e-12
    with VirtualBench(load_bench(BENCH)) as vb:
        plans = microscope_grid_plans(vb, n=5)
    assert [p.params["z_mm"] for p in plans] == pytest.approx(list(z))
    for p in plans:
        want = lateral_calibration_spacing_mm(13.0, p.params["z_mm"])
        assert p.grid_spacing_mm() == pytest.approx(want)
        assert p.nyquist_check()["ok"] and p.params["mode"] == "stage"
    sides = [int(round(np.sqrt(len(p.params["positions_mm"])))) for p in plans]
    assert sides == [4] * 9  # a 5 x 5 grid's outer PSFs would leave the sensor


@pytest.mark.slow
def test_microscope_end_to_end_beads_at_their_depths(tmp_path):
    """Calibrate (3 x 3 grids at the 9 Eq. 5.10 depths, Eq. 5.9 spacing), image four
    beads at three depths over the excitation background, reconstruct the volume with
    the local convolution model and the background estimate: every bead is found in
    its plane (about 3 minutes on 2 cores)."""
    from instrument.processing.reconstruct_grid import load_psf_grid
    from recon import reconstruct_grid
    from recon.volume.localize import detect_peaks, match_peaks

    beads = np.array([(0.15, -0.1, 1.9), (-0.2, 0.12, 2.35), (0.05, 0.2, 2.8),
                      (-0.1, -0.15, 2.8)])
    with VirtualBench(load_bench(BENCH), seed=3) as vb:
        runs = calibrate_microscope(vb, tmp_path / "runs", n=3, frames_per_point=1)
        vb.set_scene(BeadScene(beads, np.full(len(beads), 2e11)))
        vb.camera.exposure_s = 2e-3
        raw = np.asarray(vb.camera.snap(timeout_s=10).image, np.float64)
        assert 0.2 < raw.max() / 4095 < 0.95
        d, pitch = vb.geometry.d_mm, vb.geometry.sensor_pitch_um * 1e-3
        rows, cols = vb.geometry.sensor_shape
    grids = [load_psf_grid(r) for r in runs]
    rec = reconstruct_grid(grids, raw, model="local", background="estimate",
                           iterations=150, l1=1e-3, dark=64.0)
    depths = np.array(rec.info["depths_mm"])
    truth = np.array([(np.interp(1 / z, 1 / depths[::-1], np.arange(len(depths))[::-1]),
                       (rows - 1) / 2 - y * d / z / pitch, (cols - 1) / 2 - x * d / z / pitch)
                      for x, y, z in beads])
    peaks = detect_peaks(rec.image, threshold=0.1)
    match = match_peaks(peaks, truth, max_lateral_px=3.0, max_axial_planes=1.0)
    assert match["missed"] == [], (peaks, truth)
    assert np.max(np.abs(match["axial_planes"])) <= 0.5
    assert np.max(match["lateral_px"]) <= 2.0
    assert rec.background is not None and rec.background.mean() > 0
