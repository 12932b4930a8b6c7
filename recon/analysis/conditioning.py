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
- :func:`stack_source_columns`, :func:`axial_layout` and :func:`condition_vs_k_axial`
  -- the same across depth (Fig. 4.5 takes neighbours laterally *and* axially):
  columns of the 3D ``A`` (Eq. 4.4) are PSFs of a stack's planes, so k sources at
  consecutive depth planes (every ``s``-th plane of a stack uniform in 1/z, i.e. a
  1/z separation of ``s`` steps, Eq. 4.7), optionally also spread laterally on an
  x-z grid (Fig. 4.4's 4 x 4 sources).

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

from recon.analysis.similarity import check_image, check_stack
from recon.errors import ReconInputError
from recon.validate import float_array

__all__ = [
    "axial_layout",
    "condition_vs_k",
    "condition_vs_k_axial",
    "local_condition_number",
    "point_source_columns",
    "stack_source_columns",
]


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
    a = float_array(columns, "columns", ndims=(2, 3))
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
    h = check_image(psf, "psf")
    pos = float_array(positions_px, "positions_px", ndims=(1, 2))
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


def _separation(value: Any, name: str, example: str, allow_zero: bool = False) -> float:
    """A finite separation > 0 (or >= 0 with ``allow_zero``), as float."""
    bad = (isinstance(value, bool) or not isinstance(value, numbers.Real)
           or not math.isfinite(float(value)))
    if bad or float(value) < 0 or (float(value) == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ReconInputError(f"{name} must be finite and {bound}, got {value!r}; e.g. {example}")
    return float(value)


def _check_axis(axis: str) -> None:
    if axis not in ("x", "y"):
        raise ReconInputError(f"axis must be 'x' or 'y', got {axis!r}")


def _check_ks(ks: Iterable[int]) -> list[int]:
    k_list = list(ks)
    if not k_list:
        raise ReconInputError("ks is empty; pass numbers of sources, e.g. range(2, 17)")
    for k in k_list:
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 1:
            raise ReconInputError(f"ks must hold integers >= 1, got {k!r}")
    return [int(k) for k in k_list]


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
    h = check_image(psf, "psf")
    sep = _separation(separation_px, "separation_px", "2 (pixels)")
    if layout not in ("line", "grid"):
        raise ReconInputError(f"layout must be 'line' or 'grid', got {layout!r}")
    _check_axis(axis)
    k_list = _check_ks(ks)
    k_max = int(max(k_list))
    if k_max > h.size:
        raise ReconInputError(
            f"{k_max} sources need more columns than the PSF's {h.size} pixels; use fewer"
        )
    positions = _layout_positions(k_max, sep, layout, axis)
    cols = point_source_columns(h, positions, order=order)
    return np.array([local_condition_number(cols[:, : int(k)]) for k in k_list], dtype=np.float64)


def stack_source_columns(stack: Any, sources: Any, *, order: int = 3) -> np.ndarray:
    """Columns of the 3D system matrix (Eq. 4.4) for point sources at planes of a stack.

    Parameters
    ----------
    stack : array_like
        Shape (n_z, rows, cols): the on-axis PSF of every depth plane (e.g. a
        calibration sweep's ``psf_stack``), real, finite, no all-zero plane.
    sources : array_like
        Shape (k, 3): ``(plane, dy, dx)`` per source -- the plane index (an
        integer, 0 <= plane < n_z) and the sensor-plane shift in pixels of its PSF
        (an object-space shift ``Delta x`` at depth ``z`` is ``Delta x d / z``).
    order : int, optional
        Spline order for sub-pixel shifts, as in :func:`point_source_columns`.

    Returns
    -------
    numpy.ndarray
        float64, shape (rows * cols, k): column j is ``stack[plane_j]`` translated
        by ``(dy_j, dx_j)`` and cropped to the sensor (the crop ``C`` of Eq. 4.4),
        flattened in C order.

    Raises
    ------
    ReconInputError
        An invalid stack, ``sources`` not finite of shape (k, 3), a plane index that
        is not an integer inside the stack, or a bad ``order``.
    """
    h = check_stack(stack)
    src = float_array(sources, "sources", ndims=(1, 2))
    if src.ndim == 1:
        src = src[None, :]
    if src.shape[1] != 3:
        raise ReconInputError(
            f"sources must have shape (k, 3) of (plane, dy, dx), got {src.shape}")
    planes = src[:, 0]
    if not np.all(planes == np.round(planes)) or planes.min() < 0 or planes.max() >= h.shape[0]:
        raise ReconInputError(
            f"source planes must be integers in 0..{h.shape[0] - 1} (the stack's planes), "
            f"got {planes.tolist()}")
    out = np.empty((h[0].size, src.shape[0]), dtype=np.float64)
    for k in np.unique(planes).astype(int):
        sel = np.flatnonzero(planes == k)
        out[:, sel] = point_source_columns(h[k], src[sel, 1:], order=order)
    return out


def axial_layout(n_z: int, k_max: int, separation_planes: int, *, separation_px: float = 0.0,
                 axis: str = "x", start_plane: int | None = None) -> np.ndarray:
    """Nested positions of up to ``k_max`` neighbouring sources across depth planes.

    With ``separation_px = 0`` the sources stand on a line along z at one lateral
    position: source j in plane ``start + j s`` (``s = separation_planes``). With
    ``separation_px > 0`` they fill an x-z grid (Fig. 4.4: 16 sources as 4 x 4) of
    ``w = ceil(sqrt(k_max))`` sources along ``axis``, ``separation_px`` apart and
    centred, in raster order: source j in plane ``start + (j // w) s`` at lateral
    offset ``(j % w - (w - 1) // 2) separation_px``. The first k positions are the
    k-source arrangement for every k <= ``k_max``.

    Parameters
    ----------
    n_z : int
        Planes in the stack (>= 1).
    k_max : int
        Largest number of sources (>= 1).
    separation_planes : int
        Plane step between neighbouring depths (>= 1); for a stack uniform in 1/z
        with step ``c`` (Eq. 4.7) the sources are ``s c`` apart in 1/z.
    separation_px : float, optional
        Lateral spacing on the sensor, pixels (>= 0; 0: one line along z).
    axis : {"x", "y"}, optional
        Lateral direction of the x-z grid.
    start_plane : int, optional
        Plane of the first source; default centres the sources in the stack.

    Returns
    -------
    numpy.ndarray
        float64, shape (k_max, 3): ``(plane, dy, dx)`` per source.

    Raises
    ------
    ReconInputError
        Invalid numbers, or the sources need more planes than the stack holds
        (``(depths - 1) s + 1 > n_z - start``).
    """
    for name, v, lo in (("n_z", n_z, 1), ("k_max", k_max, 1),
                        ("separation_planes", separation_planes, 1)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < lo:
            raise ReconInputError(f"{name} must be an integer >= {lo}, got {v!r}")
    lat = _separation(separation_px, "separation_px", "0 (a line along z) or 2 (pixels)",
                      allow_zero=True)
    _check_axis(axis)
    width = math.ceil(math.sqrt(k_max)) if lat > 0 else 1
    depths = math.ceil(k_max / width)
    span = (depths - 1) * int(separation_planes)
    if start_plane is None:
        start = max(0, (int(n_z) - 1 - span) // 2)
    elif isinstance(start_plane, bool) or not isinstance(start_plane, numbers.Integral) \
            or not 0 <= start_plane < n_z:
        raise ReconInputError(f"start_plane must be an integer in 0..{n_z - 1}, got "
                              f"{start_plane!r}")
    else:
        start = int(start_plane)
    if start + span >= n_z:
        raise ReconInputError(
            f"{k_max} sources on {depths} depth(s) {separation_planes} plane(s) apart need "
            f"{span + 1} planes from plane {start}, the stack has {n_z}; use fewer sources "
            "or a smaller separation")
    j = np.arange(k_max)
    along = (j % width - (width - 1) // 2) * lat
    zeros = np.zeros(k_max)
    dy, dx = (zeros, along) if axis == "x" else (along, zeros)
    return np.stack([start + (j // width) * int(separation_planes), dy, dx], axis=1)


def condition_vs_k_axial(
    stack: Any,
    separation_planes: int,
    ks: Iterable[int] = range(2, 17),
    *,
    separation_px: float = 0.0,
    axis: str = "x",
    start_plane: int | None = None,
    order: int = 3,
) -> np.ndarray:
    """Local condition number for k neighbouring sources across depth (Fig. 4.5).

    The axial counterpart of :func:`condition_vs_k`: the sources of
    :func:`axial_layout` (k consecutive depths ``separation_planes`` planes apart,
    optionally an x-z grid with lateral spacing ``separation_px``), their columns
    from :func:`stack_source_columns`, and :func:`local_condition_number` of the
    first k for each k.

    Parameters
    ----------
    stack : array_like
        Shape (n_z, rows, cols), the PSF of each plane, sorted by depth
        (background-removed).
    separation_planes : int
        Plane step between neighbouring sources (>= 1).
    ks : iterable of int, optional
        Numbers of sources (each >= 1); default 2 .. 16.
    separation_px, axis, start_plane
        See :func:`axial_layout`.
    order : int, optional
        Spline order for sub-pixel lateral shifts.

    Returns
    -------
    numpy.ndarray
        float64, shape (len(ks),): condition number of the first k sources for each
        k in ``ks`` (``inf`` where rank deficient).

    Raises
    ------
    ReconInputError
        An invalid stack or parameters, or more sources than the stack's planes hold.

    Notes
    -----
    The columns of Eq. 4.4 for sources at different depths differ by the PSF's
    scale (its support grows as ``1 + d / z``, Sec. 3.2) rather than by a shift,
    so two sources one 1/z step apart (Eq. 4.7) are about as alike as two sources
    one lateral resolution apart. Nested positions: never decreases with k.
    """
    h = check_stack(stack)
    k_list = _check_ks(ks)
    positions = axial_layout(h.shape[0], max(k_list), separation_planes,
                             separation_px=separation_px, axis=axis, start_plane=start_plane)
    cols = stack_source_columns(h, positions, order=order)
    return np.array([local_condition_number(cols[:, :k]) for k in k_list], dtype=np.float64)
