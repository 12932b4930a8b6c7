"""The recipe fitted on binned pairs (recon.analysis.early_stop.fit_recipe): the
calibration's held-out PSFs and observed solves at 2 x 2 binning choose the count the
full-size fit chooses, and the run records the binning.

Synthetic camera of 192 x 224 pixels (96 x 112 binned, FIT_MIN_PX): a sparse PSF
blurred over a few pixels, smooth non-negative scenes, 3 % noise, so that a prior-free
FISTA semi-converges (its error falls, then rises) and the count matters.
"""

import json

import numpy as np
import pytest

from recon.analysis.early_stop import FIT_MIN_PX, fit_bin_factor, fit_held_out, fit_recipe
from recon.analysis.psf_from_scenes import estimate_psf_from_scenes
from recon.early_stop import EarlyStop
from recon.errors import ReconInputError

from .synthetic_camera import measure, smooth_scene, sparse_psf

ROWS, COLS = 2 * FIT_MIN_PX, 2 * FIT_MIN_PX + 32
COUNTS = (3, 10, 30, 100, 300)
ONE = {"thresholds": (0.0,), "weights": (0.0,)}


@pytest.fixture(scope="module")
def pairs():
    rng = np.random.default_rng(7)
    h = sparse_psf(rng, ROWS, COLS, points=40, margin=8, sigma_px=1.5)
    scenes, measurements = [], []
    for _ in range(4):
        x = smooth_scene(rng, ROWS, COLS, sigma_px=4.0, gain=8, floor=3.5)
        b = measure(x, h)
        scenes.append(x)
        measurements.append((b + 0.03 * b.std() * rng.standard_normal(b.shape)).astype(
            np.float32))
    return scenes, measurements, estimate_psf_from_scenes(scenes, measurements).psf


def test_the_fit_bins_pairs_that_keep_enough_pixels():
    assert fit_bin_factor((ROWS, COLS)) == 2 and fit_bin_factor((ROWS, COLS, 3)) == 2
    assert fit_bin_factor((ROWS - 1, COLS)) == 1  # a side of 95 binned: fitted full size
    assert fit_bin_factor((24, 32)) == 1


def test_the_binned_fit_chooses_the_full_size_fits_count_and_records_its_binning(pairs):
    scenes, measurements, psf = pairs
    full = fit_recipe(scenes, measurements, psf, bin_factor=1, candidates=COUNTS, **ONE)
    binned = fit_recipe(scenes, measurements, psf, candidates=COUNTS, **ONE)
    assert (full.bin_factor, binned.bin_factor) == (1, 2)
    assert (full.fit.fit_bin_factor, binned.fit.fit_bin_factor) == (1, 2)
    assert binned.held_out.psfs[0].shape == (ROWS // 2, COLS // 2)
    assert binned.fit.psf_sha256 == full.fit.psf_sha256  # both for the full-size PSF
    # an interior count (semi-convergence), the same at both sizes
    assert 10 <= full.fit.iterations <= 100, full.fit.errors
    assert binned.fit.iterations == full.fit.iterations, (binned.fit.errors, full.fit.errors)
    assert "binned 2 x 2" in binned.fit.method and "binned" not in full.fit.method
    assert binned.reference_db.shape == (4,) and np.all(np.isfinite(binned.reference_db))
    again = EarlyStop.from_dict(json.loads(json.dumps(binned.fit.to_dict())))
    assert again.fit_bin_factor == 2
    old = binned.fit.to_dict()
    del old["fit_bin_factor"]  # a file written before the binning was recorded
    assert EarlyStop.from_dict(old).fit_bin_factor == 1


def test_the_benchmarks_nested_fit_is_the_calibrations(pairs):
    scenes, measurements, _ = pairs
    fit = fit_held_out(scenes, measurements, 0, candidates=COUNTS, **ONE)
    assert fit.fit_bin_factor == 2 and fit.pairs == ()


def test_a_psf_of_another_size_or_a_bin_too_large_is_refused(pairs):
    scenes, measurements, psf = pairs
    with pytest.raises(ReconInputError, match="binned 2 x 2"):
        fit_recipe(scenes, measurements, psf[:-2], candidates=(3,), **ONE)
    with pytest.raises(ReconInputError, match="bin_factor"):
        fit_recipe(scenes, measurements, psf, bin_factor=ROWS, candidates=(3,), **ONE)


def test_the_calibration_run_records_the_binning_of_its_held_out_figures(pairs, tmp_path):
    from instrument.runs.runstore import RunStore
    from tests.calibration_routines.test_psf_from_scenes_progress import calibrate_files

    scenes, measurements, _ = pairs
    run = calibrate_files(tmp_path, scenes[:3], measurements[:3])
    summary = RunStore.open(run).attrs["summary"]
    assert summary["held_out_bin_factor"] == 2
    assert EarlyStop.load(run).fit_bin_factor == 2
    assert sorted(summary["held_out_residual"]) == ["p0", "p1", "p2"]
