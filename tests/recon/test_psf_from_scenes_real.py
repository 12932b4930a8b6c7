"""The PSF calibrated from known scenes on the shared real pairs (mirflickr-real),
scored on the pair left out; fails loudly if the data is absent (tests/real_data.py)."""

from __future__ import annotations

import pytest

from benchmarks.psf_from_scenes import NAMES, load_pairs
from recon.analysis.psf_from_scenes import leave_one_out


def test_leave_one_out_on_three_real_pairs_binned():
    """Three pairs binned 3 x 3 (90 x 160): 0.074 measured (a flat PSF: about 0.2)."""
    scenes, measurements = load_pairs(names=NAMES[:3], bin_factor=3)
    loo = leave_one_out(scenes, measurements)
    assert loo.mean <= 0.09, loo.residuals


@pytest.mark.slow
def test_leave_one_out_on_the_five_real_pairs():
    """All five pairs at full size (270 x 480): 0.079 measured, several minutes."""
    scenes, measurements = load_pairs()
    loo = leave_one_out(scenes, measurements)
    assert loo.mean <= 0.09, loo.residuals
