"""The virtual bench: what the simulated camera sees follows the stage, LEDs and SLM."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import zoom
from scipy.signal import fftconvolve

from instrument.acquisition.exposure import ExposureError, autoexpose, average_frames
from instrument.devices.virtual_bench import PlanarScene, VirtualBench
from recon.errors import ReconInputError


@pytest.fixture()
def bench():
    with VirtualBench(seed=1) as vb:
        leds = vb.led_array
        pos = np.asarray(leds.positions_mm)
        vb.centre_led = int(np.argmin(np.hypot(pos[:, 0], pos[:, 1])))
        yield vb


def _capture_psf(vb, x, y, z, frames=2):
    vb.source_stage.move_to({"x": x, "y": y, "z": z}, timeout_s=60)
    # light the LED nearest the pinhole
    pos = np.asarray(vb.led_array.positions_mm)
    vb.led_array.set_leds([int(np.argmin(np.hypot(pos[:, 0] - x, pos[:, 1] - y)))])
    vb.camera.exposure_s = 0.2
    lit, _ = average_frames(vb.camera, frames)
    vb.led_array.all_off()
    dark, _ = average_frames(vb.camera, frames)
    return lit - dark


def _shift_px(a, b):
    """(dy, dx) such that b ~ a shifted by it, from the cross-correlation peak."""
    a = a - a.mean()
    b = b - b.mean()
    xc = fftconvolve(b, a[::-1, ::-1], mode="full")
    iy, ix = np.unravel_index(np.argmax(xc), xc.shape)
    return iy - (a.shape[0] - 1), ix - (a.shape[1] - 1)


def test_psf_cache_keeps_the_positions_used_last(bench):
    """The ray-traced PSFs are cached per position, the least recently used dropped
    first, at most PSF_CACHE_SIZE of them (a long session's stage positions are ever
    new: the cache must not grow with them)."""
    from instrument.devices.virtual_bench import PSF_CACHE_SIZE

    home = bench.psf((0.0, 0.0, 60.0))
    assert bench.psf((0.0, 0.0, 60.00001)) is home  # same position to 0.1 um: cached
    for k in range(1, 3 * PSF_CACHE_SIZE):
        bench.psf((0.01 * k, 0.0, 60.0))
        assert bench.psf((0.0, 0.0, 60.0)) is home  # used every step: kept
        assert len(bench._psf_cache) <= PSF_CACHE_SIZE
    assert (0.01, 0.0, 60.0) not in bench._psf_cache  # used once, long ago: dropped
    first = bench.psf((0.01, 0.0, 60.0))  # traced again, the same
    np.testing.assert_array_equal(first, bench.model.psf((0.01, 0.0, 60.0)))


def test_lateral_stage_move_shifts_psf_by_d_over_z(bench):
    """Eq. 3.1: a lateral source shift dx moves the PSF by -dx d/z on the sensor."""
    z, dx, dy = 40.0, 0.6, -0.4  # mm
    h0 = _capture_psf(bench, 0.0, 0.0, z)
    h1 = _capture_psf(bench, dx, dy, z)
    g = bench.geometry
    pitch_mm = g.sensor_pitch_um * 1e-3
    expected = (-dy * g.d_mm / z / pitch_mm, -dx * g.d_mm / z / pitch_mm)  # (rows, cols)
    got = _shift_px(h0, h1)
    assert abs(got[0] - expected[0]) <= 1.0 and abs(got[1] - expected[1]) <= 1.0, (got, expected)
    assert abs(expected[1]) > 8  # the move is large enough to be a real test


def test_axial_stage_move_scales_psf(bench):
    """Fig. 4.2: a closer source gives a larger caustic, magnified by (z + d) / z
    relative to the diffuser; the ratio between two depths is found by a scale search."""
    z1, z2 = 30.0, 80.0
    h1 = _capture_psf(bench, 0.0, 0.0, z1)
    h2 = _capture_psf(bench, 0.0, 0.0, z2)
    d = bench.geometry.d_mm
    expected = ((z1 + d) / z1) / ((z2 + d) / z2)  # h1 = h2 scaled by this
    scales = np.linspace(1.0, 1.4, 41)
    scores = []
    for s in scales:
        big = zoom(h2, s, order=1)
        r0 = (big.shape[0] - h2.shape[0]) // 2
        c0 = (big.shape[1] - h2.shape[1]) // 2
        crop = big[r0:r0 + h2.shape[0], c0:c0 + h2.shape[1]]
        a, b = crop - crop.mean(), h1 - h1.mean()
        scores.append(float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum())))
    best = scales[int(np.argmax(scores))]
    assert abs(best - expected) <= 0.03, (best, expected)
    assert max(scores) > 0.5 > scores[0]  # scaled copies match, the unscaled one does not


def test_no_light_no_psf_and_led_coupling(bench):
    bench.source_stage.move_to({"x": 0.0, "y": 0.0, "z": 40.0}, timeout_s=60)
    assert bench.source_power_photons_per_s() == 0.0
    bench.led_array.set_leds([bench.centre_led])
    on_axis = bench.source_power_photons_per_s()
    far = int(np.argmax(np.hypot(*np.asarray(bench.led_array.positions_mm).T)))
    bench.led_array.set_leds([far])
    assert bench.source_power_photons_per_s() < 1e-3 * on_axis
    bench.led_array.set_leds([bench.centre_led], brightness=0.5)
    assert bench.source_power_photons_per_s() == pytest.approx(0.5 * on_axis)


def test_autoexpose_reaches_target_and_reports_rails(bench):
    bench.source_stage.move_to({"x": 0.0, "y": 0.0, "z": 40.0}, timeout_s=60)
    bench.led_array.set_leds([bench.centre_led])
    bench.camera.exposure_s = 1e-4
    result = autoexpose(bench.camera, target=0.5, tolerance=0.1, dark_level=64.0)
    assert abs(result.peak_fraction - 0.5) <= 0.1
    bench.led_array.all_off()  # nothing but dark: the target needs more than the bound
    with pytest.raises(ExposureError, match="outside"):
        autoexpose(bench.camera, dark_level=64.0, bounds_s=(1e-5, 0.05))


def test_scene_truth_needs_a_planar_scene(bench):
    with pytest.raises(ReconInputError):
        bench.scene_truth()
    bench.set_scene(PlanarScene(np.ones((8, 8)), 40.0, 10.0))
    truth = bench.scene_truth()
    assert truth.shape == bench.geometry.sensor_shape and truth.max() == pytest.approx(1.0)


@pytest.mark.parametrize("relay_na, bounds", [(None, (0.4, 0.7)), (0.05, (0.7, 0.9))])
def test_holography_branch_misaligned_mask_lowers_the_spot(relay_na, bounds):
    """A focused spot computed for the model mask loses intensity when the mask
    stage moves the true mask by one mask pixel: the triangle law ~ (1 - 1/k)^2 with
    an ideal relay; less with the default relay pupil, which rounds the SLM pixels
    (the apex of the triangle)."""
    from recon.optics.holo_display import phase_to_gray, spot_phase

    bench = VirtualBench(seed=0, relay_na=relay_na).open()
    bench.set_branch("holography")
    holo = bench.hologram
    u0 = (17.0, 11.0)
    gray = phase_to_gray(spot_phase(holo.mask, u0))
    bench.slm.show_image(gray)
    spot = [int(round(v)) for v in holo.spot_camera_px(u0)]

    def peak():
        img = bench.irradiance(bench.camera)
        r, c = spot[1], spot[0]
        return float(img[r - 2:r + 3, c - 2:c + 3].sum())

    aligned = peak()
    mask_px_mm = holo.mask.mask_pitch_um * 1e-3
    bench.mask_stage.move_to({"x": mask_px_mm}, timeout_s=60)
    shifted = peak()
    assert bounds[0] < shifted / aligned < bounds[1], shifted / aligned


def test_scenes_reach_the_camera(bench):
    """Beads in 3D and a tilted target both light the sensor; nothing without a scene."""
    from instrument.devices.virtual_bench import BeadScene, TiltedTargetScene

    assert not np.any(bench.irradiance(bench.camera))
    bench.set_scene(BeadScene(np.array([[0.0, 0.0, 40.0], [1.0, -0.5, 60.0]]),
                              np.array([1e11, 1e11])))
    beads = bench.irradiance(bench.camera)
    bench.set_scene(TiltedTargetScene(30.0, 60.0, 8.0))
    target = bench.irradiance(bench.camera)
    assert beads.sum() > 0 and target.sum() > 0
    assert not np.allclose(beads / beads.sum(), target / target.sum())
    with pytest.raises(ReconInputError):
        bench.set_scene("a photo")


def test_holography_laser_power_drifts_with_bench_time_and_eta_does_not(bench):
    """The laser's power walks slowly with the bench clock (the camera sees it); the
    spot efficiency eta, a ratio to the frame's energy, does not."""
    from recon.optics.holo_display import efficiency, phase_to_gray, spot_phase

    bench.set_branch("holography")
    holo = bench.hologram
    u0 = (17.0, 11.0)
    bench.slm.show_image(phase_to_gray(spot_phase(holo.mask, u0)))
    spot = holo.spot_camera_px(u0)
    first = bench.irradiance(bench.camera).copy()
    bench.sleep(3600.0)
    later = bench.irradiance(bench.camera)
    ratio = later.sum() / first.sum()
    assert abs(ratio - 1.0) > 1e-3  # ~1e-3 per sqrt(s) over an hour (mean-reverting)
    np.testing.assert_allclose(later, first * ratio, rtol=1e-9)
    assert holo.drift.time_s == pytest.approx(bench.now_s())
    assert efficiency(later, spot) == pytest.approx(efficiency(first, spot), rel=1e-9)
