"""Bead localisation in a reconstructed volume: peak detection and matching to truth.

Used to score 3D reconstructions of point sources (beads, Kuo 2020 Sec. 4.4-4.5):
:func:`detect_peaks` finds local maxima of a volume ``(n_z, rows, cols)`` and refines
them to sub-voxel positions; :func:`match_peaks` pairs detected peaks with the true
positions (optimal assignment within a gate) and reports the lateral and axial
errors, the missed true beads and the spurious detections.

Positions are in voxel units ``(plane, row, col)`` (float64): planes count along the
depth grid (uniform in 1/z for a calibration sweep of Eq. 4.7, so one plane is one
1/z step), rows and columns are lateral pixels of the reconstruction grid. The
caller converts to object space (lateral ``px * pitch * z / d``, axial via the
plane depths).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from ..errors import ReconInputError

__all__ = ["detect_peaks", "match_peaks"]


def _volume(v) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.ndim != 3 or min(a.shape) < 1:
        raise ReconInputError(f"volume must be 3D (n_z, rows, cols), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ReconInputError("volume contains NaN or inf")
    return a


def detect_peaks(volume, *, threshold: float = 0.25, radius_px: int = 2,
                 radius_planes: int = 1, max_peaks: int = 1000,
                 local_mass: bool = False) -> np.ndarray:
    """Local maxima of a volume above a fraction of its maximum, at sub-voxel precision.

    A voxel is a peak when it is the maximum of its ``(2 radius_planes + 1) x
    (2 radius_px + 1)^2`` neighbourhood (:func:`scipy.ndimage.maximum_filter`,
    constant 0 outside; ties: the first in C order) and at least ``threshold`` times
    the volume's maximum. With ``local_mass`` the detection runs on the local mass
    instead, the sum of the non-negative values over each voxel's 3 x 3 x 3
    neighbourhood: a source whose reconstruction is split over two planes and four
    pixels (it sits between voxels) then scores its whole mass, not a quarter of it
    in one voxel. Each peak is refined by the intensity-weighted centroid of the
    non-negative values of ``volume`` in its 3 x 3 x 3 neighbourhood (clipped at
    the volume's border), so a bead spread over two planes lands between them.

    Parameters
    ----------
    volume : array_like, shape (n_z, rows, cols)
        Real, finite; e.g. the sensor field of view of a reconstruction,
        ``x[:, op.crop[0], op.crop[1]]``.
    threshold : float
        Fraction of the maximum a peak must reach, in (0, 1].
    radius_px, radius_planes : int
        Half sizes (>= 0) of the neighbourhood a peak must dominate: peaks closer
        than this merge.
    max_peaks : int
        At most this many peaks, brightest first (>= 1).
    local_mass : bool
        Detect on the 3 x 3 x 3 local mass (see above) rather than on voxel values.

    Returns
    -------
    ndarray, float64, shape (n_peaks, 3)
        ``(plane, row, col)`` of each peak, brightest first; empty (0, 3) when the
        volume has no positive value. Candidates whose refined positions fall within
        ``radius_planes`` planes and ``radius_px`` pixels of a brighter peak (ties,
        plateaus) are dropped.

    Raises
    ------
    ReconInputError
        Not a finite 3D array, or invalid threshold, radii or ``max_peaks``.
    """
    v = _volume(volume)
    if not (isinstance(threshold, int | float) and 0 < threshold <= 1):
        raise ReconInputError(f"threshold must be in (0, 1], got {threshold!r}")
    for name, r in (("radius_px", radius_px), ("radius_planes", radius_planes)):
        if isinstance(r, bool) or not isinstance(r, int) or r < 0:
            raise ReconInputError(f"{name} must be an integer >= 0, got {r!r}")
    if isinstance(max_peaks, bool) or not isinstance(max_peaks, int) or max_peaks < 1:
        raise ReconInputError(f"max_peaks must be an integer >= 1, got {max_peaks!r}")
    score = ndimage.uniform_filter(np.clip(v, 0.0, None), 3, mode="constant") * 27.0 \
        if local_mass else v
    top = float(score.max())
    if not top > 0:
        return np.zeros((0, 3), np.float64)
    size = (2 * radius_planes + 1, 2 * radius_px + 1, 2 * radius_px + 1)
    local = ndimage.maximum_filter(score, size=size, mode="constant", cval=0.0)
    cand = np.argwhere((score == local) & (score >= threshold * top))
    order = np.argsort(-score[tuple(cand.T)], kind="stable")
    kept: list[np.ndarray] = []
    for idx in cand[order]:
        pos = _centroid(v, idx)
        # a plateau of equal maxima (or a tie) gives several candidates: keep the first
        if any(abs(pos[0] - q[0]) <= radius_planes and math.hypot(*(pos[1:] - q[1:]))
               <= radius_px for q in kept):
            continue
        kept.append(pos)
        if len(kept) == max_peaks:
            break
    out = np.asarray(kept, np.float64).reshape(-1, 3)
    return out


def _centroid(v: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Weighted centroid of the non-negative values in the 3 x 3 x 3 box around ``idx``."""
    lo = np.maximum(idx - 1, 0)
    hi = np.minimum(idx + 2, v.shape)
    w = np.clip(v[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]], 0.0, None)
    grids = np.meshgrid(*(np.arange(a, b) for a, b in zip(lo, hi, strict=True)), indexing="ij")
    total = float(w.sum())
    if not total > 0:  # only possible for a local-mass peak without positive values
        return idx.astype(np.float64)
    return np.array([float((g * w).sum()) / total for g in grids])


def match_peaks(detected, truth, *, max_lateral_px: float = 3.0,
                max_axial_planes: float = 3.0) -> dict:
    """Pair detected peaks with true positions and measure the errors.

    The pairing minimises the total squared distance ``(d_row^2 + d_col^2) /
    max_lateral_px^2 + d_plane^2 / max_axial_planes^2`` (Hungarian algorithm,
    :func:`scipy.optimize.linear_sum_assignment`) over the pairs inside the gate
    ``hypot(d_row, d_col) <= max_lateral_px`` and ``|d_plane| <= max_axial_planes``;
    a true position left without a partner is *missed*, a detection left over is
    *spurious*. The gate should be wider than the accuracy being tested (a bead
    found two planes off is then reported as an axial error of 2, not as missed).

    Parameters
    ----------
    detected : array_like, shape (n_det, 3)
        ``(plane, row, col)`` of the detections (e.g. :func:`detect_peaks`).
    truth : array_like, shape (n_true, 3)
        ``(plane, row, col)`` of the true positions (fractional).
    max_lateral_px, max_axial_planes : float
        Gate, > 0.

    Returns
    -------
    dict
        ``pairs``: list of ``(truth_index, detected_index)``; ``lateral_px`` and
        ``axial_planes`` (float64 arrays, one per pair, in ``pairs`` order):
        ``hypot(d_row, d_col)`` and the signed ``plane_detected - plane_true``;
        ``missed``: indices of unmatched true positions; ``spurious``: indices of
        unmatched detections.

    Raises
    ------
    ReconInputError
        Arrays not of shape (n, 3), not finite, or a gate that is not positive.
    """
    pos = []
    for name, a in (("detected", detected), ("truth", truth)):
        arr = np.asarray(a, dtype=np.float64).reshape(-1, 3) if np.size(a) == 0 \
            else np.asarray(a, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != 3 or not np.all(np.isfinite(arr)):
            raise ReconInputError(
                f"{name} positions must be a finite (n, 3) array of (plane, row, col), "
                f"got shape {arr.shape}")
        pos.append(arr)
    det, tru = pos
    for name, g in (("max_lateral_px", max_lateral_px), ("max_axial_planes", max_axial_planes)):
        if not (isinstance(g, int | float) and math.isfinite(g) and g > 0):
            raise ReconInputError(f"{name} must be finite and > 0, got {g!r}")
    d = det[None, :, :] - tru[:, None, :]  # (n_true, n_det, 3)
    lat = np.hypot(d[..., 1], d[..., 2])
    inside = (lat <= max_lateral_px) & (np.abs(d[..., 0]) <= max_axial_planes)
    cost = (lat / max_lateral_px) ** 2 + (d[..., 0] / max_axial_planes) ** 2
    big = 1e6 + 10.0 * float(cost.size)
    pairs = []
    if inside.any():
        rows, cols = linear_sum_assignment(np.where(inside, cost, big))
        pairs = [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if inside[r, c]]
    matched_t = {p[0] for p in pairs}
    matched_d = {p[1] for p in pairs}
    return {
        "pairs": pairs,
        "lateral_px": np.array([lat[t, k] for t, k in pairs], np.float64),
        "axial_planes": np.array([d[t, k, 0] for t, k in pairs], np.float64),
        "missed": [i for i in range(len(tru)) if i not in matched_t],
        "spurious": [k for k in range(len(det)) if k not in matched_d],
    }
