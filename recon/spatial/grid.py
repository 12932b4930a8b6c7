"""Registered PSF grids and their interpolation weights (Kuo 2020, Sec. 5.2, Eq. 5.2-5.3).

A :class:`PsfGrid` holds the calibration PSFs of one depth measured at the nodes
of a lateral grid, registered to the central PSF (Eq. 5.2 with ``s_i = 1``: each
PSF shifted back by the translation that maximises its cross-correlation with the
central one), the node positions as those sensor-pixel shifts, and the grid's
shape. Its :meth:`PsfGrid.tents` are the bilinear weights ``alpha_i`` of Eq. 5.3 on
the object grid of the cropped convolution model (Eq. 3.4: a point at padded-grid
position ``centre + (dy, dx)`` images to the central PSF shifted by ``(dy, dx)``),
so a point at a node images exactly to that node's measured PSF.

:func:`synthesize_grid` makes the grid of a depth between two calibrated ones
(Sec. 5.2, "It is also possible to synthesize new PSFs at different depths"): the
registered PSFs of both neighbours are scaled by ``s_i`` of Eq. 5.2 to the new
depth and combined with weights linear in 1/z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..analysis import register_shift
from ..errors import ReconInputError
from ..operators import real32
from ..scenes import tent_weights

__all__ = ["PsfGrid", "register_psfs", "scale_psf", "synthesize_grid"]


def register_psfs(psfs: np.ndarray, reference: int | None = None, positions=None
                  ) -> tuple[np.ndarray, np.ndarray, int]:
    """Register calibration PSFs to the central one (Eq. 5.2, ``s_i = 1``).

    Shifts come from cross-correlation (Sec. 5.2) of the square roots of the PSFs
    (which compresses the sensor fall-off, so the faint spots of an off-axis PSF
    count). With ``positions`` the PSFs are registered outwards from the reference,
    each against its nearest already registered neighbour (whose fall-off window
    overlaps its own far more than the central PSF's does), and the shifts add up
    along the chain; without, each is registered against the reference directly.

    Parameters
    ----------
    psfs : ndarray, shape (N, rows, cols)
        Background-free PSFs of one depth (e.g. after
        :func:`recon.analysis.remove_background_dct`).
    reference : int, optional
        Index of the central PSF; default the position nearest the axis, or without
        positions the PSF with the most energy in the sensor's centre ninth.
    positions : array_like, (N, 2), optional
        Source positions (any unit), for the neighbour chain.

    Returns
    -------
    registered : ndarray, float32, (N, rows, cols)
        Each PSF shifted back by its shift (bilinear, zeros outside).
    shifts_px : ndarray, float64, (N, 2)
        ``(dy, dx)`` of each PSF relative to the reference, sensor pixels
        (:func:`recon.analysis.register_shift`: cross-correlation, 1/20 px).
    reference : int

    Raises
    ------
    ReconInputError
        Not a 3D stack, fewer than one PSF, an all-zero PSF (from the registration).
    """
    h = real32(psfs, "PSF grid", contiguous=True)
    if h.ndim != 3 or h.shape[0] < 1:
        raise ReconInputError(f"PSF grid must be (N, rows, cols), got shape {h.shape}")
    root = np.sqrt(np.maximum(h, 0.0))
    pos = None if positions is None else np.asarray(positions, np.float64).reshape(-1, 2)
    if reference is None:
        if pos is not None:
            reference = int(np.argmin(np.hypot(*pos.T)))
        else:
            r, c = h.shape[1] // 3, h.shape[2] // 3
            reference = int(np.argmax(h[:, r:2 * r or None, c:2 * c or None].sum(axis=(1, 2))))
    shifts = np.zeros((h.shape[0], 2), np.float64)
    if pos is None:
        shifts[:] = [register_shift(root[reference], img) for img in root]
    else:
        done = [int(reference)]
        for i in np.argsort(np.hypot(*(pos - pos[reference]).T), kind="stable"):
            if i == reference:
                continue
            near = done[int(np.argmin(np.hypot(*(pos[done] - pos[i]).T)))]
            shifts[i] = shifts[near] + register_shift(root[near], root[i])
            done.append(int(i))
    registered = np.stack([ndimage.shift(img, -s, order=1, mode="constant")
                           for img, s in zip(h, shifts, strict=True)]).astype(np.float32)
    return registered, shifts, int(reference)


def scale_psf(psf: np.ndarray, s: float) -> np.ndarray:
    """``h(s u)`` about the sensor centre (the axis), bilinear, zeros outside (Eq. 5.2).

    Parameters
    ----------
    psf : ndarray, (rows, cols)
    s : float
        Coordinate scale (> 0); ``s > 1`` shrinks the pattern.

    Returns
    -------
    ndarray, float32, (rows, cols)
    """
    h = np.asarray(psf, np.float32)
    centre = (np.asarray(h.shape, np.float64) - 1.0) / 2.0
    return ndimage.affine_transform(h, np.full(2, s), offset=centre * (1.0 - s), order=1,
                                    mode="grid-constant", cval=0.0).astype(np.float32)


@dataclass(frozen=True)
class PsfGrid:
    """Registered calibration PSFs of one depth on a lateral grid (Sec. 5.2).

    Parameters
    ----------
    psfs : ndarray, (N, rows, cols)
        Registered PSFs, row-major over the grid (``N = ny * nx``; node ``a * nx + b``
        is grid row ``a``, column ``b``); converted to float32.
    shifts_px : ndarray, (N, 2)
        ``(dy, dx)`` of each node's (unregistered) PSF relative to the reference,
        sensor pixels: where the node sits relative to the padded grid's centre.
    grid_shape : (ny, nx)
    z_mm : float, optional
        Depth of the grid (distance in front of the diffuser, mm); needed for 3D.
    d_mm : float, optional
        Diffuser-to-sensor distance, mm; needed to synthesise other depths.

    Raises
    ------
    ReconInputError
        Shapes that do not agree, non-finite or all-zero PSFs, or node rows /
        columns whose mean positions are not strictly monotonic (not a grid).
    """

    psfs: np.ndarray
    shifts_px: np.ndarray
    grid_shape: tuple[int, int]
    z_mm: float | None = None
    d_mm: float | None = None

    def __post_init__(self):
        h = real32(self.psfs, "PSF grid", contiguous=True)
        s = np.asarray(self.shifts_px, np.float64)
        try:
            ny, nx = (int(v) for v in self.grid_shape)
        except (TypeError, ValueError) as exc:
            raise ReconInputError(f"grid_shape must be (ny, nx), got {self.grid_shape!r}"
                                  ) from exc
        if h.ndim != 3 or ny < 1 or nx < 1 or h.shape[0] != ny * nx:
            raise ReconInputError(
                f"PSF grid of shape {h.shape} does not hold {ny} x {nx} PSFs; pass "
                "(ny * nx, rows, cols), row-major over the grid")
        if s.shape != (ny * nx, 2) or not np.all(np.isfinite(s)):
            raise ReconInputError(f"shifts_px must be {ny * nx} finite (dy, dx) pairs, got "
                                  f"shape {s.shape}")
        if not np.all(np.isfinite(h)):
            raise ReconInputError("PSF grid contains NaN or inf; fix the calibration frames")
        empty = [k for k in range(h.shape[0]) if not np.any(h[k])]
        if empty:
            raise ReconInputError(f"PSFs {empty} of the grid are all zero; recapture them")
        for name, v in (("z_mm", self.z_mm), ("d_mm", self.d_mm)):
            if v is not None and not (math.isfinite(float(v)) and float(v) > 0):
                raise ReconInputError(f"{name} must be a positive number of mm, got {v!r}")
        set_ = object.__setattr__
        set_(self, "psfs", h)
        set_(self, "shifts_px", s)
        set_(self, "grid_shape", (ny, nx))
        for axis, centres in enumerate(self.node_coordinates()):
            steps = np.diff(centres)
            if len(centres) > 1 and not (np.all(steps > 0) or np.all(steps < 0)):
                raise ReconInputError(
                    f"the grid's node {'rows' if axis == 0 else 'columns'} sit at "
                    f"{np.round(centres, 1).tolist()} px: not a grid (positions must be "
                    "strictly monotonic); order the PSFs row-major over the grid")

    @property
    def n(self) -> int:
        """Number of PSFs."""
        return self.psfs.shape[0]

    @property
    def sensor_shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self.psfs.shape[1:]

    @classmethod
    def from_positions(cls, psfs, positions_mm, *, z_mm: float | None = None,
                       d_mm: float | None = None, registered: bool = False,
                       shifts_px=None) -> PsfGrid:
        """A grid from PSFs at lateral source positions in any order.

        Parameters
        ----------
        psfs : ndarray, (N, rows, cols)
            Background-free PSFs; registered already when ``registered`` (then
            ``shifts_px`` is required), else registered here (:func:`register_psfs`,
            outwards from the position nearest the axis).
        positions_mm : array_like, (N, 2)
            Source positions ``(x, y)``, mm, on a rectangular raster.
        z_mm, d_mm : float, optional
        registered : bool
        shifts_px : array_like, (N, 2), optional

        Raises
        ------
        ReconInputError
            Positions that do not form a full rectangular raster.
        """
        pos = np.asarray(positions_mm, np.float64).reshape(-1, 2)
        h = real32(psfs, "PSF grid", contiguous=True)
        if h.ndim != 3 or len(pos) != h.shape[0]:
            raise ReconInputError(f"{len(pos)} positions for a PSF stack of shape {h.shape}")
        tol = 1e-3 * max(float(np.ptp(pos)), 1e-9)
        xs = _distinct(pos[:, 0], tol)
        ys = _distinct(pos[:, 1], tol)
        if len(xs) * len(ys) != len(pos):
            raise ReconInputError(
                f"{len(pos)} positions on {len(ys)} rows and {len(xs)} columns: not a full "
                "rectangular raster; the local convolution model needs PSFs on a grid")
        key = [int(np.argmin(np.abs(ys - y))) * len(xs) + int(np.argmin(np.abs(xs - x)))
               for x, y in pos]
        if sorted(key) != list(range(len(pos))):
            raise ReconInputError("two PSFs share one grid position; pass one per node")
        order = np.argsort(key)
        if registered:
            if shifts_px is None:
                raise ReconInputError("registered PSFs need their shifts_px")
            shifts = np.asarray(shifts_px, np.float64).reshape(-1, 2)
        else:
            h, shifts, _ = register_psfs(h, positions=pos)
        return cls(h[order], shifts[order], (len(ys), len(xs)), z_mm, d_mm)

    @property
    def central(self) -> int:
        """Index of the node nearest the reference (the central PSF, zero shift)."""
        return int(np.argmin(np.hypot(*self.shifts_px.T)))

    def valid_masks(self) -> np.ndarray:
        """Per node, the registered pixels the sensor saw, (N, rows, cols) bool.

        Registration shifts a PSF back by its shift, so where the light fell off the
        sensor the registered PSF holds zeros that are missing data, not darkness:
        pixel ``(r, c)`` is valid when ``(r + dy, c + dx)`` lies on the sensor.
        """
        rows, cols = self.sensor_shape
        r = np.arange(rows)[None, :, None] + np.round(self.shifts_px[:, 0])[:, None, None]
        c = np.arange(cols)[None, None, :] + np.round(self.shifts_px[:, 1])[:, None, None]
        return (r >= 0) & (r < rows) & (c >= 0) & (c < cols)

    def node_coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean node row offsets (ny,) and column offsets (nx,), sensor px."""
        ny, nx = self.grid_shape
        s = self.shifts_px.reshape(ny, nx, 2)
        return s[:, :, 0].mean(axis=1), s[:, :, 1].mean(axis=0)

    def tents(self, padded_shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear weights of Eq. 5.3 on the padded object grid, separable.

        ``alpha_{a * nx + b}(r, c) = wy[a, r] * wx[b, c]``: tents (1 at a node's
        row / column, 0 at the neighbours, constant beyond the outer nodes), a
        partition of unity.

        Parameters
        ----------
        padded_shape : (P0, P1)
            The object grid (:func:`recon.operators.padded_grid`).

        Returns
        -------
        wy : ndarray, float32, (ny, P0)
        wx : ndarray, float32, (nx, P1)
        """
        return tuple(_axis_tents(c, p // 2, p)
                     for c, p in zip(self.node_coordinates(), padded_shape, strict=True))

    def restrict(self, rows: slice, cols: slice) -> PsfGrid:
        """The sub-grid of node rows ``rows`` and columns ``cols`` (same registration)."""
        ny, nx = self.grid_shape
        idx = np.arange(ny * nx).reshape(ny, nx)[rows, cols]
        return PsfGrid(self.psfs[idx.ravel()], self.shifts_px[idx.ravel()], idx.shape,
                       self.z_mm, self.d_mm)


def _distinct(values: np.ndarray, tol: float) -> np.ndarray:
    v = np.sort(values)
    keep = np.concatenate([[True], np.diff(v) > tol])
    groups = np.cumsum(keep) - 1
    return np.array([v[groups == g].mean() for g in range(groups[-1] + 1)])


def _axis_tents(centres: np.ndarray, origin: int, length: int) -> np.ndarray:
    pos = np.arange(length, dtype=np.float64) - origin
    if len(centres) == 1:
        return np.ones((1, length), np.float32)
    order = np.argsort(centres)
    w = np.empty((len(centres), length), np.float32)
    w[order] = tent_weights(pos, np.asarray(centres)[order])
    return w


def synthesize_grid(grids: list[PsfGrid], z_mm: float) -> PsfGrid:
    """The registered PSF grid at a depth between calibrated ones (Sec. 5.2, Eq. 5.2).

    The two calibrated grids bracketing ``z_mm`` (or the nearest one outside their
    range) are scaled to the new depth, ``h~_i(u; z) = h_i(s_i u)`` with
    ``s_i = z (d + z_i) / (z_i (d + z))`` about the axis, and combined with weights
    linear in 1/z; each node's position (the lateral shift ``m x``, ``m = d / z``)
    scales by ``z_i / z``. The PSF sums are interpolated the same way, so the
    depth's brightness follows the calibration. A depth equal to a calibrated one
    returns that grid.

    Parameters
    ----------
    grids : list of PsfGrid
        Calibrated grids with ``z_mm`` and ``d_mm``, all of one grid shape and
        sensor shape.
    z_mm : float
        The new depth, mm (> 0).

    Returns
    -------
    PsfGrid

    Raises
    ------
    ReconInputError
        No grids, grids without depth or ``d_mm``, different grid or sensor shapes.
    """
    if not grids:
        raise ReconInputError("no calibrated PSF grids to synthesise a depth from")
    for g in grids:
        if g.z_mm is None or g.d_mm is None:
            raise ReconInputError("synthesising a depth needs grids with z_mm and d_mm")
        if g.grid_shape != grids[0].grid_shape or g.sensor_shape != grids[0].sensor_shape:
            raise ReconInputError(
                "the calibrated PSF grids differ in grid or sensor shape; calibrate every "
                "depth on the same grid")
    z = float(z_mm)
    if not (math.isfinite(z) and z > 0):
        raise ReconInputError(f"depth {z_mm!r} must be a positive number of mm")
    ordered = sorted(grids, key=lambda g: g.z_mm)
    zs = np.array([g.z_mm for g in ordered])
    exact = np.flatnonzero(np.isclose(zs, z, rtol=1e-9, atol=0))
    if exact.size:
        return ordered[int(exact[0])]
    hi = int(np.searchsorted(zs, z))
    pair = [max(hi - 1, 0), min(hi, len(zs) - 1)]
    if pair[0] == pair[1]:
        weights = [1.0]
        pair = pair[:1]
    else:
        inv = 1.0 / zs[pair]
        t = (1.0 / z - inv[0]) / (inv[1] - inv[0])
        weights = [1.0 - t, t]
    psfs = np.zeros_like(ordered[0].psfs)
    shifts = np.zeros_like(ordered[0].shifts_px)
    for w, j in zip(weights, pair, strict=True):
        g = ordered[j]
        s = z * (g.d_mm + g.z_mm) / (g.z_mm * (g.d_mm + z))
        for i in range(g.n):
            scaled = scale_psf(g.psfs[i], s)
            total = float(scaled.sum())
            if total > 0:
                scaled *= float(g.psfs[i].sum()) / total
            psfs[i] += w * scaled
        shifts += w * g.shifts_px * (g.z_mm / z)
    return PsfGrid(psfs, shifts, ordered[0].grid_shape, z, ordered[0].d_mm)
