"""The recipe chosen by held-out errors moved towards in-sample ones
(recon.analysis.early_stop, ``in_sample``).

A held-out PSF comes from one calibration pair fewer than the PSF the recipe ships
with; reconstructions with it peak earlier. The fit also solves each pair with the
shipped PSF itself and moves the held-out errors (in dB) at each count halfway towards
the in-sample ones, by the gap between the two solves of the lead (green) channel,
undenoised. Small synthetic camera (tests/recon/synthetic_camera.py); the held-out
PSFs are made noisier than the shipped one on purpose, so that the two errors choose
different counts.
"""

import json

import numpy as np
import pytest

from recon.analysis.early_stop import (
    IN_SAMPLE_SHARE,
    fit_early_stop,
    fit_recipe,
    gain_fitted_error,
    solve_checkpoints,
)
from recon.analysis.psf_from_scenes import estimate_psf_from_scenes
from recon.early_stop import EarlyStop, clean_psf, psf_identity
from recon.errors import ReconInputError
from recon.preprocess.binning import box_bin

from .synthetic_camera import semiconvergent_pairs

ROWS, COLS = 24, 32
COUNTS = (3, 10, 20, 30, 50, 100)


@pytest.fixture(scope="module")
def noisy_held_out():
    """Four pairs, the PSF from all four, and held-out PSFs 6 % noisier (of its peak)."""
    xs, bs = semiconvergent_pairs(ROWS, COLS, 4)
    psf = estimate_psf_from_scenes(xs, bs).psf
    rng = np.random.default_rng(5)
    held = [np.clip(psf + 0.06 * psf.max() * rng.standard_normal(psf.shape), 0, None)
            .astype(np.float32) for _ in xs]
    both = fit_early_stop(xs, bs, held, psf, candidates=COUNTS, weights=(0.0,), in_sample=True,
                          field=False)
    alone = fit_early_stop(xs, bs, held, psf, candidates=COUNTS, weights=(0.0,), field=False)
    return xs, bs, psf, held, both, alone


def _best(errors):
    return int(np.argmin(np.log10(errors).mean(axis=-1).ravel()))


def test_the_choice_lies_between_the_held_out_and_the_in_sample_counts(noisy_held_out):
    *_, both, alone = noisy_held_out
    held, own = both.lead_errors[:, 0]  # one channel here: every channel is the lead
    np.testing.assert_allclose(held, both.errors[0, :, 0], rtol=1e-9)
    held_best, own_best = _best(held), _best(own)
    # the noisier held-out PSFs peak earlier than the shipped PSF on the pairs it saw
    assert COUNTS[held_best] < COUNTS[own_best]
    score = ((1 - IN_SAMPLE_SHARE) * np.log10(held).mean(axis=-1)
             + IN_SAMPLE_SHARE * np.log10(own).mean(axis=-1))
    assert both.iterations == COUNTS[int(np.argmin(score))]
    assert COUNTS[held_best] < both.iterations < COUNTS[own_best]  # neither alone
    # without it: the held-out errors alone choose, and they are the same numbers
    assert alone.lead_errors is None and alone.iterations == COUNTS[held_best]
    np.testing.assert_array_equal(alone.errors, both.errors)


def test_the_move_applies_at_every_denoising_weight(noisy_held_out):
    """The lead channel's solves are scored undenoised: each count's gap moves that
    count's errors at every weight, none of which need be 0."""
    xs, bs, psf, held, _, _ = noisy_held_out
    weights = (0.1, 0.5)
    fit = fit_early_stop(xs, bs, held, psf, candidates=COUNTS, weights=weights,
                         in_sample=True, field=False)
    gap = np.log10(fit.lead_errors[1, 0]).mean(axis=-1) - np.log10(
        fit.lead_errors[0, 0]).mean(axis=-1)
    score = np.log10(fit.errors[0]).mean(axis=-1) + IN_SAMPLE_SHARE * gap[:, None]
    j, m = np.unravel_index(int(np.argmin(score)), score.shape)
    assert (fit.iterations, fit.denoise_weight) == (COUNTS[j], weights[m])


def test_the_in_sample_move_is_measured_on_the_green_channel_of_rgbsemiconvergent_pairs():
    """RGB pairs: the lead channel (green) alone is solved with the shipped PSF, and
    its held-out errors are that channel's of the held-out solve."""
    # one camera per channel
    rgb = [semiconvergent_pairs(ROWS, COLS, 3, seed=s) for s in (21, 22, 23)]
    xs = [np.stack([rgb[c][0][k] for c in range(3)], axis=-1) for k in range(3)]
    bs = [np.stack([rgb[c][1][k] for c in range(3)], axis=-1) for k in range(3)]
    psf = estimate_psf_from_scenes(xs, bs).psf
    held = [estimate_psf_from_scenes(xs[:k] + xs[k + 1:], bs[:k] + bs[k + 1:]).psf
            for k in range(3)]
    fit = fit_early_stop(xs, bs, held, psf, candidates=(10, 30), weights=(0.0,),
                         in_sample=True, field=False)
    assert fit.lead_errors.shape == (2, 1, 2, 3)
    image = solve_checkpoints(psf[..., 1], bs[2][..., 1], (30,))[30]
    assert fit.lead_errors[1, 0, 1, 2] == pytest.approx(
        gain_fitted_error(image, xs[2][..., 1]), rel=1e-9)
    image = solve_checkpoints(held[2], bs[2], (30,))[30]
    assert fit.lead_errors[0, 0, 1, 2] == pytest.approx(
        gain_fitted_error(image[..., 1], xs[2][..., 1]), rel=1e-9)
    assert fit.errors[0, 1, 0, 2] == pytest.approx(gain_fitted_error(image, xs[2]), rel=1e-9)


def test_the_in_sample_errors_are_each_pairs_own_with_the_shipped_psf(noisy_held_out):
    xs, bs, psf, _, both, _ = noisy_held_out
    assert both.errors.shape == (1, len(COUNTS), 1, 4)
    assert both.lead_errors.shape == (2, 1, len(COUNTS), 4)
    for k in (0, 3):
        images = solve_checkpoints(clean_psf(psf, 0.0), bs[k], (20, 100))
        for n in (20, 100):
            assert both.lead_errors[1, 0, COUNTS.index(n), k] == pytest.approx(
                gain_fitted_error(images[n], xs[k]), rel=1e-9)


def test_a_binned_fit_scores_the_shipped_psf_binned_as_itssemiconvergent_pairs():
    xs, bs = semiconvergent_pairs(2 * ROWS, 2 * COLS, 3, seed=7)
    psf = estimate_psf_from_scenes(xs, bs).psf
    xb, bb = [box_bin(x, 2) for x in xs], [box_bin(b, 2) for b in bs]
    fit = fit_early_stop(xb, bb, [box_bin(psf, 2)] * 3, psf, candidates=(10, 30),
                         weights=(0.0,), binned_by=2, in_sample=True, field=False)
    image = solve_checkpoints(box_bin(psf, 2), bb[1], (30,))[30]
    assert fit.lead_errors[1, 0, 1, 1] == pytest.approx(gain_fitted_error(image, xb[1]),
                                                       rel=1e-9)
    # the held-out PSFs given were that same binned PSF: both errors agree
    np.testing.assert_allclose(fit.lead_errors[1], fit.lead_errors[0], rtol=1e-9)


def test_the_calibrations_fit_chooses_by_both_and_the_file_keeps_them(tmp_path):
    xs, bs = semiconvergent_pairs(ROWS, COLS, 3, seed=11)
    fit = fit_recipe(xs, bs, candidates=(5, 20), weights=(0.0,), bin_factor=1).fit
    assert fit.lead_errors is not None and fit.lead_errors.shape == (2, 1, 2, 3)
    assert "moved halfway at each count towards the errors with the PSF" in fit.method
    held_only = fit_recipe(xs, bs, candidates=(5, 20), weights=(0.0,), bin_factor=1,
                           in_sample=False).fit
    assert held_only.lead_errors is None
    assert "moved halfway" not in held_only.method
    path = tmp_path / "early_stop.json"
    path.write_text(json.dumps(fit.to_dict()))
    back = EarlyStop.load(path)
    np.testing.assert_allclose(back.lead_errors, fit.lead_errors, atol=1e-6)
    assert back.method == fit.method
    old = fit.to_dict()
    del old["lead_errors"]  # a file of the earlier form
    assert EarlyStop.from_dict(old).lead_errors is None


@pytest.mark.parametrize("bad, words", [
    (lambda d: d.update(lead_errors=[[[[float("nan")] * 3]]] * 2), "lead_errors"),
    (lambda d: d.update(lead_errors=[[[[0.1, 0.2]]]] * 2), "lead-channel errors of shape"),
    (lambda d: d.update(lead_errors=[[[[0.1] * 3]]]), "lead-channel errors of shape"),
])
def test_a_recipe_file_with_bad_lead_channel_errors_is_refused(bad, words):
    d = EarlyStop(5, (5,), np.full((1, 1, 1, 3), 0.1), psf_identity(np.ones((4, 4))),
                  lead_errors=np.full((2, 1, 1, 3), 0.2)).to_dict()
    assert d["lead_errors_axes"][1:] == ["threshold", "iterations", "pair"]
    EarlyStop.from_dict(d)  # as written: read back
    bad(d)
    with pytest.raises(ReconInputError, match=words):
        EarlyStop.from_dict(d)
