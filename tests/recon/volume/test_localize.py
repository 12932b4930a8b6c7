"""Tests for recon.volume.localize: peak detection at sub-voxel precision and matching."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.volume.localize import detect_peaks, match_peaks


def blob_volume(centres, amplitudes, shape=(8, 32, 32), sigma=(0.7, 1.0, 1.0)):
    """Gaussian blobs at fractional (plane, row, col) centres."""
    grids = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    v = np.zeros(shape)
    for c, a in zip(centres, amplitudes, strict=True):
        r2 = sum(((g - ci) / s) ** 2 for g, ci, s in zip(grids, c, sigma, strict=True))
        v += a * np.exp(-0.5 * r2)
    return v


def split_point(v: np.ndarray, pos, amplitude: float) -> None:
    """Add a point at a fractional position, its mass split trilinearly over 8 voxels
    (how a reconstruction on the grid represents a source between voxels)."""
    base = np.floor(pos).astype(int)
    frac = np.asarray(pos) - base
    for corner in np.ndindex(2, 2, 2):
        w = np.prod([f if c else 1 - f for f, c in zip(frac, corner, strict=True)])
        v[tuple(base + np.array(corner))] += amplitude * w


def test_detects_points_brightest_first_at_subvoxel_positions():
    centres = [(2.0, 10.0, 12.0), (5.3, 20.0, 8.4), (4.0, 25.3, 24.0)]
    v = np.zeros((8, 32, 32))
    for c, a in zip(centres, [0.6, 1.0, 0.8], strict=True):
        split_point(v, c, a)
    v[0, 0, 0] = 0.1  # below the threshold
    peaks = detect_peaks(v, threshold=0.25)
    assert peaks.shape == (3, 3) and peaks.dtype == np.float64
    # brightest peak voxel first (0.6, 0.8 * 0.7, 1.0 * 0.7 * 0.6); the centroid undoes
    # the trilinear split exactly
    np.testing.assert_allclose(peaks, [centres[0], centres[2], centres[1]], atol=1e-9)
    assert detect_peaks(v, threshold=0.8).shape == (2, 3)
    assert detect_peaks(v, max_peaks=1).shape == (1, 3)


def test_local_mass_finds_a_source_split_between_voxels():
    v = np.zeros((6, 20, 20))
    split_point(v, (1.0, 5.0, 5.0), 1.0)       # on a voxel
    split_point(v, (3.5, 12.5, 12.5), 0.8)     # split equally over 8 voxels: 0.1 each
    assert detect_peaks(v, threshold=0.25).shape == (1, 3)
    peaks = detect_peaks(v, threshold=0.25, local_mass=True)
    np.testing.assert_allclose(peaks, [(1.0, 5.0, 5.0), (3.5, 12.5, 12.5)], atol=1e-9)


def test_blurred_blobs_within_a_fifth_of_a_voxel():
    centres = [(2.0, 10.0, 12.0), (5.5, 20.0, 8.0), (4.0, 25.3, 24.0)]
    peaks = detect_peaks(blob_volume(centres, [0.6, 1.0, 0.8]))
    # a Gaussian wider than the 3-voxel window: the centroid is pulled towards the
    # peak voxel (by 0.14 voxel here), never across it
    np.testing.assert_allclose(peaks, [centres[1], centres[2], centres[0]], atol=0.2)


def test_close_peaks_merge_within_the_radius_and_empty_volume():
    v = np.zeros((3, 12, 12))
    v[1, 5, 5], v[1, 5, 7] = 1.0, 0.9  # 2 px apart
    assert detect_peaks(v, radius_px=2).shape[0] == 1
    assert detect_peaks(v, radius_px=1).shape[0] == 2
    assert detect_peaks(np.zeros((2, 4, 4))).shape == (0, 3)
    assert detect_peaks(-np.ones((2, 4, 4))).shape == (0, 3)


def test_match_by_hand():
    truth = np.array([[1.0, 10.0, 10.0], [4.0, 20.0, 20.0], [6.0, 5.0, 30.0]])
    det = np.array([[4.0, 20.0, 23.0],   # 3 px lateral: inside the gate
                    [1.5, 10.0, 10.0],   # half a plane off
                    [0.0, 0.0, 0.0],     # nothing near: spurious
                    [6.0, 5.0, 34.0]])   # 4 px: outside, so bead 2 is missed
    m = match_peaks(det, truth, max_lateral_px=3.0, max_axial_planes=3.0)
    assert sorted(m["pairs"]) == [(0, 1), (1, 0)]
    order = [p[0] for p in m["pairs"]]
    lat = dict(zip(order, m["lateral_px"], strict=True))
    ax = dict(zip(order, m["axial_planes"], strict=True))
    assert lat == {0: 0.0, 1: 3.0} and ax == {0: 0.5, 1: 0.0}
    assert m["missed"] == [2] and m["spurious"] == [2, 3]
    # the assignment is optimal, not greedy: two detections compete for one bead
    m2 = match_peaks([[1.0, 10.0, 11.0], [1.0, 10.0, 10.5]], truth[:1])
    assert m2["pairs"] == [(0, 1)] and m2["spurious"] == [0]
    # nothing detected: all missed
    assert match_peaks(np.zeros((0, 3)), truth)["missed"] == [0, 1, 2]


@pytest.mark.parametrize("call,fragment", [
    (lambda: detect_peaks(np.ones((4, 4))), "3D"),
    (lambda: detect_peaks(np.full((2, 3, 3), np.nan)), "NaN"),
    (lambda: detect_peaks(np.ones((2, 3, 3)), threshold=0), "threshold"),
    (lambda: detect_peaks(np.ones((2, 3, 3)), radius_px=-1), "radius_px"),
    (lambda: detect_peaks(np.ones((2, 3, 3)), max_peaks=0), "max_peaks"),
    (lambda: match_peaks([[1, 2]], [[1, 2, 3]]), r"\(n, 3\)"),
    (lambda: match_peaks([[1, 2, 3]], [[1, 2, 3]], max_lateral_px=0), "max_lateral_px"),
])
def test_refusals(call, fragment):
    with pytest.raises(ReconInputError, match=fragment):
        call()
