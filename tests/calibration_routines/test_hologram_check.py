"""The verification step's test hologram (docs/protocols.md, "Mask alignment", step 7).

On the virtual bench (true camera mapping and relay of the bench, the model mask
with all-zero section shifts as the corrected mask): an aligned mask reproduces the
simulated hologram speckle for speckle, a mask displaced by 2 mask px or of the
wrong seed does not. Without the bench: the orientation conventions between the
hologram grid (ScatteringDisplay), the fine display model and the camera mapping.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from calibration_routines.mask_alignment.hologram_check import (
    compare_frames,
    hologram_check,
    place_target,
    target_region,
)
from calibration_routines.mask_alignment.record import corrected_mask
from calibration_routines.mask_alignment.spotmeter import SpotMeter
from instrument.acquisition.plan import PlanError
from instrument.devices.virtual_bench import VirtualBench
from recon.cgh import ScatteringDisplay, optimize_hologram, random_binary_mask
from recon.optics.holo_display import (
    CameraMapping,
    HolographicDisplayModel,
    MaskModel,
    MaskTransform,
)


@pytest.fixture(scope="module")
def rig():
    """Aligned holography bench, its dark-calibrated meter, the software's model and
    the corrected mask of an alignment that needed no section shifts."""
    bench = VirtualBench(seed=0).open()
    bench.set_branch("holography")
    bench.slm.lut_rad = bench.slm_response.lut_rad(bench.slm.wavelength_nm)  # LUT calibrated
    bench.hologram.mask.truth = MaskTransform()
    m = bench.hologram.mask
    model = MaskModel(m.slm_shape, m.slm_pitch_um, m.k, m.q, m.seed, margin=m.margin)
    mask, _ = corrected_mask(model, np.zeros((15, 2), int), (3, 5))
    meter = SpotMeter(bench)
    meter.measure_dark()
    yield bench, meter, model, mask
    bench.close()


def _check(rig, truth: MaskTransform, mask=None, **kwargs) -> dict:
    bench, meter, model, cmask = rig
    bench.hologram.mask.truth = truth
    try:
        return hologram_check(meter, model, cmask if mask is None else mask,
                              bench.hologram.camera, bench.hologram.relay, **kwargs)
    finally:
        bench.hologram.mask.truth = MaskTransform()


def test_aligned_bench_matches_its_simulation(rig):
    res = _check(rig, MaskTransform())
    # measured: PSNR 51.5 dB, SSIM 0.999, correlation 0.9994 (camera noise, 8-bit LUT
    # quantisation and the bench's 4x supersampled mask rendering are the difference)
    assert res["psnr_db"] > 45.0
    assert res["ssim"] > 0.98
    assert res["correlation"] > 0.99
    # the target lies where the camera sees it: most simulated light lands on it
    # (0.76 measured) and the capture agrees
    assert res["energy_in_region_simulated"] > 0.6
    assert res["energy_in_region_captured"] == pytest.approx(
        res["energy_in_region_simulated"], abs=0.02)
    assert 0.3 < res["peak_fraction"] < 0.7 and not res["railed"] and res["exposure_s"] > 0
    assert res["frame_shape"] == [256, 320] and res["grid_shape"] == [384, 480]
    assert res["slm_shape"] == [96, 120] and res["target"] == "skimage.data.camera"
    i0, i1, j0, j1 = res["target_rect"]
    assert 0 <= i0 < i1 <= 384 and 0 <= j0 < j1 <= 480
    # the camera (256 x 320 px, 1 px per sample) sees |uy| < 128, |ux| < 160 only
    assert 192 - 128 <= i0 and i1 <= 192 + 128 and 240 - 160 <= j0 and j1 <= 240 + 160
    assert res["region_pixels"] == pytest.approx((i1 - i0) * (j1 - j0), rel=0.02)
    json.dumps(res, allow_nan=False)  # a plain JSON-ready dict


@pytest.mark.parametrize("case", ["shift 2 px", "wrong seed"])
def test_misalignment_is_detected(rig, case):
    bench, _, model, _ = rig
    if case == "shift 2 px":
        # measured: PSNR 22.2 dB, SSIM 0.47, correlation 0.47 ((1 - 2/k)^2 = 1/4 of the
        # amplitude still correlates); 1 px gave 27.6 dB / 0.85, 0.5 px 33.4 dB / 0.96
        res = _check(rig, MaskTransform(translation=(2.0, 0.0)))
        assert res["correlation"] < 0.6 and res["ssim"] < 0.6
    else:
        # measured: PSNR 19.4 dB, SSIM 0.08, correlation 0.00 (unrelated speckle)
        m = bench.hologram.mask
        other = MaskModel(m.slm_shape, m.slm_pitch_um, m.k, m.q, m.seed + 1, margin=m.margin)
        res = _check(rig, MaskTransform(), mask=corrected_mask(other, np.zeros((15, 2), int),
                                                               (3, 5))[0])
        assert abs(res["correlation"]) < 0.1 and res["ssim"] < 0.2
    assert res["psnr_db"] < 30.0  # vs > 45 dB aligned


def test_far_field_orientation_matches_the_camera_map():
    """An off-centre block of the target shows up where ``camera_map`` puts its far-field
    position, not at any mirror image, through a rotated, mirrored, scaled and offset
    camera: grid index -> u, ScatteringDisplay's far field, the fine display model and
    the camera affine agree (a sign flip anywhere moves the block)."""
    slm, k = (48, 60), 4
    grid = (slm[0] * k, slm[1] * k)
    cam = CameraMapping.from_params(shape=(120, 160), scale=0.9, rotation=0.35, flip_x=True,
                                    offset=(110.0, 40.0))
    image = np.full((40, 60), 0.05)
    image[4:14, 6:21] = 1.0  # top-left block (image rows down, columns right)
    target, rect = place_target(image, cam, grid)
    i0, i1, j0, j1 = rect
    h, w = i1 - i0, j1 - j0
    # the target is off-centre here (the offset camera sees an off-centre window)
    assert abs((i0 + i1) / 2 - grid[0] // 2) > 10 and abs((j0 + j1) / 2 - grid[1] // 2) > 10
    mask = random_binary_mask(slm, k, seed=2)
    phase = optimize_hologram(ScatteringDisplay(slm, k, mask=mask), target, steps=30).phase
    sim_mask = MaskModel(slm, 16.0, k, q=2, margin=0, bits=mask)
    frame = HolographicDisplayModel(sim_mask, camera=cam).render_phase(phase)

    def density(r0, r1, c0, c1):  # mean camera irradiance over a grid sub-rectangle
        reg = target_region(cam, grid, (r0, r1, c0, c1))
        assert reg.sum() > 20
        return frame[reg].mean()

    bi = (i0 + round(4 * h / 40), i0 + round(14 * h / 40))
    bj = (j0 + round(6 * w / 60), j0 + round(21 * w / 60))
    flip_i = (i0 + i1 - bi[1], i0 + i1 - bi[0])
    flip_j = (j0 + j1 - bj[1], j0 + j1 - bj[0])
    block = density(*bi, *bj)
    for mirror in ((*flip_i, *bj), (*bi, *flip_j), (*flip_i, *flip_j)):
        assert block > 4 * density(*mirror), mirror
    # and the block's light centroid is where the affine maps its far-field centre
    reg = target_region(cam, grid, (*bi, *bj))
    yy, xx = np.nonzero(reg)
    wgt = frame[reg]
    centroid = np.array([(wgt * xx).sum(), (wgt * yy).sum()]) / wgt.sum()
    u = ((bj[0] + bj[1] - 1) / 2 - grid[1] // 2, (bi[0] + bi[1] - 1) / 2 - grid[0] // 2)
    np.testing.assert_allclose(centroid, cam.to_camera(u), atol=1.5)


def test_place_target_fits_the_visible_far_field():
    cam = CameraMapping.from_params(shape=(120, 200), scale=1.3, rotation=0.2,
                                    offset=(80.0, 70.0))
    grid = (192, 240)
    target, (i0, i1, j0, j1) = place_target(np.ones((30, 60)), cam, grid)
    assert target.dtype == np.float32 and target.shape == grid
    assert (j1 - j0) / (i1 - i0) == pytest.approx(2.0, rel=0.1)  # aspect kept
    assert not target[:i0].any() and not target[i1:].any()
    assert not target[:, :j0].any() and not target[:, j1:].any()
    # every target sample is on the camera
    ii, jj = np.mgrid[i0:i1, j0:j1]
    c = cam.to_camera(np.stack([jj - grid[1] // 2, ii - grid[0] // 2], axis=-1))
    assert c[..., 0].min() >= 0 and c[..., 0].max() <= 199
    assert c[..., 1].min() >= 0 and c[..., 1].max() <= 119
    # ... and fills most of the camera's short side (rotation costs some)
    assert (i1 - i0) * 1.3 > 0.6 * 120
    region = target_region(cam, grid, (i0, i1, j0, j1))
    assert region.sum() == pytest.approx((i1 - i0) * (j1 - j0) * 1.3**2, rel=0.05)


def test_compare_frames_normalises_and_scores():
    rng = np.random.default_rng(0)
    sim = rng.exponential(1.0, (60, 80))
    region = np.zeros(sim.shape, bool)
    region[10:50, 10:70] = True
    same = compare_frames(7.0 * sim, sim, region)  # gain cancels
    assert same["psnr_db"] == float("inf") or same["psnr_db"] > 100
    assert same["ssim"] == pytest.approx(1.0) and same["correlation"] == pytest.approx(1.0)
    noisy = compare_frames(sim + rng.normal(0, 0.1, sim.shape), sim, region)
    # data range ~9 (exponential speckle), noise 0.1: about 20 log10(9 / 0.1) = 39 dB
    assert 30 < noisy["psnr_db"] < 45 and noisy["ssim"] < 1.0 and noisy["correlation"] > 0.98
    dark = compare_frames(np.zeros(sim.shape), sim, region)
    assert dark["psnr_db"] is None and dark["correlation"] is None
    with pytest.raises(PlanError, match="too few for SSIM"):
        compare_frames(sim, sim, np.zeros(sim.shape, bool))


class _NoCapture:
    """A meter that must not be reached: input errors are found before any capture."""

    def show(self, phase):
        raise AssertionError("showed a pattern despite bad input")

    def frame(self):
        raise AssertionError("captured despite bad input")


def test_bad_inputs_raise_clear_errors(rig):
    bench, meter, model, mask = rig
    cam, relay = bench.hologram.camera, bench.hologram.relay
    nm = _NoCapture()
    with pytest.raises(PlanError, match=r"corrected_mask has shape \(416, 512\).*\(384, 480\)"):
        hologram_check(nm, model, model.model, cam, relay)  # the model with its margin
    with pytest.raises(PlanError, match=r"corrected_mask: .*\+1/-1"):
        hologram_check(nm, model, (mask < 0).astype(np.float32), cam, relay)  # 0/1 floats
    with pytest.raises(PlanError, match="2-D grey image"):
        hologram_check(nm, model, mask, cam, relay, target=np.ones((8, 8, 3)))
    with pytest.raises(PlanError, match="steps"):
        hologram_check(nm, model, mask, cam, relay, steps=0)
    with pytest.raises(PlanError, match="relay must be a RelayModel"):
        hologram_check(nm, model, mask, cam, None)
    with pytest.raises(PlanError, match="meter must be a SpotMeter"):
        hologram_check(object(), model, mask, cam, relay)
    with pytest.raises(PlanError, match="sees only"):  # the camera looks elsewhere
        hologram_check(nm, model, mask, CameraMapping(shape=cam.shape, offset=(5000, 0)),
                       relay)
    # a mapping measured for another ROI: found once the frame arrives
    with pytest.raises(PlanError, match=r"camera frame \(256, 320\) differs"):
        hologram_check(meter, model, mask, CameraMapping(shape=(200, 320)), relay,
                       steps=2)
