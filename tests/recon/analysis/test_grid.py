"""Tests of recon.analysis.grid: reconstruction-grid recommendation on a simulated stack."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage, optimize

from recon.analysis.grid import GridRecommendation, recommend_grid
from recon.analysis.psf import inner_product
from recon.errors import ReconInputError

N = 96
D_MM = 5.0
PITCH_MM = 0.005
Z_REF = 50.0


def waves(seed: int = 0, n: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    k = rng.uniform(0.08, 0.16, n)
    theta = rng.uniform(0.0, np.pi, n)
    return k * np.cos(theta), k * np.sin(theta), rng.uniform(0.0, 2 * np.pi, n)


WAVES = waves()


def caustic_psf(z_mm: float, blur_px: float = 0.0) -> np.ndarray:
    """Caustic-like lines (zero set of a random wave field) in a disc, magnified by 1 + d/z.

    Evaluated analytically at coordinates scaled by (1 + d/z) / (1 + d/z_ref) about the
    array centre, so every depth is an exact scaled copy (no resampling).
    """
    m = (1 + D_MM / z_mm) / (1 + D_MM / Z_REF)
    yy, xx = (np.mgrid[:N, :N] - (N - 1) / 2.0) / m
    kx, ky, ph = WAVES
    f = np.cos(kx[:, None, None] * xx + ky[:, None, None] * yy + ph[:, None, None]).sum(0)
    f /= np.sqrt(kx.size / 2)
    h = np.exp(-((f / 0.4) ** 2)) * (xx**2 + yy**2 <= 36.0**2)
    return ndimage.gaussian_filter(h, blur_px) if blur_px else h


DEPTHS = np.array([20.0, 30.0, 45.0, 65.0, 100.0])


@pytest.fixture(scope="module")
def stack() -> np.ndarray:
    return np.stack([caustic_psf(z) for z in DEPTHS])


@pytest.fixture(scope="module")
def full(stack) -> GridRecommendation:
    return recommend_grid(stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM)


def measured_step(z_mm: float) -> float:
    """1/z step towards the camera at which the simulated PSFs' inner product falls to 0.8."""
    ref = caustic_psf(z_mm)

    def gap(step: float) -> float:
        return inner_product(ref, caustic_psf(1.0 / (1.0 / z_mm + step))) - 0.8

    steps = np.linspace(1e-4, 0.02, 40)
    first = int(np.flatnonzero([gap(s) <= 0 for s in steps])[0])
    return optimize.brentq(gap, steps[first - 1], steps[first], xtol=1e-7)


def test_planes_are_half_the_distinguishable_step_apart(full):
    inv = 1.0 / full.depths_mm
    spacing = -np.diff(inv)
    np.testing.assert_allclose(spacing[:-1], full.inverse_depth_step_per_mm, rtol=1e-9)
    assert 0 < spacing[-1] <= full.inverse_depth_step_per_mm * (1 + 1e-9)
    assert full.depths_mm[0] == 20.0 and full.depths_mm[-1] == 100.0
    assert full.inverse_depth_step_per_mm == pytest.approx(full.resolvable_step_per_mm / 2)
    # independent: the finest step at which simulated PSFs of neighbouring depths fall to
    # an inner product of 0.8 (the farthest depth, where 1/z steps are smallest)
    truth = min(measured_step(z) for z in (45.0, 100.0))
    assert full.inverse_depth_step_per_mm == pytest.approx(truth / 2, rel=0.15)


def test_recommendation_contents(full, stack):
    n = full.depths_mm.size
    assert full.step_per_psf_per_mm.shape == (5,)
    assert full.resolvable_step_per_mm == pytest.approx(full.step_per_psf_per_mm.min())
    assert full.lateral_bin == 1  # sharp lines: about 1.4 px resolution
    assert 1.0 < full.lateral_resolution_px < 2.0
    assert full.lateral_resolution_70_px > full.lateral_resolution_px
    np.testing.assert_allclose(full.voxel_size_mm, PITCH_MM * full.depths_mm / D_MM)
    assert full.psf_indices.shape == (n,)
    # nearest calibrated depth in 1/z
    for z, i in zip(full.depths_mm, full.psf_indices, strict=True):
        assert i == np.argmin(np.abs(1 / DEPTHS - 1 / z))
    assert full.calibrated_range_mm == (20.0, 100.0) == full.span_mm
    text = "\n".join(full.reasons)
    assert f"{n} plane(s)" in text and "no binning" in text
    assert "1/mm" in text and "Nyquist" in text and "interpolated" in text
    d = full.to_dict()
    assert d["lateral_bin"] == 1 and len(d["depths_mm"]) == n
    json.dumps(d)


def test_narrower_scene_gives_fewer_planes(stack, full):
    scene = recommend_grid(
        stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM, scene_depth_range_mm=(40.0, 60.0)
    )
    assert 2 <= scene.depths_mm.size < full.depths_mm.size
    assert scene.depths_mm[0] == 40.0 and scene.depths_mm[-1] == 60.0
    assert scene.inverse_depth_step_per_mm == pytest.approx(full.inverse_depth_step_per_mm)
    assert scene.span_mm == (40.0, 60.0)
    assert any(
        "the scene spans 40-60 mm" in r and f"of the {full.depths_mm.size}" in r
        for r in scene.reasons
    )
    thin = recommend_grid(
        stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM, scene_depth_range_mm=(50.0, 50.0)
    )
    np.testing.assert_array_equal(thin.depths_mm, [50.0])
    clipped = recommend_grid(
        stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM, scene_depth_range_mm=(80.0, 500.0)
    )
    assert clipped.span_mm == (80.0, 100.0)
    assert any("beyond the calibrated range" in r for r in clipped.reasons)


def test_blurrier_psf_gives_a_larger_bin(full):
    blurred = np.stack([caustic_psf(z, blur_px=3.0) for z in DEPTHS])
    rec = recommend_grid(blurred, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM)
    assert rec.lateral_bin > full.lateral_bin
    assert rec.lateral_bin == int(rec.lateral_resolution_px // 2)
    assert any(f"bin of {rec.lateral_bin}" in r for r in rec.reasons)
    # and coarser depth planes: blur makes scaled copies alike for longer
    assert rec.inverse_depth_step_per_mm > full.inverse_depth_step_per_mm


def test_refusals(stack):
    with pytest.raises(ReconInputError, match="one depth per PSF"):
        recommend_grid(stack, DEPTHS[:-1], pitch_mm=PITCH_MM, d_mm=D_MM)
    with pytest.raises(ReconInputError, match="distinct"):
        recommend_grid(stack, np.ones(5), pitch_mm=PITCH_MM, d_mm=D_MM)
    with pytest.raises(ReconInputError, match="pitch_mm"):
        recommend_grid(stack, DEPTHS, pitch_mm=0.0, d_mm=D_MM)
    with pytest.raises(ReconInputError, match="threshold"):
        recommend_grid(stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM, threshold=1.5)
    with pytest.raises(ReconInputError, match="outside the calibrated range"):
        recommend_grid(
            stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM, scene_depth_range_mm=(200.0, 300.0)
        )
    with pytest.raises(ReconInputError, match="z_near <= z_far"):
        recommend_grid(
            stack, DEPTHS, pitch_mm=PITCH_MM, d_mm=D_MM, scene_depth_range_mm=(60.0, 40.0)
        )
