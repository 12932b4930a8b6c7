"""Activity in fluorescence videos: ΔF/F against a per-pixel percentile baseline.

Following G. Kuo, *Exploiting Randomness in Computational Cameras and Displays* (PhD
dissertation, UC Berkeley, 2020), Fig. 6.5b: the change in fluorescence of a
reconstructed video, compared to a 20th-percentile baseline, shows neural activity.

Bad input raises :class:`recon.errors.ReconInputError` naming the problem and the fix.
"""

from __future__ import annotations

import numpy as np

from recon.errors import ReconInputError
from recon.validate import float_array

__all__ = ["delta_f_over_f"]


def delta_f_over_f(stack: np.ndarray, percentile: float = 20.0, *,
                   min_baseline: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ΔF/F of a video: ``(F - F0) / F0`` with ``F0`` the per-pixel ``percentile`` over time.

    Parameters
    ----------
    stack : ndarray, (frames, ...), real
        The video (e.g. reconstructions, ``(T, rows, cols)``, or traces ``(T, cells)``);
        time on the first axis. At least 2 frames.
    percentile : float
        Baseline percentile in [0, 100] (Kuo 2020, Fig. 6.5b: 20). A percentile below
        the fraction of time a pixel is at rest makes ``F0`` its resting level.
    min_baseline : float, optional
        Pixels whose baseline is below this (background of a reconstruction, where
        ``F0`` is about 0 and the ratio is noise) get ΔF/F = 0. Default: 1e-3 of the
        largest baseline.

    Returns
    -------
    dff : ndarray, float32, same shape as ``stack``
        ΔF/F (dimensionless; 1 = the fluorescence doubled).
    baseline : ndarray, float32, ``stack.shape[1:]``
        ``F0`` per pixel, in the unit of ``stack``.

    Raises
    ------
    ReconInputError
        Fewer than 2 frames, non-finite values, a percentile outside [0, 100], or a
        negative ``min_baseline``.
    """
    f = float_array(stack, "stack", ndims=None)
    if f.ndim < 1 or f.shape[0] < 2:
        raise ReconInputError(f"stack of shape {f.shape}: ΔF/F needs at least 2 frames on "
                              "its first (time) axis")
    if isinstance(percentile, bool) or not isinstance(percentile, int | float) or \
            not 0 <= percentile <= 100:
        raise ReconInputError(f"percentile={percentile!r}: give a percentile in [0, 100] "
                              "(e.g. 20)")
    baseline = np.percentile(f, percentile, axis=0)
    if min_baseline is None:
        min_baseline = 1e-3 * float(baseline.max()) if baseline.size else 0.0
    elif isinstance(min_baseline, bool) or not isinstance(min_baseline, int | float) or \
            not 0 <= min_baseline < float("inf"):
        raise ReconInputError(f"min_baseline={min_baseline!r}: give a level >= 0 in the "
                              "stack's unit")
    valid = baseline > max(float(min_baseline), 0.0)
    safe = np.where(valid, baseline, 1.0)
    dff = np.where(valid, (f - baseline) / safe, 0.0)
    return dff.astype(np.float32), baseline.astype(np.float32)
