"""Focused spots: patterns by phase conjugation through the model mask, and the
spot efficiency metric of a camera frame.

Part of :mod:`recon.optics.holo_display` (see its docstring for the model).
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import ReconInputError
from ...validate import as_int, as_vec2, finite_float
from .basics import block_reduce_kernel
from .mask import MaskModel


def phase_ramp(u: float, n_total: int, n: int, q_sub: int = 1) -> np.ndarray:
    """``exp(-i 2 pi u j / n_total)`` for ``j = 0, q_sub, 2 q_sub, ...`` (n samples)."""
    j = np.arange(n, dtype=np.float64) * q_sub
    return np.exp(-2j * math.pi * u * j / n_total).astype(np.complex64)


def block_reduce(vals: np.ndarray, ry, rx, wy, wx, n: int, out_shape):
    """Per-block sums of ``vals`` weighted by the ramps, with and without the aperture.

    Wraps :func:`recon.optics.holo_display.basics.block_reduce_kernel` (numba):
    ``ry``, ``rx`` complex ramps, ``wy``, ``wx`` aperture weights along rows and
    columns, ``n`` the block size; returns ``(out_ap, out_full)``, complex128 arrays
    of ``out_shape``.
    """
    out_ap = np.zeros(out_shape, np.complex128)
    out_full = np.zeros(out_shape, np.complex128)
    block_reduce_kernel(vals, ry.astype(np.complex64), rx.astype(np.complex64),
                         wy.astype(np.float32), wx.astype(np.float32), int(n), out_ap, out_full)
    return out_ap, out_full


def check_u0(u0, fine_shape) -> tuple[float, float]:
    """The spot's far-field offset ``u0 = (ux, uy)`` in fine-grid samples.

    Raises
    ------
    ReconInputError
        Not two finite numbers, or outside the fine grid's band
        (|ux| < nx / 2, |uy| < ny / 2 with ``fine_shape = (ny, nx)``).
    """
    ux, uy = as_vec2(u0, "u0")
    ny, nx = fine_shape
    if abs(ux) >= nx / 2 or abs(uy) >= ny / 2:
        raise ReconInputError(
            f"u0 = {(ux, uy)} is outside the fine grid's band (|ux| < {nx / 2}, "
            f"|uy| < {ny / 2} far-field samples)")
    return ux, uy


def _check_patch(patch, slm_shape) -> tuple[int, int, int, int] | None:
    if patch is None:
        return None
    try:
        r0, r1, c0, c1 = (int(v) for v in patch)
    except (TypeError, ValueError):
        raise ReconInputError(
            f"patch must be (row0, row1, col0, col1) SLM pixels, got {patch!r}") from None
    rows, cols = slm_shape
    if not (0 <= r0 < r1 <= rows and 0 <= c0 < c1 <= cols):
        raise ReconInputError(
            f"patch {(r0, r1, c0, c1)} must satisfy 0 <= row0 < row1 <= {rows} and "
            f"0 <= col0 < col1 <= {cols}")
    return r0, r1, c0, c1


def spot_phase(mask_model: MaskModel, u0, patch=None, *, shift=(0.0, 0.0),
               fill: float = 0.0) -> np.ndarray:
    """SLM phase that focuses the model mask's light to one far-field spot at ``u0``.

    Phase conjugation per SLM pixel (docs/protocols.md, "Mask alignment"; Eq. 7.12 with a
    point target)::

        b_p   = sum_{x in p} M(x - s) exp(-i 2 pi (ux j / Nx + uy i / Ny))
        phi_p = -angle(b_p)

    over the fine samples ``x = [i, j]`` of SLM pixel ``p``, with the model mask ``M``
    (what the software believes: ideal +1/-1, no defects) under a software shift
    ``s``. This maximises ``|sum_p exp(i phi_p) b_p| = sum_p |b_p|`` (the spot energy).
    Integer shifts are computed at mask resolution (exactly equal to the fine-grid
    sum); fractional shifts on the fine grid.

    Parameters
    ----------
    mask_model : MaskModel
        The mask model.
    u0 : (float, float)
        Spot frequency ``(ux, uy)`` in far-field samples (see module docstring).
    patch : (int, int, int, int), optional
        ``(row0, row1, col0, col1)``: only these SLM pixels (half-open ranges) form the
        spot; the others get ``fill``.
    shift : (float, float)
        Software shift ``s`` of the model mask (mask px, x then y).
    fill : float
        Phase (rad) of SLM pixels outside ``patch``; the random mask scatters them into
        a diffuse background.

    Returns
    -------
    numpy.ndarray
        float64 (R, C), radians in ``[-pi, pi]``.
    """
    if not isinstance(mask_model, MaskModel):
        raise ReconInputError(f"mask_model must be a MaskModel, got {type(mask_model).__name__}")
    b = _model_coefficients(mask_model, u0, shift)
    phase = -np.angle(b)
    pt = _check_patch(patch, mask_model.slm_shape)
    if pt is not None:
        fill = finite_float(fill, "fill")
        r0, r1, c0, c1 = pt
        out = np.full(mask_model.slm_shape, fill, np.float64)
        out[r0:r1, c0:c1] = phase[r0:r1, c0:c1]
        return out
    return phase


def _model_coefficients(mm: MaskModel, u0, shift) -> np.ndarray:
    """``b_p`` of :func:`spot_phase` (complex128 (R, C))."""
    ux, uy = check_u0(u0, mm.fine_shape)
    sx, sy = as_vec2(shift, "shift")
    ny, nx = mm.fine_shape
    rows, cols = mm.slm_shape
    k, q = mm.k, mm.q
    if sx == round(sx) and sy == round(sy):
        # mask resolution: M(X - s) for integer s; ramp at each mask pixel's first fine
        # sample times the common in-pixel factor g = sum_{r<q} exp(-i 2 pi u r / N).
        isx, isy = int(round(sx)), int(round(sy))
        hb, wb = rows * k, cols * k
        ii = np.arange(hb) + mm.margin - isy
        jj = np.arange(wb) + mm.margin - isx
        vi = (ii >= 0) & (ii < mm.bits.shape[0])
        vj = (jj >= 0) & (jj < mm.bits.shape[1])
        sub = mm.bits[np.clip(ii, 0, mm.bits.shape[0] - 1)[:, None],
                      np.clip(jj, 0, mm.bits.shape[1] - 1)[None, :]]
        vals = (1.0 - 2.0 * sub.astype(np.float32))
        vals[~(vi[:, None] & vj[None, :])] = 1.0
        gx = np.exp(-2j * math.pi * ux * np.arange(q) / nx).sum()
        gy = np.exp(-2j * math.pi * uy * np.arange(q) / ny).sum()
        ry = phase_ramp(uy, ny, hb, q)
        rx = phase_ramp(ux, nx, wb, q)
        _, full = block_reduce(vals.astype(np.complex64), ry, rx, np.ones(hb), np.ones(wb), k,
                                (rows, cols))
        return full * (gx * gy)
    vals = mm.model_fine((sx, sy))
    ry = phase_ramp(uy, ny, ny)
    rx = phase_ramp(ux, nx, nx)
    _, full = block_reduce(vals, ry, rx, np.ones(ny), np.ones(nx), k * q, (rows, cols))
    return full


# --------------------------------------------------------------------------- SLM, relay


def efficiency(frame: np.ndarray, spot_px, window: int = 5, ring: int | None = None) -> float:
    """Spot efficiency ``eta = (E_W - n_W b) / E_total`` of a camera frame.

    ``E_W`` is the energy in the ``window x window`` pixels centred on the pixel
    nearest ``spot_px``, ``n_W`` their number, ``b`` the local background per pixel
    (the mean over the surrounding square ring of width ``ring``, default ``window``;
    the mean is unbiased for speckle) and ``E_total`` the energy of the whole frame.
    ``eta`` is insensitive to laser power (a ratio) and to a uniform dark offset only
    if the frame is offset-corrected beforehand.

    Parameters
    ----------
    frame : numpy.ndarray
        2-D real, camera pixels (e.g. e-/s), finite, positive total.
    spot_px : (float, float)
        Spot position ``(x, y)`` in camera pixels.
    window : int
        Odd window size (>= 1).
    ring : int, optional
        Background ring width in pixels (>= 1).

    Returns
    -------
    float
        ``eta`` (dimensionless; can be slightly negative when there is no spot).

    Raises
    ------
    ReconInputError
        ``frame`` not a 2-D real array, NaN/inf in it or no positive energy; an even
        or too large ``window``; ``ring`` < 1; ``spot_px`` outside the frame.
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 2 or frame.dtype.kind not in "fiu":
        raise ReconInputError("frame must be a 2-D real numpy array")
    window = as_int(window, "window", 1)
    if window % 2 == 0:
        raise ReconInputError(f"window must be odd, got {window}")
    ring = window if ring is None else as_int(ring, "ring", 1)
    rows, cols = frame.shape
    if window > min(rows, cols):
        raise ReconInputError(f"window {window} is larger than the frame {frame.shape}")
    x, y = as_vec2(spot_px, "spot_px")
    cx, cy = int(round(x)), int(round(y))
    if not (0 <= cx < cols and 0 <= cy < rows):
        raise ReconInputError(f"spot_px {(x, y)} is outside the frame {frame.shape}")
    f = frame.astype(np.float64, copy=False)
    total = float(f.sum())
    if not math.isfinite(total):
        raise ReconInputError("frame contains NaN or inf")
    if total <= 0.0:
        raise ReconInputError("frame has no positive energy")
    h = window // 2

    def box(r):
        return (max(cy - r, 0), min(cy + r + 1, rows), max(cx - r, 0), min(cx + r + 1, cols))

    r0, r1, c0, c1 = box(h)
    inner = f[r0:r1, c0:c1]
    e_w = float(inner.sum())
    o0, o1, p0, p1 = box(h + ring)
    outer = f[o0:o1, p0:p1]
    n_ring = outer.size - inner.size
    bg = (float(outer.sum()) - e_w) / n_ring if n_ring > 0 else 0.0
    return (e_w - inner.size * bg) / total
