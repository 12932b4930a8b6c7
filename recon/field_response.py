"""A scene calibration's field response: a smooth gain over the field of view.

The forward model (Eq. 3.4) is shift-invariant: one PSF for every point of the field.
A real lensless camera is not quite: the sensor's angular acceptance and the
diffuser's falloff make the off-axis field dimmer than the model says, and the
reconstruction puts light where a calibration's scenes never had any (outside the
monitor that showed them). A scene-calibrated recipe (:class:`recon.early_stop.EarlyStop`)
may therefore carry a gain per point of the field, fitted on its calibration pairs'
held-out reconstructions (:func:`recon.analysis.field_response.fit_field_response`)
and kept only where it lowered the error of pairs it was not fitted on. The gain is
stored on a coarse grid (one node per :data:`STEP_PX` pixels of the PSF, each node the
least-squares gain of the smoothed neighbourhood), and applied, bilinearly
interpolated to the image's size, by multiplying the reconstructed image
(:func:`apply_field_response`).

Where the calibration scenes were dark in every pair the gain is near 0: a recipe with
a field response reconstructs the calibrated field of view, which is the field its
scenes filled (docs/calibration.md).
"""

from __future__ import annotations

import numpy as np

from .errors import ReconInputError

__all__ = ["STEP_PX", "apply_field_response", "check_field_response", "field_gain",
           "field_gain_like", "resample_evenly"]

#: Pixels of the full-size PSF per node of the field response's grid; the gain is
#: smoothed over about this scale (a Gaussian of 0.8 of it) before it is sampled.
STEP_PX = 10


def resample_evenly(values, shape) -> np.ndarray:
    """A 2D array bilinearly resampled onto ``shape``, both grids covering the same
    field evenly (sample ``i`` of ``n`` at the centre of the ``i``-th of ``n`` equal
    strips): a grid's nodes from an image, or an image from a grid's nodes.

    Parameters
    ----------
    values : array_like, (rows, cols), real
    shape : tuple of int
        ``(rows, cols, ...)`` of the result (only the first two are used).

    Returns
    -------
    ndarray, float64, (shape[0], shape[1])
        Bilinear between samples, the nearest sample's value beyond the outer ones.
    """
    from scipy.ndimage import map_coordinates

    v = np.asarray(values, np.float64)
    r, c = ((np.arange(n) + 0.5) * side / n - 0.5
            for n, side in zip((int(shape[0]), int(shape[1])), v.shape, strict=True))
    rr, cc = np.meshgrid(r, c, indexing="ij")
    return map_coordinates(v, [rr, cc], order=1, mode="nearest")


def field_gain(grid, shape) -> np.ndarray:
    """The field response ``grid`` interpolated to an image of ``shape``.

    The grid's nodes cover the field evenly (node ``i`` of ``n`` at the centre of the
    ``i``-th of ``n`` equal strips), so a binned image gets the same field response.

    Parameters
    ----------
    grid : array_like, (n_rows, n_cols), float
        The gains, >= 0 (:func:`check_field_response`).
    shape : tuple of int
        ``(rows, cols, ...)`` of the image.

    Returns
    -------
    ndarray, float32, (rows, cols)
        Bilinear between nodes, the nearest node's value beyond the outer ones.
    """
    return resample_evenly(grid, shape).astype(np.float32)


def field_gain_like(grid, image) -> np.ndarray:
    """:func:`field_gain` of ``grid`` for ``image``, shaped to broadcast against it
    (every colour channel alike).

    Parameters
    ----------
    grid : array_like, (n_rows, n_cols), float
    image : ndarray, (rows, cols) or (rows, cols, channels)

    Returns
    -------
    ndarray, float32, (rows, cols) or (rows, cols, 1)
    """
    g = field_gain(grid, image.shape)
    return g[..., None] if image.ndim == 3 else g


def apply_field_response(image, grid, *, divide: bool = False) -> np.ndarray:
    """``image`` multiplied by the field response ``grid`` (every channel alike), or
    divided by it.

    Parameters
    ----------
    image : array_like, (rows, cols) or (rows, cols, channels), real
    grid : array_like, (n_rows, n_cols), or None
        None: the image unchanged (as float32).
    divide : bool
        Divide by the gain instead: a response to take out of a measurement
        (:func:`recon.analysis.sensor_response.remove_sensor_response`; every gain > 0).

    Returns
    -------
    ndarray, float32, the image's shape
    """
    x = np.asarray(image, np.float32)
    if grid is None:
        return x.copy()
    gain = field_gain_like(grid, x)
    return (x / gain if divide else x * gain).astype(np.float32)


def check_field_response(value) -> np.ndarray:
    """A field response read from a file: a 2D grid of finite gains >= 0.

    Parameters
    ----------
    value : nested list or array_like

    Returns
    -------
    ndarray, float64, (n_rows, n_cols)

    Raises
    ------
    ReconInputError
        Not a 2D grid with at least one node, or a negative or non-finite gain.
    """
    try:
        g = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        g = np.asarray([np.nan])
    if g.ndim != 2 or g.size == 0 or not np.all(np.isfinite(g)) or g.min() < 0:
        raise ReconInputError("early-stop calibration: field_response must be a 2D grid "
                              "of finite gains >= 0 (give the file a PSF-from-scenes "
                              "calibration wrote, or calibrate again)")
    return g
