"""recon.analysis.delta_f_over_f: the percentile baseline and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from recon.analysis import delta_f_over_f
from recon.errors import ReconInputError


def test_resting_level_is_the_baseline_and_dff_is_exact():
    rng = np.random.default_rng(0)
    t, rows, cols = 50, 4, 5
    f0 = rng.uniform(10, 100, (rows, cols))
    active = np.zeros((t, rows, cols))
    active[rng.random((t, rows, cols)) < 0.3] = 1.0  # active 30 % of the time, at rest 70 %
    change = active * rng.uniform(0.5, 3.0, (t, rows, cols))
    dff, baseline = delta_f_over_f(f0 * (1 + change), 20)
    np.testing.assert_allclose(baseline, f0, rtol=1e-6)
    np.testing.assert_allclose(dff, change, rtol=1e-5, atol=1e-6)
    assert dff.dtype == np.float32 and dff.shape == (t, rows, cols)


def test_background_below_min_baseline_is_zero_not_noise():
    f = np.zeros((10, 3))
    f[:, 0] = 50 + np.arange(10)
    f[:, 1] = 1e-6 * np.arange(10)  # background of a reconstruction
    dff, _ = delta_f_over_f(f)
    assert np.all(dff[:, 1] == 0) and np.all(dff[:, 2] == 0)
    assert dff[-1, 0] > 0.1
    dff, _ = delta_f_over_f(f, min_baseline=0.0)
    assert dff[-1, 1] > 1  # the ratio of tiny numbers, when asked for


@pytest.mark.parametrize("stack, kwargs, words", [
    (np.ones((1, 4)), {}, "at least 2 frames"),
    (np.full((3, 4), np.nan), {}, "NaN"),
    (np.ones((3, 4)), {"percentile": 120}, "percentile=120"),
    (np.ones((3, 4)), {"percentile": True}, "percentile=True"),
    (np.ones((3, 4)), {"min_baseline": -1.0}, "min_baseline=-1.0"),
])
def test_bad_input_is_refused_naming_it(stack, kwargs, words):
    with pytest.raises(ReconInputError, match=words):
        delta_f_over_f(stack, **kwargs)
