"""Tests of recon.analysis.angular: Gaussian fall-off fit and angular field of view."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from recon.analysis import FalloffFit, fit_gaussian_falloff, fov_half_angle_deg
from recon.errors import ReconInputError

SQRT_2LN5 = math.sqrt(2 * math.log(5))  # 1.794: where a Gaussian is 20 % of its peak


def gauss(theta, amplitude, sigma, center=0.0):
    return amplitude * np.exp(-((np.asarray(theta, float) - center) ** 2) / (2 * sigma**2))


# ----------------------------------------------------------------------------- fall-off fit


def test_fit_exact_gaussian_and_hand_computed_crossing():
    theta = np.array([0.0, 10.0, 20.0, 30.0])
    y = gauss(theta, 1.0, 13.0)  # 1, 0.7439, 0.3063, 0.0698
    fit = fit_gaussian_falloff(theta, y)
    assert isinstance(fit, FalloffFit)
    assert fit.sigma_deg == pytest.approx(13.0, rel=1e-6)
    assert fit.amplitude == pytest.approx(1.0, rel=1e-6)
    assert fit.cutoff_deg == pytest.approx(13.0 * SQRT_2LN5, rel=1e-6)  # 23.32 deg
    # data cross 0.2 between 20 and 30 deg: 20 + (0.3063 - 0.2) / (0.3063 - 0.0698) * 10
    y20, y30 = math.exp(-400 / 338), math.exp(-900 / 338)
    assert fit.cutoff_measured_deg == pytest.approx(20 + (y20 - 0.2) / (y20 - y30) * 10, rel=1e-6)
    assert fit.cutoff_measured_deg == pytest.approx(24.49, abs=0.01)
    assert fit.rms_residual < 1e-8
    with pytest.raises(dataclasses.FrozenInstanceError):
        fit.sigma_deg = 1.0  # type: ignore[misc]


@pytest.mark.parametrize("seed", range(5))
def test_fit_recovers_sigma_from_noisy_two_sided_data(seed):
    # Fig. 5.3a: sigma = 13 deg; +/-60 deg every 2 deg, noise 1 % of the peak
    rng = np.random.default_rng(seed)
    theta = np.arange(-60.0, 61.0, 2.0)
    y = gauss(theta, 1000.0, 13.0) + rng.normal(0.0, 10.0, theta.size)
    fit = fit_gaussian_falloff(theta, y)
    assert fit.sigma_deg == pytest.approx(13.0, rel=0.02)
    assert fit.amplitude == pytest.approx(1000.0, rel=0.02)
    assert fit.cutoff_deg == pytest.approx(13.0 * SQRT_2LN5, rel=0.02)
    assert fit.cutoff_measured_deg == pytest.approx(fit.cutoff_deg, abs=1.0)
    assert fit.rms_residual == pytest.approx(10.0, rel=0.35)


def test_fit_with_center_offset():
    theta = np.arange(-30.0, 31.0, 1.0) + 5.0
    y = gauss(theta, 3.0, 10.0, center=5.0)
    fit = fit_gaussian_falloff(theta, y, center_deg=5.0)
    assert fit.sigma_deg == pytest.approx(10.0, rel=1e-6)
    assert fit.amplitude == pytest.approx(3.0, rel=1e-6)
    # the crossing is measured from the centre, not from 0
    assert fit.cutoff_measured_deg == pytest.approx(10.0 * SQRT_2LN5, abs=0.05)
    # a wrong centre gives a worse fit
    assert fit_gaussian_falloff(theta, y).rms_residual > 0.05


def test_fit_measured_cutoff_nan_when_data_never_fall_to_20_percent():
    theta = np.linspace(-10.0, 10.0, 11)
    fit = fit_gaussian_falloff(theta, gauss(theta, 1.0, 13.0))
    assert fit.sigma_deg == pytest.approx(13.0, rel=1e-6)
    assert math.isnan(fit.cutoff_measured_deg)


@pytest.mark.parametrize(
    ("angles", "intensity", "match"),
    [
        ([0.0, 10.0], [1.0, 0.5], "at least 3"),
        ([0.0, 0.0, 10.0], [1.0, 1.0, 0.5], "at least 3"),
        ([0.0, 10.0, 20.0], [1.0, np.nan, 0.1], "NaN"),
        ([0.0, 10.0, 20.0], [0.0, 0.0, 0.0], "no positive"),
        ([0.0, 10.0, 20.0], [1.0, 0.5], "one intensity per angle"),
        ([[0.0, 10.0, 20.0]], [[1.0, 0.5, 0.1]], "1D"),
        (np.linspace(-5, 5, 11), np.ones(11), "larger angles"),
    ],
)
def test_fit_refusals(angles, intensity, match):
    with pytest.raises(ReconInputError, match=match):
        fit_gaussian_falloff(angles, intensity)


def test_fit_refuses_bad_center():
    with pytest.raises(ReconInputError, match="center_deg"):
        fit_gaussian_falloff([0.0, 10.0, 20.0], [1.0, 0.5, 0.1], center_deg=float("inf"))


# ----------------------------------------------------------------------------- field of view


def test_fov_dissertation_pco_prototype():
    # Sec. 3.3 / 4.4: PCO edge 5.5 (2560 x 2160 px of 6.5 um), d = 8.8 mm, beta = 0.5 deg,
    # alpha_c = 41.5 deg (x) and 30 deg (y): the sensor limits, FoV +/-42 and +/-30.5 deg
    kw = dict(beta_deg=0.5, psf_width_mm=0.0, d_mm=8.8)
    assert fov_half_angle_deg(41.5, sensor_width_mm=2560 * 6.5e-3, **kw) == pytest.approx(42.0)
    assert fov_half_angle_deg(30.0, sensor_width_mm=2160 * 6.5e-3, **kw) == pytest.approx(30.5)


def test_fov_geometric_limit_wins_for_large_alpha_c():
    # (8 + 2) / (2 * 5) = 1 -> 45 deg
    fov = fov_half_angle_deg(89.0, beta_deg=0.5, sensor_width_mm=8.0, psf_width_mm=2.0, d_mm=5.0)
    assert fov == pytest.approx(45.5)
    # Eq. 3.12 form with half widths l = 4, w = 1: atan((l + w) / d)
    assert fov == pytest.approx(0.5 + math.degrees(math.atan((4.0 + 1.0) / 5.0)))
    # and alpha_c wins when smaller
    assert fov_half_angle_deg(
        20.0, beta_deg=0.5, sensor_width_mm=8.0, psf_width_mm=2.0, d_mm=5.0
    ) == pytest.approx(20.5)


@pytest.mark.parametrize(
    ("alpha_c", "kw", "match"),
    [
        (0.0, {}, "alpha_c_deg"),
        (95.0, {}, "alpha_c_deg"),
        (30.0, {"d_mm": 0.0}, "d_mm"),
        (30.0, {"beta_deg": -1.0}, "beta_deg"),
        (30.0, {"psf_width_mm": -1.0}, "psf_width_mm"),
        (30.0, {"sensor_width_mm": float("nan")}, "sensor_width_mm"),
    ],
)
def test_fov_refusals(alpha_c, kw, match):
    args = dict(beta_deg=0.5, sensor_width_mm=8.0, psf_width_mm=1.0, d_mm=5.0)
    args.update(kw)
    with pytest.raises(ReconInputError, match=match):
        fov_half_angle_deg(alpha_c, **args)
