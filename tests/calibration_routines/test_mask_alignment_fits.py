"""Fits and the corrected-mask stitching of the mask alignment (hand-computed cases)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration_routines.mask_alignment import (
    best_subpixel_offset,
    corrected_mask,
    fit_similarity,
    fit_triangle,
    section_bounds,
)
from calibration_routines.mask_alignment.fitting import fit_parabola, fit_plane, triangle
from instrument.acquisition.plan import PlanError
from recon.optics.holo_display import MaskModel


def test_triangle_values():
    assert triangle(np.array([-2.0, -0.5, 0.0, 0.25, 1.0])).tolist() == [0, 0.5, 1, 0.75, 0]


@pytest.mark.parametrize("d", [-1.3, 0.0, 0.37, 2.5])
def test_fit_triangle_recovers_offset(d):
    k = 4
    s = np.arange(-5, 6) + round(d)
    amp = 0.1 * triangle((s - d) / k) + 0.002
    rng = np.random.default_rng(1)
    eta = (amp + rng.normal(0, 1e-4, s.size)) ** 2
    fit = fit_triangle(s, eta, k)
    assert abs(fit.offset - d) < 0.02
    assert fit.offset_sigma < 0.02
    assert abs(fit.amplitude - 0.1) < 2e-3 and abs(fit.background - 0.002) < 1e-3


def test_fit_triangle_noise_free_is_exact():
    s = np.arange(-5, 6)
    fit = fit_triangle(s, (triangle((s - 0.61) / 4)) ** 2, 4)
    assert fit.offset == pytest.approx(0.61, abs=1e-6)
    assert fit.rms < 1e-8


def test_fit_triangle_errors():
    with pytest.raises(PlanError, match="4 distinct"):
        fit_triangle([0, 1, 1, 2], [1, 2, 3, 4], 4)
    with pytest.raises(PlanError, match="positions but"):
        fit_triangle([0, 1, 2, 3], [1, 2], 4)
    with pytest.raises(PlanError, match="k must be"):
        fit_triangle([0, 1, 2, 3], [1, 2, 3, 4], 0)


def test_fit_similarity_hand_case():
    xs, ys = np.meshgrid([-200.0, 0.0, 200.0], [-100.0, 0.0, 100.0])
    c = np.stack([xs.ravel(), ys.ravel()], 1)
    t, theta, mu = np.array([3.3, -5.7]), 3e-3, 2e-4
    d = t + theta * np.stack([-c[:, 1], c[:, 0]], 1) + mu * c
    fit = fit_similarity(c, d)
    assert fit.translation == pytest.approx(tuple(t), abs=1e-9)
    assert fit.theta == pytest.approx(theta, abs=1e-12)
    assert fit.scale_error == pytest.approx(mu, abs=1e-12)
    assert fit.residual_rms < 1e-9
    # a distortion the similarity cannot explain shows in the residuals
    d2 = d.copy()
    d2[4] += (0.5, 0.0)
    assert np.abs(fit_similarity(c, d2).residuals).max() > 0.3


def test_fit_similarity_errors():
    with pytest.raises(PlanError, match="coincide"):
        fit_similarity([[1, 2], [1, 2], [1, 2]], [[0, 0], [0, 0], [0, 0]])
    with pytest.raises(PlanError, match="at least 3"):
        fit_similarity([[0, 0], [1, 1]], [[0, 0], [0, 0]])


def test_best_subpixel_offset():
    # no distortion: minus the common fractional part
    phi, gain = best_subpixel_offset(np.array([[3.3, -5.7]] * 4), 4)
    assert phi == pytest.approx((-0.3, -0.3), abs=0.011) and gain > 1.0
    # two groups of patches a third of a pixel apart: the move balances them
    d = np.array([[0.0, 0.0]] * 3 + [[0.34, 0.0]] * 3)
    phi, _ = best_subpixel_offset(d, 4)
    assert -0.35 < phi[0] < 0.01 and abs(phi[1]) < 0.011


def test_section_bounds_cover_the_slm():
    b = section_bounds((96, 120), (3, 5))
    assert len(b) == 15 and b[0] == (0, 32, 0, 24) and b[-1] == (64, 96, 96, 120)
    area = sum((r1 - r0) * (c1 - c0) for r0, r1, c0, c1 in b)
    assert area == 96 * 120
    with pytest.raises(PlanError, match="does not fit"):
        section_bounds((4, 4), (5, 1))


def test_corrected_mask_stitches_shifted_sections():
    mm = MaskModel((8, 10), 8.0, k=2, q=1, seed=3, margin=4)
    shifts = np.zeros((2 * 2, 2), int)
    shifts[3] = (1, -2)
    mask, seam = corrected_mask(mm, shifts, (2, 2), radius=1)
    model, m = mm.model, mm.margin
    assert mask.shape == (16, 20) and mask.dtype == np.float32
    # section 0 (rows 0-8, cols 0-10 in mask px) is the unshifted model
    np.testing.assert_array_equal(mask[:8, :10], model[m:m + 8, m:m + 10])
    # section 3 reads M(x - s): row i, col j from model[i - sy, j - sx]
    np.testing.assert_array_equal(mask[8:, 10:], model[m + 8 + 2:m + 16 + 2, m + 10 - 1:m + 20 - 1])
    # seams only where section 3 meets its neighbours
    assert seam[:7, :9].all() and not seam[8, 12] and not seam[12, 10]
    with pytest.raises(PlanError, match="margin"):
        corrected_mask(mm, np.full((4, 2), 5), (2, 2))
    with pytest.raises(PlanError, match="section shifts"):
        corrected_mask(mm, np.zeros((3, 2)), (2, 2))


def test_triangle_law_half_width_is_k():
    """The fit's model: spot amplitude halves at half an SLM pixel (k / 2 mask px)."""
    assert math.isclose(float(triangle(np.array([2.0 / 4]))[0]), 0.5)


def test_fit_parabola_recovers_vertex_width_and_rejects_edges():
    z = np.linspace(-0.2, 0.2, 9)
    f = fit_parabola(z, 2.0 - 50.0 * (z - 0.03) ** 2)
    assert f.accepted and f.vertex == pytest.approx(0.03, abs=1e-12)
    assert f.curvature == pytest.approx(-50.0) and f.peak == pytest.approx(2.0)
    # 0.8 of the peak: 50 dz^2 = 0.4 -> full width 2 sqrt(0.008)
    assert f.width_80 == pytest.approx(2 * math.sqrt(0.008))
    # a Gaussian: only the top enters; vertex exact by symmetry of the samples used
    g = fit_parabola(z, np.exp(-0.5 * ((z - 0.05) / 0.1) ** 2))
    assert g.accepted and abs(g.vertex - 0.05) < 0.005 and g.used < 9
    edge = fit_parabola(z, np.exp(-0.5 * ((z - 0.35) / 0.1) ** 2))
    assert not edge.accepted
    dip = fit_parabola(z, 1.0 + z**2)
    assert not dip.accepted and "curvature" in dip.reason


def test_fit_plane_slopes_and_errors():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1, 1, (15, 2))
    z = 0.1 + 0.02 * xy[:, 0] - 0.03 * xy[:, 1]
    p = fit_plane(xy, z)
    assert (p.z0, p.slope_x, p.slope_y) == pytest.approx((0.1, 0.02, -0.03))
    noisy = fit_plane(xy, z + rng.normal(0, 1e-3, 15), np.full(15, 1e-3))
    assert abs(noisy.slope_x - 0.02) < 4 * noisy.sigmas[1]
    with pytest.raises(PlanError, match="line"):
        fit_plane(np.stack([np.arange(5.0), 2 * np.arange(5.0)], 1), np.arange(5.0))


def test_smoothed_triangle_is_the_gaussian_convolution():
    from calibration_routines.mask_alignment.fitting import smoothed_triangle

    x = np.linspace(-2, 2, 41)
    np.testing.assert_array_equal(smoothed_triangle(x, 0.0), triangle(x))
    t = np.linspace(-3, 3, 60001)  # numerical convolution with a sigma-0.2 Gaussian
    g = np.exp(-0.5 * (t / 0.2) ** 2) / (0.2 * math.sqrt(2 * math.pi))
    num = [np.trapezoid(triangle(xi - t) * g, t) for xi in x]
    np.testing.assert_allclose(smoothed_triangle(x, 0.2), num, atol=1e-6)


@pytest.mark.parametrize("d", [0.1, 0.3, -1.45])
def test_fit_triangle_on_a_rounded_apex(d):
    """A blurred apex (relay pupil, defocus): the rounded model recovers d; the sharp
    triangle is pushed away from the nearest integer."""
    from calibration_routines.mask_alignment.fitting import smoothed_triangle

    k, s = 4, np.arange(-5, 6) + round(d)
    eta = (0.1 * smoothed_triangle((s - d) / k, 0.12) + 0.002) ** 2
    fit = fit_triangle(s, eta, k)
    assert fit.offset == pytest.approx(d, abs=1e-4)
    assert fit.rounding == pytest.approx(0.12, abs=1e-3)
    sharp = fit_triangle(s, eta, k, rounded=False)
    assert abs(sharp.offset - d) > 10 * abs(fit.offset - d)
