"""The sensor response of a scene calibration (recon.analysis.sensor_response): a
nuisance of the PSF's estimate.

Synthetic camera: a sparse PSF, smooth scenes, and a sensor shaded by a known smooth
gain (brighter at one corner, as the real camera's is at its bottom centre): ``b =
V C (h * P x)`` plus 1 % noise. The fit must find that shading from the pairs alone,
and a PSF estimated with it must predict a pair it never saw better than one without.
"""

import numpy as np
import pytest

from recon.analysis.early_stop import fit_recipe
from recon.analysis.psf_from_scenes import estimate_psf_from_scenes, predict_measurements
from recon.analysis.sensor_response import (
    MIN_GAIN,
    estimate_with_sensor_response,
    fit_sensor_response,
    grid_shape,
    remove_sensor_response,
)
from recon.field_response import field_gain

from .synthetic_camera import measure, smooth_scene, sparse_psf

ROWS, COLS = 64, 96


def _shading(rows=ROWS, cols=COLS):
    """A bright patch low on the sensor (a linear ramp would not do: a PSF and a gain
    over the object absorb most of one)."""
    r, c = np.mgrid[0:rows, 0:cols]
    bump = np.exp(-(((r - 0.75 * rows) / (0.25 * rows)) ** 2
                    + ((c - 0.4 * cols) / (0.25 * cols)) ** 2) / 2)
    return (0.7 + 0.6 * bump).astype(np.float32)


@pytest.fixture(scope="module")
def camera():
    rng = np.random.default_rng(5)
    h = sparse_psf(rng, ROWS, COLS, points=40, margin=4, sigma_px=0.8)
    v = _shading()
    scenes, shaded, flat = [], [], []
    for _ in range(6):
        x = smooth_scene(rng, ROWS, COLS, sigma_px=2.0)
        b = measure(x, h)
        noise = 0.01 * b.std() * rng.standard_normal(b.shape)
        scenes.append(x)
        shaded.append((v * b + noise).astype(np.float32))
        flat.append((b + noise).astype(np.float32))
    return scenes, shaded, flat, v


def _held_out_residual(scenes, measurements, grid):
    """Pair 5 predicted by the PSF (and response) from pairs 0-4."""
    train_b = [remove_sensor_response(b, grid) for b in measurements[:5]]
    psf = estimate_psf_from_scenes(scenes[:5], train_b).psf
    shade = 1.0 if grid is None else field_gain(grid, (ROWS, COLS))
    prediction = shade * predict_measurements(psf, scenes[5:])[0][..., 0]
    b = measurements[5]
    return float(np.linalg.norm(prediction - b) / np.linalg.norm(b))


def test_fit_finds_the_sensors_shading(camera):
    scenes, shaded, _, v = camera
    grid = fit_sensor_response(scenes[:5], shaded[:5])
    assert grid.shape == grid_shape((ROWS, COLS)) and grid.min() >= MIN_GAIN
    found = field_gain(grid, (ROWS, COLS))
    truth = v / np.median(v)
    # the same shape (correlation 0.73 measured), flatter: the PSF takes up part of
    # the shading and the smoothing (15 px) part of the patch (16 px)
    assert np.corrcoef(found.ravel(), truth.ravel())[0, 1] > 0.6
    assert np.ptp(found) > 0.1
    # and it pays on the pair held out of it: 0.060 against 0.095 without (measured)
    with_response = _held_out_residual(scenes, shaded, grid)
    without = _held_out_residual(scenes, shaded, None)
    assert with_response < 0.75 * without


def test_an_unshaded_sensor_gets_a_flat_response(camera):
    scenes, _, flat, _ = camera
    grid = fit_sensor_response(scenes[:5], flat[:5])
    assert np.abs(grid - 1.0).max() < 0.1
    # and costs nothing on the pair held out
    assert _held_out_residual(scenes, flat, grid) < 1.05 * _held_out_residual(
        scenes, flat, None)


def test_remove_divides_at_any_binning():
    grid = np.array([[1.0, 2.0], [4.0, 0.5]])
    b = np.ones((20, 30, 3), np.float32)
    out = remove_sensor_response(b, grid)
    np.testing.assert_allclose(out[..., 0], 1.0 / field_gain(grid, (20, 30)), rtol=1e-6)
    assert np.allclose(out[..., 0], out[..., 2])
    binned = remove_sensor_response(np.ones((10, 15), np.float32), grid)
    assert binned.shape == (10, 15)
    assert binned[0, 0] == pytest.approx(1.0) and binned[-1, 0] == pytest.approx(0.25)
    np.testing.assert_array_equal(remove_sensor_response(b, None), b)


def test_the_calibration_estimates_its_psfs_with_it(camera):
    """fit_recipe's PSF from every pair is the one from the measurements divided by the
    response it fits; each held-out PSF is estimated with the response of its own pairs
    (estimate_with_sensor_response without the held-out pair)."""
    scenes, shaded, _, _ = camera
    kw = {"candidates": (5, 20), "weights": (0.0,), "bin_factor": 1}
    rounds = []
    fit = fit_recipe(scenes[:5], shaded[:5], on_sensor=lambda r, _: rounds.append(r), **kw)
    plain = fit_recipe(scenes[:5], shaded[:5], fit_sensor=False, **kw)
    assert rounds == [1, 2] and plain.sensor_response is None
    np.testing.assert_array_equal(fit.sensor_response, fit_sensor_response(scenes[:5],
                                                                            shaded[:5]))
    by_hand = estimate_psf_from_scenes(
        scenes[:5], [remove_sensor_response(b, fit.sensor_response) for b in shaded[:5]])
    np.testing.assert_array_equal(fit.estimate.psf, by_hand.psf)
    held_out, _ = estimate_with_sensor_response(scenes[1:5], shaded[1:5])
    np.testing.assert_array_equal(fit.held_out.psfs[0], held_out.psf)
    # and they predict their held-out pairs better than the PSFs without it
    assert fit.held_out.mean < plain.held_out.mean
