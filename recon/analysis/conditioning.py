"""Local condition number of the system matrix for groups of neighbouring point sources.

Following G. Kuo, *Exploiting Randomness in Computational Cameras and Displays*
(PhD dissertation, UC Berkeley, 2020), Sec. 4.4 ("Local condition number theory",
Fig. 4.5): if an oracle gave the support of the scene, the values of its k nonzero
voxels would be the least-squares solution with the k columns of ``A`` at that
support, and the worst noise amplification is that sub-matrix's condition number.
The worst case is a contiguous block of sources, so the analysis takes k
neighbouring sources at a given separation and lets k grow.

- :func:`local_condition_number` -- ``sigma_max / sigma_min`` of k columns.
- :func:`point_source_columns` -- the columns of ``A`` (Eq. 4.4, one depth) for point
  sources at lateral shifts of a PSF, cropped to the sensor.
- :func:`condition_vs_k` -- the condition number for k = 2 .. 16 neighbouring
  sources on a line or a grid at one separation (it approaches a limit).

Shifts are in sensor pixels, ``(dy, dx)`` = (rows, cols). Every refusal raises
:class:`recon.errors.ReconInputError` whose message says what is wrong and how to
fix it. Results are float64.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable
from typing import Any

import numpy as np
import scipy.ndimage

from recon.analysis.psf import _as_float
from recon.analysis.similarity import _check_image
from recon.errors import ReconInputError

__all__ = ["condition_vs_k", "local_condition_number", "point_source_columns"]


def local_condition_number(columns: Any) -> float:
    """Condition number (ratio of extreme singular values) of a matrix of k columns.

    Parameters
    ----------
    columns : array_like
        Either shape (m, k), m >= k >= 1: a matrix whose k columns are columns of
        the system matrix (e.g. from :func:`point_source_columns`); or shape
        (k, rows, cols): k images, each flattened into one column.

    Returns
    -------
    float
        ``sigma_max / sigma_min`` >= 1 of the (m, k) matrix; ``inf`` if it is rank
        deficient (``sigma_min`` = 0, e.g. two identical columns). Example: two unit
        columns with inner product ``c`` give ``sqrt((1 + |c|) / (1 - |c|))`` (the
        Gram matrix has eigenvalues ``1 +- c``; 3 for ``c = 0.8``).

    Raises
    ------
    ReconInputError
        If `columns` is not a finite 2D/3D numeric array, has more columns than
        rows, or is all zero.

    Notes
    -----
    Sec. 4.4: the condition number of the sub-matrix bounds how much measurement
    noise can be amplified in the least-squares estimate of the k source values
    with known support. Singular values from :func:`numpy.linalg.svd`
    (``compute_uv=False``), O(m k^2). Columns are not normalised: the columns of a
    shift-invariant ``A`` have equal norms unless part of a shifted PSF leaves the
    sensor.
    """
    a = _as_float(columns, "columns", ndims=(2, 3))
    if a.ndim == 3:
        a = a.reshape(a.shape[0], -1).T
    m, k = a.shape
    if k > m:
        raise ReconInputError(
            f"columns has shape {a.shape}: more columns ({k}) than rows ({m}), so the "
            "matrix is rank deficient; pass an (m, k) matrix with m >= k, or a (k, rows, "
            "cols) stack of images"
        )
    if not np.any(a):
        raise ReconInputError("columns is all zero; pass PSF columns with signal")
    sv = np.linalg.svd(a, compute_uv=False)
    smax, smin = float(sv[0]), float(sv[-1])
    if smin <= smax * np.finfo(np.float64).eps * max(m, k):
        return math.inf
    return smax / smin


def _shift_int(h: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``h`` translated by whole pixels ``(dy, dx)``, zeros shifted in (sensor crop)."""
    out = np.zeros_like(h)
    rows, cols = h.shape
    if abs(dy) >= rows or abs(dx) >= cols:
        return out
    src_r = slice(max(0, -dy), rows - max(0, dy))
    dst_r = slice(max(0, dy), rows - max(0, -dy))
    src_c = slice(max(0, -dx), cols - max(0, dx))
    dst_c = slice(max(0, dx), cols - max(0, -dx))
    out[dst_r, dst_c] = h[src_r, src_c]
    return out


def point_source_columns(psf: Any, positions_px: Any, *, order: int = 3) -> np.ndarray:
    """Columns of the system matrix for point sources at lateral shifts of a PSF.

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), the sensor image of a point source (one depth), real,
        finite, not all zero.
    positions_px : array_like
        Shape (k, 2): the sensor-plane shift ``(dy, dx)`` in pixels of each source's
        PSF relative to `psf` (an object-space shift ``Delta x`` at depth ``z`` is
        ``m Delta x`` with ``m = d/z``). A single pair is accepted as (2,).
    order : int, optional
        Spline order of :func:`scipy.ndimage.shift` for sub-pixel shifts (0-5,
        default 3). Integer shifts are exact copies.

    Returns
    -------
    numpy.ndarray
        float64, shape (rows * cols, k): column j is ``psf`` translated by
        ``positions_px[j]`` with zeros shifted in and whatever leaves the frame
        dropped (the sensor crop ``C`` of Eq. 4.4), flattened in C order.

    Raises
    ------
    ReconInputError
        If `psf` is invalid, `positions_px` is not finite of shape (k, 2), or
        `order` is not an integer in 0..5.

    Notes
    -----
    For a shift-invariant system (one depth of Eq. 4.4, ``b = C (h * v)``) the
    column of ``A`` for a point source is the PSF translated to that source's
    position and cropped to the sensor. Sub-pixel shifts use
    ``scipy.ndimage.shift(psf, (dy, dx), order=order, mode="constant")``.
    """
    h = _check_image(psf, "psf")
    pos = _as_float(positions_px, "positions_px", ndims=(1, 2))
    if pos.ndim == 1:
        pos = pos[None, :]
    if pos.shape[1] != 2:
        raise ReconInputError(
            f"positions_px must have shape (k, 2) of (dy, dx) shifts in pixels, got {pos.shape}"
        )
    if isinstance(order, bool) or not isinstance(order, numbers.Integral) or not 0 <= order <= 5:
        raise ReconInputError(f"order must be an integer in 0..5, got {order!r}")
    out = np.empty((h.size, pos.shape[0]), dtype=np.float64)
    for j, (dy, dx) in enumerate(pos):
        if float(dy).is_integer() and float(dx).is_integer():
            col = _shift_int(h, int(dy), int(dx))
        else:
            col = scipy.ndimage.shift(h, (dy, dx), order=int(order), mode="constant", cval=0.0)
        out[:, j] = col.ravel()
    return out


def _layout_positions(k_max: int, separation: float, layout: str, axis: str) -> np.ndarray:
    """Nested positions: the first k of them are the k-source arrangement for every k."""
    j = np.arange(k_max)
    if layout == "line":
        along = (j - (k_max - 1) // 2) * separation
        zeros = np.zeros(k_max)
        return np.stack([zeros, along] if axis == "x" else [along, zeros], axis=1)
    width = math.ceil(math.sqrt(k_max))
    height = math.ceil(k_max / width)
    rows = (j // width - (height - 1) // 2) * separation
    cols = (j % width - (width - 1) // 2) * separation
    return np.stack([rows, cols], axis=1)


def condition_vs_k(
    psf: Any,
    separation_px: float,
    ks: Iterable[int] = range(2, 17),
    *,
    layout: str = "line",
    axis: str = "x",
    order: int = 3,
) -> np.ndarray:
    """Local condition number for k neighbouring point sources at one separation (Fig. 4.5).

    Parameters
    ----------
    psf : array_like
        Shape (rows, cols), background-removed PSF at one depth.
    separation_px : float
        Sensor-plane distance between neighbouring sources in pixels (> 0);
        an object-space separation ``Delta x`` at depth ``z`` is ``Delta x d / z``
        on the sensor. Non-integer values use sub-pixel shifts (`order`).
    ks : iterable of int, optional
        Numbers of sources, each >= 1. Default 2 .. 16.
    layout : {"line", "grid"}, optional
        ``"line"`` (default): sources in a row along `axis`. ``"grid"``: sources
        filling a square grid of ``ceil(sqrt(max(ks)))`` columns in raster order
        (16 sources make a 4 x 4 grid).
    axis : {"x", "y"}, optional
        Direction of the line (columns or rows). Default "x".
    order : int, optional
        Spline order for sub-pixel shifts, as in :func:`point_source_columns`.

    Returns
    -------
    numpy.ndarray
        float64, shape (len(ks),): :func:`local_condition_number` of the first k
        sources for each k in `ks` (``inf`` where rank deficient).

    Raises
    ------
    ReconInputError
        If `psf` is invalid, `separation_px` is not finite and > 0, `ks` is empty
        or holds a value < 1 or more sources than pixels, or `layout` / `axis` is
        not one of the choices.

    Notes
    -----
    The source positions are nested: the arrangement for k sources is the first k
    positions of the arrangement for ``max(ks)`` (line or raster order, centred on
    the PSF's own position), so each sub-matrix holds the previous one and, by
    singular-value interlacing, the condition number never decreases with k. Sec.
    4.4 / Fig. 4.5: it grows with k and approaches a limit, larger the closer the
    sources; the limit, not the two-point value, governs complex scenes.
    """
    h = _check_image(psf, "psf")
    if (
        isinstance(separation_px, bool)
        or not isinstance(separation_px, numbers.Real)
        or not math.isfinite(float(separation_px))
        or float(separation_px) <= 0
    ):
        raise ReconInputError(
            f"separation_px must be finite and > 0, got {separation_px!r}; e.g. 2 (pixels)"
        )
    if layout not in ("line", "grid"):
        raise ReconInputError(f"layout must be 'line' or 'grid', got {layout!r}")
    if axis not in ("x", "y"):
        raise ReconInputError(f"axis must be 'x' or 'y', got {axis!r}")
    k_list = list(ks)
    if not k_list:
        raise ReconInputError("ks is empty; pass numbers of sources, e.g. range(2, 17)")
    for k in k_list:
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 1:
            raise ReconInputError(f"ks must hold integers >= 1, got {k!r}")
    k_max = int(max(k_list))
    if k_max > h.size:
        raise ReconInputError(
            f"{k_max} sources need more columns than the PSF's {h.size} pixels; use fewer"
        )
    sep = float(separation_px)
    positions = _layout_positions(k_max, sep, layout, axis)
    cols = point_source_columns(h, positions, order=order)
    return np.array([local_condition_number(cols[:, : int(k)]) for k in k_list], dtype=np.float64)
