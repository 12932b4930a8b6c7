"""What a PSF estimated from scenes buys (recon.analysis.early_stop.reference_db), and
what the recipe's fit costs: one observed solve per pair and threshold, with progress."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from recon.analysis import early_stop
from recon.analysis.early_stop import REFERENCE_ITERATIONS, fit_early_stop, reference_db
from recon.analysis.psf_from_scenes import leave_one_out
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator

ROWS, COLS = 24, 32


def synthetic_pairs(n: int, seed: int, noise: float = 0.02):
    """``n`` smooth non-negative scenes, their measurements through a sparse blurred
    PSF with ``noise`` times the rms of Gaussian noise, and that PSF (sensor-sized)."""
    rng = np.random.default_rng(seed)
    spots = np.zeros((ROWS, COLS), np.float32)
    where = rng.integers((2, 2), (ROWS - 2, COLS - 2), size=(10, 2))
    spots[where[:, 0], where[:, 1]] = rng.random(10) + 0.5
    psf = gaussian_filter(spots, 0.7)
    op = ConvolutionOperator(psf)
    scenes = [(np.maximum(gaussian_filter(rng.random((ROWS, COLS)), 1.5) * 4 - 1.5, 0)
               + 0.05).astype(np.float32) for _ in range(n)]
    clean = [op.forward(np.pad(x, ((ROWS // 2,) * 2, (COLS // 2,) * 2))) for x in scenes]
    return scenes, [(b + noise * b.std() * rng.standard_normal(b.shape)).astype(np.float32)
                    for b in clean], psf


@pytest.fixture(scope="module")
def pairs():
    return synthetic_pairs(4, 5)


def test_reference_db_ranks_psfs_by_what_they_reconstruct(pairs):
    """The held-out PSFs reconstruct the pairs far better than a flat PSF of the same
    total or the true PSF shifted by two pixels; the figure is -20 log10 of the error of
    the fixed reference solve."""
    xs, bs, truth = pairs
    loo = leave_one_out(xs, bs).psfs
    good = reference_db(xs, bs, loo)
    flat = reference_db(xs, bs, [np.full_like(truth, truth.mean())] * 4)
    shifted = reference_db(xs, bs, [np.roll(truth, 2, axis=1)] * 4)
    assert good.shape == (4,)
    assert np.all(good > flat + 3) and np.all(good > shifted + 1), (good, flat, shifted)
    image = early_stop.solve_checkpoints(loo[0], bs[0], [REFERENCE_ITERATIONS])
    err = early_stop.gain_fitted_error(image[REFERENCE_ITERATIONS], xs[0])
    assert good[0] == pytest.approx(-20 * np.log10(err))


def test_reference_db_is_read_from_the_fit_without_solving_again(pairs, monkeypatch):
    xs, bs, _ = pairs
    loo = leave_one_out(xs, bs).psfs
    fit = fit_early_stop(xs, bs, loo, loo[0])
    solved = reference_db(xs, bs, loo)

    def refuse(*args, **kwargs):
        raise AssertionError("solved again")
    monkeypatch.setattr(early_stop, "solve_checkpoints", refuse)
    np.testing.assert_allclose(reference_db(xs, bs, loo, fit), solved, rtol=1e-6)
    with pytest.raises(ReconInputError, match="4 pairs and 3 held-out PSFs"):
        reference_db(xs, bs, loo[:3])


def test_the_fit_observes_one_solve_per_pair_and_threshold(pairs, monkeypatch):
    """Every candidate count is a checkpoint of one solve of the largest count: 3
    thresholds x 4 pairs = 12 solves of 200 iterations, each reported as progress."""
    xs, bs, _ = pairs
    loo = leave_one_out(xs, bs).psfs
    solves, progress = [], []
    real = early_stop._solve

    def counting(psf, raw, iterations, observe=None, **options):
        solves.append(iterations)
        return real(psf, raw, iterations, observe=observe, **options)
    monkeypatch.setattr(early_stop, "_solve", counting)
    fit_early_stop(xs, bs, loo, loo[0], thresholds=(0.0, 0.05, 0.1),
                   on_solve=lambda done, total: progress.append((done, total)))
    assert solves == [max(early_stop.CANDIDATES)] * 12  # the field response: none more
    assert progress == [(i, 12) for i in range(1, 13)]
