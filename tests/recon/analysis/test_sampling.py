"""Tests of recon.analysis.sampling: depth grids, depth sensitivity, calibration spacing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from recon.analysis import (
    axial_step_eq510_per_mm,
    depth_sensitivity,
    inverse_depth_step_per_mm,
    inverse_depths,
    lateral_calibration_spacing_mm,
    scale_at_threshold,
    uniform_depths,
)
from recon.errors import ReconInputError

N = 129  # odd, so the array centre (64, 64) is a pixel


def gaussian(sigma: float = 8.0) -> np.ndarray:
    yy, xx = np.mgrid[:N, :N] - (N - 1) / 2.0
    return np.exp(-(yy**2 + xx**2) / (2 * sigma**2))


def speckle(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.standard_normal((N, N)), 1.5) + 1j * (
        ndimage.gaussian_filter(rng.standard_normal((N, N)), 1.5)
    )
    yy, xx = np.mgrid[:N, :N] - (N - 1) / 2.0
    return np.abs(field) ** 2 * (yy**2 + xx**2 <= 40**2)


# ----------------------------------------------------------------------------- depth grids


def test_uniform_depths_hand_values():
    z = uniform_depths(1.0, 3.0, 5)
    np.testing.assert_allclose(z, [1.0, 1.5, 2.0, 2.5, 3.0])
    assert z.dtype == np.float64


def test_inverse_depths_with_n_hand_values_and_constant_step():
    # 1/z = 1, 0.75, 0.5, 0.25
    np.testing.assert_allclose(inverse_depths(1.0, 4.0, n=4), [1.0, 4 / 3, 2.0, 4.0])
    z = inverse_depths(7.3, 2300.0, n=128)
    assert z[0] == 7.3 and z[-1] == 2300.0
    assert np.all(np.diff(z) > 0)
    steps = -np.diff(1.0 / z)
    np.testing.assert_allclose(steps, steps[0], rtol=1e-9)
    assert steps[0] == pytest.approx((1 / 7.3 - 1 / 2300.0) / 127)


def test_inverse_depths_with_c_whole_number_of_steps_ends_exactly():
    np.testing.assert_allclose(inverse_depths(1.0, 4.0, c_per_mm=0.25), [1.0, 4 / 3, 2.0, 4.0])
    # 1/z_min - 1/z_max = 0.3 = 3 steps of 0.1 despite rounding in 0.1
    z = inverse_depths(1 / 0.6, 1 / 0.3, c_per_mm=0.1)
    assert z.size == 4 and z[-1] == 1 / 0.3


def test_inverse_depths_with_c_appends_z_max_with_a_shorter_last_step():
    z = inverse_depths(1.0, 5.0, c_per_mm=0.25)
    np.testing.assert_allclose(z, [1.0, 4 / 3, 2.0, 4.0, 5.0])
    c = 0.0333  # Eq. 5.10 for the Sec. 6.4 microscope, 1/mm
    z = inverse_depths(1.7, 10.0, c_per_mm=c)
    steps = -np.diff(1.0 / z)
    np.testing.assert_allclose(steps[:-1], c, rtol=1e-9)
    assert 0 < steps[-1] <= c
    assert z[0] == 1.7 and z[-1] == 10.0 and np.all(np.diff(z) > 0)


def test_inverse_depths_refusals():
    with pytest.raises(ReconInputError, match="exactly one"):
        inverse_depths(1.0, 2.0)
    with pytest.raises(ReconInputError, match="exactly one"):
        inverse_depths(1.0, 2.0, n=3, c_per_mm=0.1)
    with pytest.raises(ReconInputError, match="c_per_mm"):
        inverse_depths(1.0, 2.0, c_per_mm=0.0)
    with pytest.raises(ReconInputError, match="smaller than"):
        inverse_depths(2.0, 1.0, n=3)
    with pytest.raises(ReconInputError, match="z_min_mm"):
        inverse_depths(0.0, 1.0, n=3)
    with pytest.raises(ReconInputError, match="n must"):
        inverse_depths(1.0, 2.0, n=1)
    with pytest.raises(ReconInputError, match="larger step"):
        inverse_depths(1.0, 2.0, c_per_mm=1e-9)
    with pytest.raises(ReconInputError, match="n must"):
        uniform_depths(1.0, 2.0, 2.5)


def test_axial_step_eq510_hand_check():
    # Sec. 6.4: lambda = 520 nm, p = 250 um -> 33 m^-1
    c = axial_step_eq510_per_mm(520.0, 250.0)
    assert c == pytest.approx(4 * 520e-6 / 0.25**2)
    assert c == pytest.approx(0.0333, abs=1e-4)
    assert axial_step_eq510_per_mm(520.0, 500.0) == pytest.approx(c / 4)
    # "calibrate every 100 um axially ... satisfies the condition for z = 1.7 mm or further"
    assert 1 / 1.7 - 1 / 1.8 <= c
    assert 1 / 1.6 - 1 / 1.7 > c
    with pytest.raises(ReconInputError, match="wavelength_nm"):
        axial_step_eq510_per_mm(-520.0, 250.0)


# ----------------------------------------------------------------------------- depth of field


def test_depth_sensitivity_of_gaussian_matches_closed_form():
    # h(s x) of a 2D Gaussian of width sigma has width sigma / s;
    # <g_a, g_b> / (|g_a| |g_b|) = 2 a b / (a^2 + b^2)  ->  mu(s) = 2 s / (1 + s^2)
    s = np.array([1.0, 1.1, 1.25, 1.5, 1 / 1.5, 2.0])
    mu = depth_sensitivity(gaussian(), s)
    assert mu.shape == s.shape and mu.dtype == np.float64
    np.testing.assert_allclose(mu, 2 * s / (1 + s**2), atol=2e-3)


def test_depth_sensitivity_of_speckle_is_one_at_unit_scale_and_decreases():
    s = np.array([1.0, 1.005, 1.01, 1.02, 1.05, 1.1, 1.2])
    mu = depth_sensitivity(speckle(), s)
    assert mu[0] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(mu) < 0)
    assert mu[-1] < 0.6
    # roughly symmetric in s <-> 1/s
    assert depth_sensitivity(speckle(), 1 / 1.05)[0] == pytest.approx(mu[4], abs=0.03)


def test_depth_sensitivity_is_about_the_array_centre():
    # a blob at the centre is the fixed point of the scaling, an off-centre blob moves away
    centred = depth_sensitivity(gaussian(3.0), [1.5])[0]
    off = depth_sensitivity(np.roll(gaussian(3.0), 30, axis=1), [1.5])[0]
    assert centred == pytest.approx(2 * 1.5 / (1 + 1.5**2), abs=5e-3)
    assert off < 0.1


def test_depth_sensitivity_empty_copy_is_zero_and_refusals():
    corner = np.zeros((N, N))
    corner[0, 0] = 1.0
    assert depth_sensitivity(corner, [0.5])[0] == 0.0
    with pytest.raises(ReconInputError, match="scales"):
        depth_sensitivity(gaussian(), [1.0, 0.0])
    with pytest.raises(ReconInputError, match="all zero"):
        depth_sensitivity(np.zeros((8, 8)), [1.1])
    with pytest.raises(ReconInputError, match="NaN"):
        depth_sensitivity(np.full((8, 8), np.nan), [1.1])


def test_scale_at_threshold_gaussian_closed_form():
    # 2 s / (1 + s^2) = 0.9  ->  s = (1 + sqrt(1 - 0.81)) / 0.9 = 1.5954
    s_star = scale_at_threshold(gaussian(), 0.9)
    assert s_star == pytest.approx((1 + math.sqrt(1 - 0.81)) / 0.9, rel=3e-3)


def test_scale_at_threshold_speckle_hits_threshold():
    psf = speckle(1)
    s_star = scale_at_threshold(psf)
    assert 1.0 < s_star < 1.2
    assert depth_sensitivity(psf, [s_star])[0] == pytest.approx(0.8, abs=1e-6)
    assert scale_at_threshold(psf, 0.5) > s_star


def test_scale_at_threshold_refusals():
    # a smooth Gaussian only reaches mu = 0.923 at s = 1.5
    with pytest.raises(ReconInputError, match="stays above"):
        scale_at_threshold(gaussian(), 0.9, max_scale=1.5)
    with pytest.raises(ReconInputError, match="threshold"):
        scale_at_threshold(gaussian(), 1.2)
    with pytest.raises(ReconInputError, match="max_scale"):
        scale_at_threshold(gaussian(), max_scale=1.0)


def test_inverse_depth_step_formula_and_sign():
    psf = gaussian()
    d, z = 3.8, 20.0
    c = inverse_depth_step_per_mm(psf, d, z, 0.9)
    s_star = scale_at_threshold(psf, 0.9)
    assert c == pytest.approx((s_star - 1) * (1 / d + 1 / z), rel=1e-9)
    # the neighbouring depth is nearer, and its caustics are magnified by s* (Eq. 5.2)
    z_near = 1 / (1 / z + c)
    assert z_near < z
    assert (1 + d / z_near) / (1 + d / z) == pytest.approx(s_star, rel=1e-9)
    with pytest.raises(ReconInputError, match="d_mm"):
        inverse_depth_step_per_mm(psf, 0.0, z)


# ----------------------------------------------------------------------------- lateral spacing


def test_lateral_spacing_small_angle_limit_is_gaussian_nyquist():
    # f~ ~ exp(-x^2 / (2 sx^2)), |F| ~ exp(-2 pi^2 sx^2 f^2): 1e-2 at f = sqrt(ln 100 / 2)/(pi sx)
    z, sigma_deg = 1.7, 0.5
    sx = z * math.radians(sigma_deg)
    expected = 1 / (2 * math.sqrt(math.log(100) / 2) / (math.pi * sx))
    assert expected == pytest.approx(1.0352 * sx, rel=1e-4)
    assert lateral_calibration_spacing_mm(sigma_deg, z) == pytest.approx(expected, rel=2e-3)
    expected_1e3 = 1 / (2 * math.sqrt(math.log(1e3) / 2) / (math.pi * sx))
    got = lateral_calibration_spacing_mm(sigma_deg, z, rel_threshold=1e-3)
    assert got == pytest.approx(expected_1e3, rel=2e-3)


def test_lateral_spacing_dissertation_hand_check():
    # Fig. 5.3 / Sec. 6.4: sigma = 13 deg, z = 1.7 mm -> "0.4 mm"; the atan of Eq. 5.9
    # fattens the tails, so the result (0.383 mm) is 4 % below the small-angle 0.399 mm
    spacing = lateral_calibration_spacing_mm(13.0, 1.7)
    assert spacing == pytest.approx(0.4, rel=0.05)
    assert spacing == pytest.approx(0.3826, rel=5e-3)
    # f~ depends on x / z only, so the spacing is proportional to z
    assert lateral_calibration_spacing_mm(13.0, 3.4) == pytest.approx(2 * spacing, rel=1e-3)


def test_lateral_spacing_spectrum_at_f_max_is_the_threshold():
    # independent check of the Fourier conventions: integrate F(f) = int f~(x) cos(2 pi f x)
    z, sigma = 1.7, math.radians(13.0)
    f_max = 1 / (2 * lateral_calibration_spacing_mm(13.0, z))
    x = np.linspace(-100 * z, 100 * z, 400_001)
    ftilde = np.exp(-(np.arctan(x / z) ** 2) / (2 * sigma**2))
    dc = np.trapezoid(ftilde, x)
    at_f = np.trapezoid(ftilde * np.cos(2 * np.pi * f_max * x), x)
    assert at_f / dc == pytest.approx(1e-2, rel=0.02)


def test_lateral_spacing_refusals():
    with pytest.raises(ReconInputError, match="89 deg"):
        lateral_calibration_spacing_mm(45.0, 1.7)
    with pytest.raises(ReconInputError, match="rel_threshold"):
        lateral_calibration_spacing_mm(13.0, 1.7, rel_threshold=1.5)
    with pytest.raises(ReconInputError, match="z_mm"):
        lateral_calibration_spacing_mm(13.0, -1.0)
    with pytest.raises(ReconInputError, match="falloff_sigma_deg"):
        lateral_calibration_spacing_mm(float("nan"), 1.7)
