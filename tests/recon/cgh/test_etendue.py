"""Étendue / FoV / eyebox calculator against the numbers quoted in Kuo 2020, Sec. 7.3."""

from __future__ import annotations

import math

import pytest

from recon.cgh import (
    etendue_mm2,
    expansion_factor,
    eyebox_for_fov,
    fov_eyebox,
    fov_for_eyebox,
    max_diffraction_angle_deg,
    pixels_for,
    slm_etendue_mm2,
)
from recon.errors import ReconInputError


def test_gaea2_eyebox_at_120_degrees_is_1_05_mm():
    # 4160 px * 532 nm = 2.21312 mm; 120 deg = 2.0944 rad -> 1.0567 mm ("1.05 mm")
    eb = eyebox_for_fov(4160, 120.0, 532.0)
    assert eb == pytest.approx(4160 * 532e-6 / (2 * math.pi / 3), rel=1e-12)
    assert 1.05 <= eb < 1.06


def test_gaea2_fov_for_10_mm_eyebox_is_12_7_degrees():
    # 2.21312 mm / 10 mm = 0.221312 rad = 12.68 deg; the sine form gives 12.71 deg
    assert fov_for_eyebox(4160, 10.0, 532.0) == pytest.approx(12.68, abs=0.01)
    assert fov_for_eyebox(4160, 10.0, 532.0, model="sine") == pytest.approx(12.71, abs=0.01)


def test_pixels_for_120_degrees_and_10_mm_is_about_32500():
    # 2 sin(60 deg) * 10 mm / 532 nm = 1.7320508 * 10 / 532e-6 = 32557
    n = pixels_for(120.0, 10.0, 532.0)
    assert n == pytest.approx(2 * math.sin(math.pi / 3) * 10 / 532e-6, rel=1e-12)
    assert 32_400 < n < 32_600
    assert n / 120.0 == pytest.approx(271.3, abs=0.1)  # "270 pixels/degree"


def test_diffraction_angle_and_etendue_of_an_slm():
    # 16 um at 532 nm: sin(theta) = 0.532 / 32
    assert max_diffraction_angle_deg(16.0, 532.0) == pytest.approx(
        math.degrees(math.asin(0.532 / 32)), rel=1e-12)
    # Eq. 7.3 equals Eq. 7.1 with the SLM's area and angle: (lambda Nx)(lambda Ny)
    w, h = 960 * 16e-3, 540 * 16e-3
    g1 = etendue_mm2(w, h, max_diffraction_angle_deg(16.0, 532.0))
    assert g1 == pytest.approx(slm_etendue_mm2((540, 960), 532.0), rel=1e-12)
    assert slm_etendue_mm2((540, 960), 532.0) == pytest.approx((532e-6 ** 2) * 540 * 960)


def test_expansion_factors_of_the_dissertation():
    assert expansion_factor(16.0, 8.0) == 4.0
    assert expansion_factor(16.0, 4.0) == 16.0
    assert expansion_factor(16.0, 2.66) == pytest.approx(36.18, abs=0.01)


def test_mask_widens_fov_and_keeps_eyebox():
    fov0, eb0 = fov_eyebox(960, 16.0, 532.0, 100.0, 50.0)
    fov1, eb1 = fov_eyebox(960, 16.0, 532.0, 100.0, 50.0, mask_pitch_um=4.0)
    assert eb1 == eb0 == pytest.approx(50.0 / 100.0 * 960 * 16e-3)
    # tan(FoV/2) = (f1/f2) tan(theta): hand computation
    th = math.asin(0.532 / 32.0)
    assert fov0 == pytest.approx(math.degrees(2 * math.atan(2 * math.tan(th))), rel=1e-12)
    assert fov1 > 3.9 * fov0  # ~4x wider (sin theta grows 4x)


@pytest.mark.parametrize("call", [
    lambda: eyebox_for_fov(0, 90.0, 532.0),
    lambda: eyebox_for_fov(100, 200.0, 532.0),
    lambda: eyebox_for_fov(100, 90.0, -1.0),
    lambda: eyebox_for_fov(100, 90.0, 532.0, model="exact"),
    lambda: max_diffraction_angle_deg(0.2, 532.0),
    lambda: fov_for_eyebox(10_000, 1.0, 532.0, model="sine"),
    lambda: slm_etendue_mm2((0, 3), 532.0),
])
def test_bad_input_names_the_problem(call):
    with pytest.raises(ReconInputError):
        call()
