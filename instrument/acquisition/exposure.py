"""Acquisition helpers shared by the demo and the calibration plans.

Frame averaging and auto-exposure on any :class:`drivers.camera.Camera`; every
wait on the camera has a timeout (the camera's ``snap(timeout_s)``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from drivers.errors import DeviceError

log = logging.getLogger(__name__)


class ExposureError(DeviceError):
    """Auto-exposure cannot reach its target within the exposure bounds."""


def full_scale(camera) -> float:
    """Full scale of ``camera``'s frames at its pixel format, DN: 2^bit_depth - 1
    (mono12 frames sit in the low 12 bits of uint16, so the dtype maximum would be
    wrong)."""
    return float(2 ** int(camera.bit_depth) - 1)


def average_frames(camera, n: int, timeout_s: float = 5.0) -> tuple[np.ndarray, list]:
    """Mean of ``n`` snapped frames (float64) and the frames' metadata.

    Parameters
    ----------
    camera : drivers.camera.Camera
        Open camera.
    n : int
        Frames to average (>= 1).
    timeout_s : float
        Per-frame timeout, s.

    Returns
    -------
    mean : ndarray, float64, the camera's image shape
    frames : list of drivers.camera.Frame
        Metadata of every frame (index, timestamps, exposure, saturation), images
        dropped to keep memory flat.

    Raises
    ------
    ValueError
        ``n`` < 1.
    drivers.errors.CameraTimeoutError
        A frame did not arrive within ``timeout_s``.
    """
    if n < 1:
        raise ValueError(f"need at least one frame to average, got {n}")
    acc = None
    meta = []
    for _ in range(n):
        frame = camera.snap(timeout_s=timeout_s)
        acc = frame.image.astype(np.float64) if acc is None else acc + frame.image
        meta.append({"index": frame.index, "device_timestamp_s": frame.device_timestamp_s,
                     "exposure_s": frame.exposure_s, "gain": frame.gain,
                     "saturated_pixels": frame.saturated_pixels})
    return acc / n, meta


@dataclass
class ExposureResult:
    """Outcome of :func:`autoexpose`: the exposure set, the peak reached as a fraction
    of full scale (dark offset removed) and the number of trial frames."""

    exposure_s: float
    peak_fraction: float
    trials: int


def autoexpose(camera, *, target: float = 0.5, tolerance: float = 0.1,
               bounds_s: tuple[float, float] = (1e-5, 2.0), dark_level: float = 0.0,
               max_trials: int = 12, timeout_s: float = 5.0) -> ExposureResult:
    """Set the exposure so the brightest pixels sit at ``target`` of full scale.

    The peak is the 99.99th percentile of the frame minus ``dark_level`` (robust to
    hot pixels). The search keeps a bracket: the longest exposure seen unsaturated
    and the shortest seen saturated. An unsaturated frame scales the exposure
    proportionally (at most 8x, and never beyond the saturated bound: then the
    geometric mean of the bracket); a saturated frame bisects the bracket in log
    exposure (or divides by 8 without a lower bound). It stops when the peak is
    within ``tolerance`` of the target with no saturated pixel, or when the bracket
    is closed (the two bounds within 5 %): a sharp peak that saturates a few pixels
    before the percentile reaches the target then ends at the longest unsaturated
    exposure, with ``peak_fraction`` below the target.

    Parameters
    ----------
    camera : drivers.camera.Camera
        Open camera (not streaming).
    target, tolerance : float
        Target peak and accepted deviation, fractions of full scale.
    bounds_s : (float, float)
        Allowed exposure range, s.
    dark_level : float
        Offset to remove before measuring the peak, DN.
    max_trials : int
    timeout_s : float
        Per-frame timeout, s.

    Returns
    -------
    ExposureResult

    Raises
    ------
    ExposureError
        The target needs an exposure outside ``bounds_s`` (scene too dark or too
        bright) or was not reached in ``max_trials`` frames; the exposure is left at
        the last unsaturated value tried (or the last value if none).
    """
    full = full_scale(camera) - dark_level
    lo, hi = bounds_s
    best_ok: tuple[float, float] | None = None  # (exposure, peak) longest unsaturated
    sat_at = math.inf  # shortest saturated exposure
    for trial in range(1, max_trials + 1):
        exposure = camera.exposure_s
        frame = camera.snap(timeout_s=timeout_s)
        peak = (float(np.percentile(frame.image, 99.99)) - dark_level) / full
        if frame.saturated_pixels:
            sat_at = min(sat_at, exposure)
        else:
            if best_ok is None or exposure > best_ok[0]:
                best_ok = (exposure, peak)
            if abs(peak - target) <= tolerance:
                return ExposureResult(exposure, peak, trial)
        if best_ok is not None and sat_at <= best_ok[0] * 1.05:
            camera.exposure_s = best_ok[0]
            return ExposureResult(best_ok[0], best_ok[1], trial)
        if frame.saturated_pixels:
            new = math.sqrt(best_ok[0] * sat_at) if best_ok is not None else exposure / 8
        else:
            new = exposure * min(8.0, target / max(peak, 1e-3))
            if new >= sat_at:
                new = math.sqrt(exposure * sat_at)
        if not lo <= new <= hi:
            if (new > hi and exposure >= hi) or (new < lo and exposure <= lo):
                if best_ok is not None:
                    camera.exposure_s = best_ok[0]
                raise ExposureError(
                    camera.device_id,
                    f"peak {peak:.2f} of full scale needs exposure {new:.3g} s, outside "
                    f"{lo:g}-{hi:g} s",
                    "change the light level (LED brightness, source power) or the bounds",
                )
            new = min(max(new, lo), hi)
        camera.exposure_s = new
        log.debug("autoexpose trial %d: peak %.3f -> exposure %.4g s", trial, peak, new)
    if best_ok is not None:
        camera.exposure_s = best_ok[0]
    raise ExposureError(camera.device_id, f"target not reached in {max_trials} frames",
                        "check for flicker or a moving scene, or raise max_trials")
