"""Host-side image steps shared by the real camera drivers: crop, bin, pixel format.

A real camera delivers a raw region (its hardware ROI, aligned to the camera's
increments) in its native pixel format. :func:`frame_image` turns it into the image
of the :class:`~drivers.camera.Camera` conventions: the exact requested ROI, binned by
block averages on the pixel-format scale, as uint8 (mono8) or uint16 (mono12 holding
0..4095, mono16 on the full 16-bit scale), and counts the saturated pixels.
"""

from __future__ import annotations

import numpy as np

from drivers.camera import PIXEL_FORMATS

__all__ = ["aligned_region", "frame_image"]


def aligned_region(
    roi: tuple[int, int, int, int], sensor: tuple[int, int],
    increments: tuple[int, int, int, int], minimum: tuple[int, int] = (1, 1),
) -> tuple[tuple[int, int, int, int], tuple[int, int]]:
    """The smallest hardware region on the camera's grid that covers ``roi``.

    Parameters
    ----------
    roi : (x, y, width, height)
        Requested region in sensor pixels.
    sensor : (rows, cols)
        Sensor size in pixels.
    increments : (x_offset, y_offset, width, height)
        The camera's steps for offsets and sizes (GenICam ``Inc``), >= 1.
    minimum : (width, height)
        The smallest width and height the camera accepts.

    Returns
    -------
    region : (x, y, width, height)
        Hardware region, ``region`` contains ``roi``.
    offset : (dx, dy)
        Position of ``roi`` inside ``region`` (what the host crops away).
    """
    x, y, w, h = (int(v) for v in roi)
    rows, cols = sensor
    xi, yi, wi, hi = (max(1, int(v)) for v in increments)
    x0, y0 = x // xi * xi, y // yi * yi
    w0 = max(-(-(x + w - x0) // wi) * wi, minimum[0])
    h0 = max(-(-(y + h - y0) // hi) * hi, minimum[1])
    while x0 + w0 > cols and x0 >= xi:  # the covering width runs off the sensor: shift left
        x0 -= xi
    while y0 + h0 > rows and y0 >= yi:
        y0 -= yi
    w0, h0 = min(w0, cols - x0), min(h0, rows - y0)
    return (x0, y0, w0, h0), (x - x0, y - y0)


def frame_image(
    raw: np.ndarray, offset: tuple[int, int], size: tuple[int, int], binning: int,
    source_bits: int, pixel_format: str,
) -> tuple[np.ndarray, int]:
    """Crop, bin and convert one raw frame to the Camera conventions.

    Parameters
    ----------
    raw : ndarray
        ``(rows, cols)`` uint8 or uint16 raw region as the camera sent it.
    offset : (dx, dy)
        Position of the requested ROI inside ``raw``.
    size : (width, height)
        Requested ROI size in pixels.
    binning : int
        Block size (>= 1); partial blocks at the right/bottom edge are dropped.
    source_bits : int
        Significant bits of ``raw`` (8 for Mono8, 12 for Mono12 in 16-bit words, 16).
    pixel_format : str
        Target format, a key of :data:`~drivers.camera.PIXEL_FORMATS`.

    Returns
    -------
    image : ndarray
        ``(height // binning, width // binning)`` uint8 (mono8) or uint16.
    saturated : int
        Pixels of the unbinned ROI at the raw full scale ``2**source_bits - 1``.

    Raises
    ------
    ValueError
        The ROI does not fit inside ``raw``.
    """
    dx, dy = offset
    w, h = size
    if dy + h > raw.shape[0] or dx + w > raw.shape[1]:
        raise ValueError(f"roi {size} at {offset} exceeds the raw frame {raw.shape}")
    roi = raw[dy:dy + h, dx:dx + w]
    saturated = int(np.count_nonzero(roi >= (1 << source_bits) - 1))
    b = int(binning)
    if b > 1:
        hb, wb = h // b, w // b
        blocks = roi[: hb * b, : wb * b].reshape(hb, b, wb, b)
        data = np.rint(blocks.mean(axis=(1, 3), dtype=np.float64))
    else:
        data = roi
    shift = PIXEL_FORMATS[pixel_format] - source_bits
    if shift > 0:
        data = np.left_shift(data.astype(np.uint32), shift)
    elif shift < 0:
        data = np.right_shift(data.astype(np.uint32), -shift)
    dtype = np.uint8 if pixel_format == "mono8" else np.uint16
    return np.ascontiguousarray(data, dtype=dtype), saturated
