"""Early stopping fitted on calibration pairs (recon.analysis.early_stop).

Small synthetic camera: a sparse blurred PSF, smooth non-negative scenes, measurements
with 3 % noise, so that a prior-free non-negative FISTA semi-converges: its error
against the scene falls, then rises as it fits the noise and the PSF's estimation
error. The fit must pick a count in the valley, and that count must generalise to a
pair it never saw.
"""

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from recon.analysis.early_stop import (
    fit_early_stop,
    fit_held_out,
    gain_fitted_error,
    reconstruct_early_stopped,
)
from recon.analysis.psf_from_scenes import estimate_psf_from_scenes, leave_one_out
from recon.early_stop import EarlyStop, psf_identity
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator

ROWS, COLS = 24, 32
COUNTS = (1, 3, 10, 30, 100, 300, 1000)


@pytest.fixture(scope="module")
def camera():
    rng = np.random.default_rng(3)
    h = np.zeros((ROWS, COLS), np.float32)
    for _ in range(12):
        h[rng.integers(2, ROWS - 2), rng.integers(2, COLS - 2)] = rng.random() + 0.5
    h = gaussian_filter(h, 0.7)
    padded = np.pad(h, ((ROWS // 2, ROWS // 2), (COLS // 2, COLS // 2)))
    scenes, measurements = [], []
    for _ in range(5):
        x = np.clip(gaussian_filter(rng.random((ROWS, COLS)), 1.5) * 4 - 1.5, 0, None) + 0.05
        b = ConvolutionOperator(x.astype(np.float32)).forward(padded)
        scenes.append(x.astype(np.float32))
        measurements.append((b + 0.03 * b.std() * rng.standard_normal(b.shape)).astype(np.float32))
    calib_x, calib_b = scenes[:4], measurements[:4]
    psf = estimate_psf_from_scenes(calib_x, calib_b).psf
    fit = fit_early_stop(calib_x, calib_b, leave_one_out(calib_x, calib_b).psfs, psf,
                         candidates=COUNTS, names=["a", "b", "c", "d"])
    return psf, fit, scenes[4], measurements[4], scenes, measurements


def _held_out_error(camera, iterations):
    psf, _, scene, raw, *_ = camera
    fit = EarlyStop(iterations, (iterations,), np.zeros((1, 4)), psf_identity(psf))
    return gain_fitted_error(reconstruct_early_stopped(psf, raw, fit, dark="none").image, scene)


def test_fitted_count_is_interior_and_generalises(camera):
    psf, fit, *_ = camera
    assert fit.errors.shape == (len(COUNTS), 4)
    assert fit.iterations in (10, 30, 100)  # neither under- nor over-fitted extreme
    assert fit.psf_sha256 == psf_identity(psf)
    best = _held_out_error(camera, fit.iterations)
    assert best < min(_held_out_error(camera, 1), _held_out_error(camera, 1000)) - 0.05


def test_reconstruction_runs_exactly_the_fitted_count(camera):
    psf, fit, _, raw, *_ = camera
    rec = reconstruct_early_stopped(psf, raw, fit, dark="none")
    assert rec.info.method == "fista"
    assert rec.info.iterations_used == fit.iterations
    assert rec.info.tv == 0.0


def test_another_psf_is_refused_in_one_line(camera):
    psf, fit, _, raw, *_ = camera
    other = np.roll(psf, 1, axis=0)
    with pytest.raises(ReconInputError, match="fitted for another PSF") as err:
        reconstruct_early_stopped(other, raw, fit, dark="none")
    assert "\n" not in str(err.value)
    with pytest.raises(ReconInputError, match="fixed by the early-stop calibration"):
        reconstruct_early_stopped(psf, raw, fit, dark="none", iterations=5)


def test_fit_reads_back_from_its_json(camera, tmp_path):
    _, fit, *_ = camera
    path = tmp_path / "early_stop.json"
    path.write_text(json.dumps(fit.to_dict()))
    for where in (path, tmp_path):  # the file, or the run directory holding it
        back = EarlyStop.load(where)
        assert (back.iterations, back.candidates, back.psf_sha256, back.pairs) == (
            fit.iterations, fit.candidates, fit.psf_sha256, fit.pairs)
        np.testing.assert_allclose(back.errors, fit.errors, atol=1e-6)
    (tmp_path / "other.json").write_text('{"kind": "psf"}')
    with pytest.raises(ReconInputError, match="not an early-stop calibration"):
        EarlyStop.load(tmp_path / "other.json")
    with pytest.raises(ReconInputError, match="cannot read"):
        EarlyStop.load(tmp_path / "missing.json")


def test_gain_fitted_error_ignores_scale():
    rng = np.random.default_rng(0)
    s = rng.random((8, 9, 3))
    assert gain_fitted_error(5.0 * s, s) == pytest.approx(0.0, abs=1e-7)
    assert gain_fitted_error(np.zeros_like(s), s) == 1.0


def test_held_out_fit_never_sees_the_held_out_pair(camera):
    psf, fit, _, _, scenes, measurements = camera
    # pair 4 held out: the same fit as from the first four pairs alone, whatever pair 4 is
    held = fit_held_out(scenes, measurements, 4, candidates=COUNTS)
    assert held.psf_sha256 == psf_identity(psf) and held.iterations == fit.iterations
    np.testing.assert_allclose(held.errors, fit.errors, rtol=1e-6)
    spoiled = [*measurements[:4], measurements[4][::-1].copy()]
    again = fit_held_out(scenes, spoiled, 4, psf=psf, candidates=COUNTS)
    np.testing.assert_allclose(again.errors, fit.errors, rtol=1e-6)
    with pytest.raises(ReconInputError, match="at least three pairs"):
        fit_held_out(scenes[:2], measurements[:2], 0)
