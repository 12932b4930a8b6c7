"""The grid an image is drawn at: no finer than the screen shows it.

A camera frame larger than its view on screen (a 2048 x 2448 sensor in a 600 x 500 px
view) is drawn from every ``step``-th pixel of every ``step``-th row: the lookup table,
the ``QImage`` and the scaled paint then cost what the screen can show, not what the
sensor holds. The view keeps the full-resolution array for the pixel readout, the ROI
statistics, the line profile and the snapshot (:class:`gui.imageview.FrameView`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["block_any", "display_step"]


def display_step(span_px: tuple[float, float], view_px: tuple[float, float]) -> int:
    """The stride at which an image is drawn: image pixels per screen pixel, rounded down.

    Parameters
    ----------
    span_px : (float, float)
        Width and height of the image region in view (columns, rows), image pixels.
    view_px : (float, float)
        Width and height of the view on screen, device pixels.

    Returns
    -------
    int
        1 (every pixel) when the view shows the region at one screen pixel per image
        pixel or larger (zoomed in), or before the view has a size; else the largest
        stride that still puts at least one drawn pixel on every screen pixel.
    """
    (span_x, span_y), (w, h) = span_px, view_px
    if w < 8 or h < 8 or not all(map(math.isfinite, (span_x, span_y))):
        return 1
    return max(1, int(min(span_x / w, span_y / h)))


def block_any(mask: np.ndarray, step: int) -> np.ndarray:
    """``mask`` on the grid drawn at ``step``: a drawn pixel is set when any pixel of its
    ``step`` x ``step`` block is (a saturated pixel between two drawn ones still shows).

    Parameters
    ----------
    mask : ndarray of bool, (rows, cols)
    step : int
        The stride (:func:`display_step`).

    Returns
    -------
    ndarray of bool, (ceil(rows / step), ceil(cols / step))
        ``mask`` itself when ``step`` is 1.
    """
    if step <= 1:
        return mask
    rows, cols = mask.shape
    r, c = -(-rows // step), -(-cols // step)
    padded = np.zeros((r * step, c * step), bool)
    padded[:rows, :cols] = mask
    return padded.reshape(r, step, c, step).any(axis=(1, 3))
