"""Two-point / 16-point distinguishability by reconstruction (Sec. 4.4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from recon.analysis.distinguishability import (
    DIP_CRITERION,
    dip_between,
    distinguishability_limit,
    points_resolved,
)
from recon.errors import ReconInputError


def test_dip_of_two_gaussians_matches_the_closed_form():
    sigma, a = 2.0, 3.0  # peaks at +-a
    r, c = np.mgrid[0:41, 0:41].astype(float)
    g = lambda x0: np.exp(-((c - x0) ** 2 + (r - 20) ** 2) / (2 * sigma**2))  # noqa: E731
    image = g(20 - a) + g(20 + a)
    dip = dip_between(image, (20, 20 - a), (20, 20 + a))
    one = lambda x: np.exp(-x**2 / (2 * sigma**2))  # noqa: E731
    expected = 1 - 2 * one(a) / (one(0) + one(2 * a))
    assert dip == pytest.approx(expected, abs=0.01)
    assert dip_between(g(20), (20, 19), (20, 21)) == 0.0  # closer than 2 px: no valley


def _caustic(blur: float) -> np.ndarray:
    rng = np.random.default_rng(0)
    core = ndimage.gaussian_filter(rng.standard_normal((64, 64)), 2)
    psf = np.zeros((96, 96))
    psf[16:80, 16:80] = np.exp(-((core / 0.02) ** 2))
    return ndimage.gaussian_filter(psf, blur) if blur else psf


def test_sharp_caustics_resolve_closer_points_than_blurred_ones():
    seps = [1, 2, 3, 4, 6, 8]
    sharp, _ = distinguishability_limit(_caustic(0), seps, iterations=200)
    blurred, results = distinguishability_limit(_caustic(1.5), seps, iterations=200)
    assert sharp is not None and blurred is not None and sharp < blurred
    assert sharp <= 3 and blurred >= 4  # measured 2 and 6 px
    assert all(r.resolved == (r.dip >= DIP_CRITERION) for r in results)
    grid, _ = distinguishability_limit(_caustic(1.5), seps, n_points=16, iterations=200)
    assert grid is not None and grid >= blurred  # a 4 x 4 grid is no easier


def test_bad_input_is_refused():
    psf = _caustic(0)
    with pytest.raises(ReconInputError, match="separation"):
        points_resolved(psf, 0.0)
    with pytest.raises(ReconInputError, match="n_points"):
        points_resolved(psf, 3.0, n_points=3)
    with pytest.raises(ReconInputError, match="axis"):
        points_resolved(psf, 3.0, axis="z")
    with pytest.raises(ReconInputError, match="psf"):
        points_resolved(np.zeros((8, 8)), 3.0)
