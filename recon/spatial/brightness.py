"""Field brightness of a lensless camera from a PSF grid (the two-part model, Eq. 5.1).

Eq. 5.1 factors an off-axis PSF into the shifted on-axis caustic pattern times a
slowly varying brightness (sensor fall-off ``f(theta)``, inverse square and
obliquity). A reconstruction with the on-axis PSF alone (Eq. 3.3) therefore shows
the scene times the relative brightness ``B(x) / B(0)``: dark corners, the
lensless camera's vignetting. When the object is far the term is "grouped with
the sample" (Sec. 5.1); dividing the reconstruction by it undoes that grouping.

:func:`node_brightness` measures ``B(x_i) / B(0)`` at each node of a calibrated
grid: the registered PSF's light over the on-axis PSF's, both summed over the
pixels the sensor saw in both (light shifted past the sensor's edge is missing
data, not darkness). :func:`brightness_map` fits a quadratic in the node offsets
(a plane for grids of fewer than 3 x 3 nodes) and evaluates it on the object grid of
the cropped convolution model; :func:`correct_brightness` divides an image by it.
"""

from __future__ import annotations

import numpy as np

from ..errors import ReconInputError
from ..operators import padded_grid
from .grid import PsfGrid

__all__ = ["brightness_map", "caustic_grid", "correct_brightness", "node_brightness"]

#: Smallest relative brightness the map may reach: a correction of more than 10x
#: amplifies noise more than it restores (and means the fit is extrapolating).
MIN_BRIGHTNESS = 0.1


def node_brightness(grid: PsfGrid) -> np.ndarray:
    """Relative brightness ``B(x_i) / B(0)`` at each node of a registered grid.

    Parameters
    ----------
    grid : PsfGrid
        Registered PSFs of one depth (background-free, same exposure scale).

    Returns
    -------
    ndarray, float64, (N,)
        1 at the central node.

    Raises
    ------
    ReconInputError
        A node whose registered PSF shares no lit pixel with the central one.
    """
    valid = grid.valid_masks()
    c = grid.central
    out = np.empty(grid.n, np.float64)
    for i in range(grid.n):
        both = valid[i] & valid[c]
        ref = float(grid.psfs[c][both].sum(dtype=np.float64))
        if not ref > 0:
            raise ReconInputError(
                f"PSF {i} of the grid overlaps no light of the central PSF on the sensor; "
                "calibrate a grid whose nodes lie within the field of view")
        out[i] = float(grid.psfs[i][both].sum(dtype=np.float64)) / ref
    return out


def _basis(dy: np.ndarray, dx: np.ndarray, quadratic: bool) -> np.ndarray:
    cols = [np.ones_like(dy), dy, dx]
    if quadratic:
        cols += [dy * dy, dy * dx, dx * dx]
    return np.stack(cols, axis=-1)


def brightness_map(grid: PsfGrid) -> np.ndarray:
    """Relative brightness on the (cropped) object grid of the convolution model.

    Object pixel ``(r, c)`` of the sensor-sized field images to the central PSF
    shifted by its offset from the padded grid's centre (Eq. 3.4), which is where
    the nodes sit (``grid.shifts_px``). The node values of :func:`node_brightness`
    are fitted by least squares with a quadratic in the offsets (3 x 3 nodes or
    more; a plane otherwise) and the fit is evaluated per pixel.

    Parameters
    ----------
    grid : PsfGrid
        For a binned reconstruction, binned alike (:func:`recon.spatial.api.bin_grid`).

    Returns
    -------
    ndarray, float32, ``grid.sensor_shape``
        Clipped below at :data:`MIN_BRIGHTNESS`.

    Raises
    ------
    ReconInputError
        A grid of one node (no field to measure), or the errors of
        :func:`node_brightness`.
    """
    if grid.n < 2:
        raise ReconInputError("one PSF says nothing about the field's brightness; "
                              "calibrate a grid of at least 2 x 2 positions")
    shape = tuple(grid.sensor_shape)
    values = node_brightness(grid)
    ny, nx = grid.grid_shape
    quadratic = min(ny, nx) >= 3
    s = grid.shifts_px
    coef, *_ = np.linalg.lstsq(_basis(s[:, 0], s[:, 1], quadratic), values, rcond=None)
    padded, (top, left), _ = padded_grid(shape)
    dy = np.arange(shape[0], dtype=np.float64) + top - padded[0] // 2
    dx = np.arange(shape[1], dtype=np.float64) + left - padded[1] // 2
    yy, xx = np.meshgrid(dy, dx, indexing="ij")
    out = _basis(yy, xx, quadratic) @ coef
    return np.maximum(out, MIN_BRIGHTNESS).astype(np.float32)


def correct_brightness(image: np.ndarray, grid: PsfGrid) -> np.ndarray:
    """Divide a reconstruction by the field's relative brightness (Eq. 5.1).

    Parameters
    ----------
    image : ndarray, (rows, cols) or (rows, cols, channels)
        Reconstruction on the sensor-sized object grid (:func:`recon.reconstruct`'s
        ``image``), same rows and columns as the grid's PSFs.
    grid : PsfGrid
        Calibrated at the scene's depth.

    Returns
    -------
    ndarray, float32, same shape

    Raises
    ------
    ReconInputError
        An image whose shape differs from the grid's sensor, or the errors of
        :func:`brightness_map`.
    """
    img = np.asarray(image, np.float32)
    if img.shape[:2] != tuple(grid.sensor_shape) or img.ndim not in (2, 3):
        raise ReconInputError(
            f"image of shape {img.shape} does not match the PSF grid's sensor "
            f"{tuple(grid.sensor_shape)}; reconstruct at the grid's binning")
    m = brightness_map(grid)
    return img / (m if img.ndim == 2 else m[:, :, None])


def caustic_grid(grid: PsfGrid) -> PsfGrid:
    """The caustic factor of Eq. 5.1 at each node: the registered PSF over its brightness.

    Each registered PSF is divided by its relative brightness
    (:func:`node_brightness`), so every node's kernel carries the central PSF's light
    and only the caustic pattern differs between nodes. Where the sensor did not see
    a node's registered PSF (the light fell past its edge,
    :meth:`~recon.spatial.PsfGrid.valid_masks`) the pixel is taken from the nearest node
    that saw it (nearest in sensor offset; the central node sees its whole PSF): the
    pattern changes slowly over the field, so a neighbour's is the best estimate there
    is, where zeros would tell the local model that the light of points next to the
    node vanishes. Measured on the demo's 3 x 3 grid (corner PSFs shifted by 128 px on
    a 256 x 320 sensor): the local model of the filled caustics, 21.3 dB (ADMM, TV
    3e-4); of the PSFs as registered, unfilled, 19.3 dB (FISTA run to convergence, TV
    1e-4); the central PSF with the brightness divided out, 19.7 dB at its best TV.

    A far scene's reconstruction with a model of these kernels shows the scene times
    the relative brightness; divide it by :func:`brightness_map` (what
    :func:`correct_brightness` does).

    Parameters
    ----------
    grid : PsfGrid
        As for :func:`node_brightness`.

    Returns
    -------
    PsfGrid
        Same shifts, shape and depths; float32 kernels.

    Raises
    ------
    ReconInputError
        The errors of :func:`node_brightness`.
    """
    valid = grid.valid_masks()
    caustics = grid.psfs / node_brightness(grid)[:, None, None].astype(np.float32)
    shifts = grid.shifts_px
    out = np.empty_like(caustics)
    for i in range(grid.n):
        order = np.argsort(np.hypot(*(shifts - shifts[i]).T), kind="stable")
        filled = np.zeros(grid.sensor_shape, bool)
        for j in order:
            take = valid[j] & ~filled
            out[i][take] = caustics[j][take]
            filled |= take
            if filled.all():
                break
        out[i][~filled] = 0.0
    return PsfGrid(out, shifts, grid.grid_shape, grid.z_mm, grid.d_mm)
