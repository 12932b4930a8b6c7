"""Tests for recon.simulate (centring, noise) and recon.metrics (PSNR/SSIM)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from recon.errors import ReconInputError
from recon.metrics import fit_gain, psnr, ssim
from recon.operators import ConvolutionOperator
from recon.preprocess import box_bin
from recon.scenes import SCENES, load_scene
from recon.simulate import Simulation, add_camera_noise, simulate_measurement

FINE = (48, 64)  # coarse 24 x 32 at bin 2


def _delta_psf(shape=FINE):
    h = np.zeros(shape, np.float32)
    h[shape[0] // 2, shape[1] // 2] = 1.0
    return h


def _caustic_psf(shape=FINE, seed=0):
    """Smooth random caustic-like PSF (a few blurred bright points), unit sum."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    h = np.zeros(shape, np.float64)
    r = rng.integers(shape[0] // 4, 3 * shape[0] // 4, 25)
    c = rng.integers(shape[1] // 4, 3 * shape[1] // 4, 25)
    h[r, c] = rng.random(25) + 0.5
    h = gaussian_filter(h, 2.0)
    return (h / h.sum()).astype(np.float32)


# ----------------------------------------------------------------------------- centring

def test_delta_psf_measurement_is_binned_scene_at_truth_position():
    """With a PSF that is a point at the sensor centre the measurement is the scene;
    after binning it must coincide with the truth in the coarse sensor FoV, and the
    coarse operator must map the truth onto the same image."""
    rng = np.random.default_rng(1)
    scene = rng.random(FINE).astype(np.float32)
    sim = simulate_measurement(_delta_psf(), scene, bin_factor=2, photons=1e6,
                               read_noise_e=0.0)
    coarse_op = ConvolutionOperator(box_bin(_delta_psf(), 2) * 4)
    assert sim.truth.shape == coarse_op.padded_shape
    fov = sim.truth[coarse_op.crop]
    np.testing.assert_allclose(fov, box_bin(scene, 2), rtol=1e-6)
    # outside the FoV the truth is zero
    assert sim.truth.sum() == pytest.approx(fov.sum(), rel=1e-6)
    np.testing.assert_allclose(sim.b_clean / sim.electrons_per_unit, fov, rtol=1e-4,
                               atol=1e-5)
    np.testing.assert_allclose(coarse_op.forward(sim.truth), fov, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("corner", [(6, 10), (15, 4), (11, 25)])
def test_small_bright_square_lines_up_with_coarse_model(corner):
    """A bin-aligned 2x2 bright square on the fine grid is one bright coarse truth
    pixel, and the binned fine rendering matches the coarse model of that truth best
    at zero shift (no half-grid or one-pixel offset between the grids)."""
    k, j = corner
    psf_f = _caustic_psf()
    scene = np.zeros(FINE, np.float32)
    scene[2 * k:2 * k + 2, 2 * j:2 * j + 2] = 1.0
    sim = simulate_measurement(psf_f, scene, bin_factor=2, photons=1e6, read_noise_e=0.0)
    psf_c = box_bin(psf_f, 2)
    op = ConvolutionOperator(psf_c / psf_c.sum())  # unit sum, like the fine PSF
    fov = sim.truth[op.crop]
    assert np.unravel_index(np.argmax(fov), fov.shape) == (k, j)
    assert fov[k, j] == pytest.approx(1.0)
    assert np.count_nonzero(sim.truth) == 1

    clean = sim.b_clean / sim.electrons_per_unit
    errors = {}
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            model = op.forward(np.roll(sim.truth, (dy, dx), axis=(0, 1)))
            errors[dy, dx] = np.linalg.norm(model - clean) / np.linalg.norm(clean)
    # zero shift is best; what remains is the square's quarter-coarse-pixel centroid
    # offset inside its block, which no coarse model can represent
    assert min(errors, key=errors.get) == (0, 0)
    assert errors[0, 0] < 0.3
    assert errors[0, 0] < 0.7 * min(v for key, v in errors.items() if key != (0, 0))


def test_block_constant_scene_is_exact_with_the_effective_coarse_psf():
    """For a scene constant on bin-aligned 2x2 blocks the binned rendering equals, to
    float precision, the coarse model of the truth with the effective PSF
    box_bin(h_f + shifts by (0,1), (1,0), (1,1)): any offset between the fine
    placement and the coarse truth grid (even one fine pixel) breaks this."""
    psf_f = _caustic_psf()
    g = sum(np.roll(psf_f.astype(np.float64), (r, c), axis=(0, 1))
            for r in (0, 1) for c in (0, 1))
    h_eff = box_bin(g, 2)
    rng = np.random.default_rng(4)
    coarse_scene = rng.random((FINE[0] // 2, FINE[1] // 2))
    scene = np.kron(coarse_scene, np.ones((2, 2))).astype(np.float32)
    sim = simulate_measurement(psf_f, scene, bin_factor=2, photons=1e6, read_noise_e=0.0)
    op = ConvolutionOperator(h_eff)
    np.testing.assert_allclose(sim.truth[op.crop], coarse_scene, rtol=1e-6)
    model = op.forward(sim.truth)
    clean = sim.b_clean / sim.electrons_per_unit
    assert np.linalg.norm(model - clean) / np.linalg.norm(clean) < 1e-5
    for shift in ((0, 1), (1, 0)):
        shifted = op.forward(np.roll(sim.truth, shift, axis=(0, 1)))
        assert np.linalg.norm(shifted - clean) / np.linalg.norm(clean) > 0.05


def test_bin_factor_one_is_the_coarse_model_exactly():
    psf = _caustic_psf()
    scene = np.random.default_rng(2).random(FINE).astype(np.float32)
    sim = simulate_measurement(psf, scene, bin_factor=1, photons=1e6, read_noise_e=0.0)
    op = ConvolutionOperator(psf)
    np.testing.assert_allclose(sim.b_clean / sim.electrons_per_unit, op.forward(sim.truth),
                               rtol=1e-4, atol=1e-6)


# ----------------------------------------------------------------------------- noise

def test_noise_statistics_poisson_and_read_noise():
    """Flat scene through a point PSF: every pixel collects `photons` electrons, so
    mean ~ photons and variance ~ photons + read_noise^2; SNR as stated."""
    shape = (160, 200)
    scene = np.ones(shape, np.float32)
    photons, read = 100.0, 3.0
    sim = simulate_measurement(_delta_psf(shape), scene, bin_factor=2, photons=photons,
                               read_noise_e=read, seed=3)
    assert isinstance(sim, Simulation)
    assert sim.b.dtype == np.float32 and sim.b.shape == (80, 100)
    assert float(sim.b_clean.max()) == pytest.approx(photons, rel=1e-5)
    np.testing.assert_allclose(sim.b_clean, photons, rtol=1e-4)
    noise = sim.b.astype(np.float64) - sim.b_clean
    assert abs(noise.mean()) < 4 * math.sqrt((photons + read**2) / noise.size)
    assert noise.var() == pytest.approx(photons + read**2, rel=0.08)
    expected_snr = 10 * math.log10(photons**2 / np.mean(noise**2))
    assert sim.snr_db == pytest.approx(expected_snr, abs=1e-4)  # float32 b
    assert sim.snr == {"photons": photons, "read_noise_e": read, "snr_db": sim.snr_db}
    assert sim.snr_db == pytest.approx(10 * math.log10(photons**2 / (photons + read**2)),
                                       abs=0.4)


def test_pure_poisson_variance_equals_mean_and_seed_reproducible():
    shape = (160, 200)
    sim = simulate_measurement(_delta_psf(shape), np.ones(shape, np.float32),
                               photons=400.0, read_noise_e=0.0, seed=7)
    b = sim.b.astype(np.float64)
    assert np.all(b == np.round(b))  # counts
    assert b.var() == pytest.approx(b.mean(), rel=0.08)
    again = simulate_measurement(_delta_psf(shape), np.ones(shape, np.float32),
                                 photons=400.0, read_noise_e=0.0, seed=7)
    np.testing.assert_array_equal(again.b, sim.b)


def test_add_camera_noise_scales_and_draws_from_one_generator():
    img = np.array([[0.0, 1.0], [2.0, 4.0]])
    noisy, clean, gain, snr_db = add_camera_noise(img, 1000.0, 0.0, seed=5)
    assert gain == 250.0 and clean.max() == 1000.0
    np.testing.assert_array_equal(noisy, np.random.default_rng(5).poisson(clean))
    assert noisy[0, 0] == 0.0 and math.isfinite(snr_db)
    rng = np.random.default_rng(7)
    again = add_camera_noise(img, 1000.0, 2.0, rng)[0]
    ref = np.random.default_rng(7)
    np.testing.assert_array_equal(again, ref.poisson(clean) + ref.normal(0.0, 2.0, img.shape))
    with pytest.raises(ReconInputError, match="all-zero"):
        add_camera_noise(np.zeros((2, 2)), 10.0, 1.0)
    with pytest.raises(ReconInputError, match="non-negative"):
        add_camera_noise(-img, 10.0, 1.0)
    with pytest.raises(ReconInputError, match="photons"):
        add_camera_noise(img, 0.0, 1.0)


def test_unpacks_as_b_truth():
    b, truth = simulate_measurement(_caustic_psf(), np.ones(FINE, np.float32))
    assert b.shape == (24, 32) and truth.shape == (48, 64)
    assert b.dtype == np.float32 and truth.dtype == np.float32


@pytest.mark.parametrize("kwargs", [{"photons": 0.0}, {"read_noise_e": -1.0},
                                    {"bin_factor": 0}, {"bin_factor": 2.0}])
def test_invalid_parameters(kwargs):
    with pytest.raises(ReconInputError):
        simulate_measurement(_caustic_psf(), np.ones(FINE, np.float32), **kwargs)


def test_scene_shape_mismatch_refused():
    with pytest.raises(ReconInputError, match="load_scene"):
        simulate_measurement(_caustic_psf(), np.ones((10, 10), np.float32))


@pytest.mark.parametrize("name", SCENES)
def test_bundled_scenes_load_offline(name):
    img = load_scene(name, (30, 40))
    assert img.shape == (30, 40) and img.dtype == np.float32
    assert 0.0 <= img.min() and img.max() <= 1.0 and img.std() > 0.01


# ----------------------------------------------------------------------------- metrics

def _pair(seed=0):
    rng = np.random.default_rng(seed)
    truth = load_scene("camera", (64, 80)).astype(np.float64)
    est = truth + 0.05 * rng.standard_normal(truth.shape)
    return est, truth


def test_psnr_and_ssim_gain_invariant():
    est, truth = _pair()
    for gain in (1e-3, 0.5, 7.0):
        assert psnr(gain * est, truth) == pytest.approx(psnr(est, truth), abs=1e-9)
        assert ssim(gain * est, truth) == pytest.approx(ssim(est, truth), abs=1e-9)


def test_metrics_match_skimage_after_gain_fit():
    est, truth = _pair(1)
    g = fit_gain(est, truth)
    assert g == pytest.approx(np.vdot(est, truth) / np.vdot(est, est))
    rng = float(truth.max() - truth.min())
    assert psnr(est, truth) == pytest.approx(
        peak_signal_noise_ratio(truth, g * est, data_range=rng))
    assert ssim(est, truth) == pytest.approx(
        structural_similarity(truth, g * est, data_range=rng))


def test_identical_images():
    _, truth = _pair()
    assert psnr(truth, truth) == math.inf
    assert ssim(truth, truth) == pytest.approx(1.0)
    assert psnr(3 * truth, truth) > 100  # identical up to the gain
    assert ssim(3 * truth, truth) == pytest.approx(1.0)


def test_offset_is_not_fitted():
    _, truth = _pair()
    assert psnr(truth + 0.2, truth) < 25


@pytest.mark.parametrize("bad", [np.zeros((8, 8, 3)), np.zeros((9, 9))])
def test_metrics_refuse_bad_shapes(bad):
    with pytest.raises(ReconInputError):
        psnr(bad, np.ones((8, 8)))


def test_metrics_refuse_constant_truth_and_nan():
    with pytest.raises(ReconInputError, match="constant"):
        psnr(np.ones((8, 8)), np.ones((8, 8)))
    est = np.ones((8, 8))
    est[0, 0] = np.nan
    with pytest.raises(ReconInputError):
        ssim(est, np.arange(64.0).reshape(8, 8))


def test_register_truth_finds_the_shift_that_matches():
    from recon.metrics import register_truth

    rng = np.random.default_rng(3)
    truth = np.zeros((40, 50))
    truth[10:30, 12:40] = rng.random((20, 28))
    estimate = 2.0 * np.roll(truth, (1, -2), axis=(0, 1))
    shift, shifted = register_truth(estimate, truth)
    assert shift == (1, -2) and np.array_equal(shifted, np.roll(truth, (1, -2), axis=(0, 1)))
    assert register_truth(estimate, truth, max_shift=1)[0] != (1, -2)
