"""Host-side image steps shared by the real camera drivers: unpack, demosaic, crop,
bin, pixel format.

A real camera delivers a raw region (its hardware ROI, aligned to the camera's
increments) in its native pixel format. Packed formats are unpacked
(:func:`unpack_lsb`: GenICam PFNC's LSB-first packing of Mono10p and Mono12p), a
colour mosaic is demosaiced (:func:`demosaic`, OpenCV's bilinear Bayer conversion) when
an RGB image is asked for, and :func:`frame_image` turns the result into the image of
the :class:`~drivers.camera.Camera` conventions: the exact requested ROI, binned by
block averages on the pixel-format scale, as uint8 (8-bit formats) or uint16 (mono10
holding 0..1023, mono12 0..4095, mono16 on the full 16-bit scale), and counts the
saturated pixels.
"""

from __future__ import annotations

import numpy as np

from drivers.camera import format_bits

__all__ = ["BAYER_PATTERNS", "aligned_region", "demosaic", "frame_image", "unpack_lsb",
           "unpack_mono10p", "unpack_mono12p"]

#: GenICam Bayer pattern names (the colours of the first row's first two pixels, then
#: the second row's) and the OpenCV conversion that demosaics them: OpenCV names its
#: codes after the 2x2 block one row and one column in, so GenICam "RG" (R G / G B) is
#: OpenCV's "BayerBG" (checked in tests/drivers/test_camera_formats.py).
BAYER_PATTERNS: dict[str, str] = {"RG": "COLOR_BayerBG2RGB", "GR": "COLOR_BayerGB2RGB",
                                  "GB": "COLOR_BayerGR2RGB", "BG": "COLOR_BayerRG2RGB"}


def unpack_lsb(data: bytes | np.ndarray, count: int, bits: int) -> np.ndarray:
    """Unpack pixels of ``bits`` bits (<= 16) packed LSB first into a little-endian bit
    stream: pixel k holds stream bits ``k * bits .. (k + 1) * bits - 1`` (GenICam PFNC
    "p" formats: Mono10p, 4 pixels in 5 bytes; Mono12p, 2 pixels in 3 bytes).

    Parameters
    ----------
    data : bytes or ndarray
        The packed buffer (``ceil(count * bits / 8)`` bytes; missing ones read as 0).
    count : int
        Pixels to unpack.
    bits : int
        Bits per pixel, 1..16.

    Returns
    -------
    ndarray
        ``(count,)`` uint16 in ``0 .. 2**bits - 1``.
    """
    n = -(-count * bits // 8)
    buf = np.zeros(n + 2, np.uint32)
    raw = np.frombuffer(bytes(data), np.uint8, count=min(len(data), n))
    buf[:raw.size] = raw
    start = np.arange(count, dtype=np.int64) * bits
    byte, shift = start // 8, (start % 8).astype(np.uint32)
    word = buf[byte] | buf[byte + 1] << 8 | buf[byte + 2] << 16
    return ((word >> shift) & ((1 << bits) - 1)).astype(np.uint16)


def unpack_mono10p(data: bytes | np.ndarray, count: int) -> np.ndarray:
    """GenICam PFNC Mono10p: ``(count,)`` uint16 0..1023 (:func:`unpack_lsb`)."""
    return unpack_lsb(data, count, 10)


def unpack_mono12p(data: bytes | np.ndarray, count: int) -> np.ndarray:
    """GenICam PFNC Mono12p: ``(count,)`` uint16 0..4095 (:func:`unpack_lsb`)."""
    return unpack_lsb(data, count, 12)


def demosaic(mosaic: np.ndarray, pattern: str) -> np.ndarray:
    """Bilinear demosaicing of a Bayer mosaic (OpenCV ``cvtColor``).

    Parameters
    ----------
    mosaic : ndarray
        ``(rows, cols)`` uint8 or uint16 raw colour mosaic, the pattern at its origin.
    pattern : str
        "RG", "GR", "GB" or "BG" (GenICam's ``BayerRG8`` etc.).

    Returns
    -------
    ndarray
        ``(rows, cols, 3)`` red, green, blue, the dtype of ``mosaic``.
    """
    import cv2

    return cv2.cvtColor(np.ascontiguousarray(mosaic), getattr(cv2, BAYER_PATTERNS[pattern]))


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
        ``(rows, cols)`` (or ``(rows, cols, 3)`` demosaiced) uint8 or uint16 raw region
        as the camera sent it.
    offset : (dx, dy)
        Position of the requested ROI inside ``raw``.
    size : (width, height)
        Requested ROI size in pixels.
    binning : int
        Block size (>= 1); partial blocks at the right/bottom edge are dropped.
    source_bits : int
        Significant bits of ``raw`` (8 for Mono8, 12 for Mono12 in 16-bit words, 16).
    pixel_format : str
        Target format: a name of :data:`~drivers.camera.PIXEL_FORMATS` or
        :data:`~drivers.camera.EXTRA_FORMATS`.

    Returns
    -------
    image : ndarray
        ``(height // binning, width // binning)`` (and the channels of ``raw``) uint8
        (8-bit formats) or uint16.
    saturated : int
        Pixels of the unbinned ROI at the raw full scale ``2**source_bits - 1`` (in
        any channel).

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
    full = roi >= (1 << source_bits) - 1
    saturated = int(np.count_nonzero(full.any(axis=-1) if roi.ndim == 3 else full))
    b = int(binning)
    if b > 1:
        hb, wb = h // b, w // b
        blocks = roi[: hb * b, : wb * b].reshape(hb, b, wb, b, *roi.shape[2:])
        data = np.rint(blocks.mean(axis=(1, 3), dtype=np.float64))
    else:
        data = roi
    bits = format_bits(pixel_format)
    shift = bits - source_bits
    if shift > 0:
        data = np.left_shift(data.astype(np.uint32), shift)
    elif shift < 0:
        data = np.right_shift(data.astype(np.uint32), -shift)
    dtype = np.uint8 if bits == 8 else np.uint16
    return np.ascontiguousarray(data, dtype=dtype), saturated
