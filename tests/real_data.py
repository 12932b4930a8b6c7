"""Shared access to the real DiffuserCam sample for tests (fails loudly if absent)."""

from __future__ import annotations

import numpy as np

from recon.sample import data_dir


def sample_paths():
    d = data_dir()  # raises, naming the missing files and DIFFUSERLAB_DATA
    return d / "psf_sample.tif", d / "rawdata_hand_sample.tif"


def check_hand_image(image: np.ndarray) -> None:
    """Non-degenerate reconstruction of the hand: non-negative, not constant, and
    most of its energy in a compact region (the hand on a dark background)."""
    assert image.ndim == 2 and np.all(np.isfinite(image))
    assert image.min() >= 0
    assert image.std() > 0.05 * image.mean()
    energy = np.sort(image.ravel().astype(np.float64) ** 2)[::-1]
    frac_pixels = np.searchsorted(np.cumsum(energy), 0.5 * energy.sum()) / energy.size
    # half the energy lies in under 10 % of the pixels (a uniform image needs 50 %)
    assert frac_pixels < 0.10, frac_pixels
    # and that compact region is one blob: the energy centroid of the brightest
    # 2 % of pixels is near the centroid of the whole image's energy
    rows, cols = np.nonzero(image > np.quantile(image, 0.98))
    spread = np.hypot(rows.std(), cols.std()) / np.hypot(*image.shape)
    assert spread < 0.25, spread
