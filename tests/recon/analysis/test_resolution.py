"""Tests of recon.analysis.resolution: autocorrelation width, inner-product predictor, DoF."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from recon.analysis.psf import inner_product
from recon.analysis.resolution import (
    LateralResolution,
    autocorrelation,
    axial_inner_product_scale,
    depth_of_field_mm,
    hyperfocal_distance_mm,
    lateral_inner_product_resolution_px,
    lateral_resolution_deg,
    lateral_resolution_object_mm,
    lateral_resolution_px,
)
from recon.analysis.sampling import inverse_depth_step_per_mm, scale_at_threshold
from recon.errors import ReconInputError

N = 129


def gaussian(sigma_y: float, sigma_x: float | None = None) -> np.ndarray:
    sigma_x = sigma_y if sigma_x is None else sigma_x
    yy, xx = np.mgrid[:N, :N] - (N - 1) / 2.0
    return np.exp(-(yy**2) / (2 * sigma_y**2) - xx**2 / (2 * sigma_x**2))


def speckle(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.standard_normal((N, N)), 1.5) + 1j * (
        ndimage.gaussian_filter(rng.standard_normal((N, N)), 1.5)
    )
    yy, xx = np.mgrid[:N, :N] - (N - 1) / 2.0
    return np.abs(field) ** 2 * (yy**2 + xx**2 <= 40**2)


def test_autocorrelation_peak_one_at_centre():
    ac = autocorrelation(speckle())
    assert ac.shape == (2 * N - 1, 2 * N - 1) and ac.dtype == np.float64
    assert ac[N - 1, N - 1] == pytest.approx(1.0, abs=1e-12)
    assert ac.max() == pytest.approx(1.0, abs=1e-12)


def test_autocorrelation_of_gaussian_is_gaussian_sigma_sqrt2():
    s = 5.0
    ac = autocorrelation(gaussian(s))
    lags = np.arange(-(N - 1), N)
    np.testing.assert_allclose(
        ac[N - 1], np.exp(-(lags**2) / (2 * (s * math.sqrt(2)) ** 2)), atol=1e-9
    )


@pytest.mark.parametrize("sigma", [2.0, 5.0, 8.0])
def test_lateral_resolution_of_gaussian_hand_value(sigma):
    # autocorrelation sigma s sqrt(2); 70 % at s sqrt(2) sqrt(2 ln(1/0.7)) = 1.19445 s
    expected = sigma * math.sqrt(2) * math.sqrt(2 * math.log(1 / 0.7))
    res = lateral_resolution_px(gaussian(sigma))
    assert isinstance(res, LateralResolution)
    assert res.x_px == pytest.approx(expected, rel=1e-8)
    assert res.y_px == pytest.approx(expected, rel=1e-8)
    assert expected == pytest.approx(1.19445 * sigma, rel=1e-5)


def test_lateral_resolution_is_per_axis_and_level():
    res = lateral_resolution_px(gaussian(3.0, 6.0))
    k = math.sqrt(2) * math.sqrt(2 * math.log(1 / 0.7))
    assert res.y_px == pytest.approx(3.0 * k, rel=1e-8)
    assert res.x_px == pytest.approx(6.0 * k, rel=1e-8)
    half = lateral_resolution_px(gaussian(4.0), level=0.5)
    assert half.x_px == pytest.approx(4.0 * math.sqrt(2) * math.sqrt(2 * math.log(2)), rel=1e-8)


def test_inner_product_resolution_of_sparse_random_pattern_is_below_a_pixel():
    # a binary pattern with density p: <h, h shifted 1 px> / |h|^2 ~ p (= 0.05), far below 0.8
    rng = np.random.default_rng(1)
    h = (rng.random((128, 128)) < 0.05).astype(float)
    padded = np.pad(h, ((0, 128), (0, 128)))
    ip1 = inner_product(padded, np.roll(padded, 1, axis=1))
    assert ip1 == pytest.approx(0.05, abs=0.01)
    res = lateral_inner_product_resolution_px(h)
    assert 0 < res.x_px < 1 and 0 < res.y_px < 1


def test_inner_product_resolution_equals_inner_product_of_shifted_copies():
    h = speckle(2)
    res = lateral_inner_product_resolution_px(h, threshold=0.8)
    # a Fourier shift on a zero-padded frame by the returned (fractional) shift
    padded = np.pad(h, ((0, N), (0, N)))
    spec = np.fft.fft2(padded)
    fx = np.fft.fftfreq(padded.shape[1])
    shifted = np.fft.ifft2(spec * np.exp(-2j * np.pi * fx[None, :] * res.x_px)).real
    # (band-limited interpolation depends slightly on the padded length: 258 here)
    assert inner_product(padded, shifted) == pytest.approx(0.8, abs=1e-4)
    # at integer shifts it brackets: above 0.8 before, below after
    t = math.floor(res.x_px)
    assert inner_product(padded, np.roll(padded, t, axis=1)) > 0.8
    assert inner_product(padded, np.roll(padded, t + 1, axis=1)) <= 0.8
    # same curve as the autocorrelation width at level 0.8
    assert res == lateral_resolution_px(h, level=0.8)
    assert res.x_px < lateral_resolution_px(h).x_px  # 0.8 is crossed before 0.7


def test_object_space_conversion_m_equals_d_over_z():
    # 2 px of 5 um at d = 5 mm, z = 20 mm: 10 um on the sensor, m = 1/4 -> 40 um
    assert lateral_resolution_object_mm(2.0, 0.005, 5.0, 20.0) == pytest.approx(0.04)
    out = lateral_resolution_object_mm(LateralResolution(2.0, 3.0), 0.005, 5.0, 20.0)
    np.testing.assert_allclose(out, [0.04, 0.06])
    z = np.array([10.0, 20.0, 40.0])
    np.testing.assert_allclose(lateral_resolution_object_mm(1.0, 0.005, 5.0, z), 0.001 * z)
    # Sec. 3.3: 0.16 deg at d = 8.8 mm is about 3.8 px of 6.5 um
    assert lateral_resolution_deg(3.78, 0.0065, 8.8) == pytest.approx(0.16, abs=0.001)
    with pytest.raises(ReconInputError, match="z_mm"):
        lateral_resolution_object_mm(1.0, 0.005, 5.0, 0.0)
    with pytest.raises(ReconInputError, match="res_px"):
        lateral_resolution_object_mm(-1.0, 0.005, 5.0, 1.0)
    with pytest.raises(ReconInputError, match="pitch_mm"):
        lateral_resolution_object_mm(1.0, 0.0, 5.0, 1.0)


def test_axial_scale_is_scale_at_threshold():
    h = speckle(3)
    assert axial_inner_product_scale(h) == scale_at_threshold(h, 0.8)


def test_hyperfocal_and_depth_of_field_from_the_scaling_law():
    h = speckle(4)
    d, zp = 5.0, 30.0
    s_star = scale_at_threshold(h, 0.8)
    z_h = hyperfocal_distance_mm(h, d_mm=d, psf_z_mm=zp)
    assert z_h == pytest.approx(d / (s_star - 1.0), rel=1e-9)
    c = inverse_depth_step_per_mm(h, d, zp)
    assert z_h == pytest.approx((1 + d / zp) / c, rel=1e-9)
    # at z_H the PSF is exactly s* times the PSF at infinity: 1 + d/z_H = s*
    assert 1 + d / z_h == pytest.approx(s_star, rel=1e-9)
    z = np.array([10.0, 0.25 * z_h, 0.5 * z_h, 0.999 * z_h, z_h * 1.001, 2 * z_h])
    far = depth_of_field_mm(h, z, d_mm=d, psf_z_mm=zp)
    near = depth_of_field_mm(h, z, d_mm=d, psf_z_mm=zp, side="near")
    assert np.all(np.isfinite(far[:4])) and np.all(np.isinf(far[4:]))
    assert np.all(np.diff(far[:4]) > 0) and np.all(near > 0) and np.all(near[:4] < far[:4])
    # the neighbours are exactly one resolvable scale s* apart
    u = 1 + d / z[:4]
    np.testing.assert_allclose(u / (1 + d / (z[:4] + far[:4])), s_star, rtol=1e-9)
    np.testing.assert_allclose((1 + d / (z - near)) / (1 + d / z), s_star, rtol=1e-9)
    assert depth_of_field_mm(h, 10.0, d_mm=d, psf_z_mm=zp).shape == (1,)


def test_refusals():
    with pytest.raises(ReconInputError, match="all zero"):
        autocorrelation(np.zeros((8, 8)))
    with pytest.raises(ReconInputError, match="level"):
        lateral_resolution_px(gaussian(3.0), level=1.0)
    with pytest.raises(ReconInputError, match="threshold"):
        lateral_inner_product_resolution_px(gaussian(3.0), threshold=0.0)
    with pytest.raises(ReconInputError, match="stays above"):
        # flat: the autocorrelation line is a triangle, 1/16 at the last lag
        lateral_resolution_px(np.ones((16, 16)), level=0.05)
    with pytest.raises(ReconInputError, match="side"):
        depth_of_field_mm(speckle(), 10.0, d_mm=5.0, psf_z_mm=30.0, side="both")
    with pytest.raises(ReconInputError, match="psf_z_mm"):
        hyperfocal_distance_mm(speckle(), d_mm=5.0, psf_z_mm=-1.0)
    with pytest.raises(ReconInputError, match="2D"):
        lateral_resolution_px(np.ones(5))
