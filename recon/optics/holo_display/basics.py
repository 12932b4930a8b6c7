"""Constants, parameter checks, the LUT and the numba kernels of the holography model.

Part of :mod:`recon.optics.holo_display` (see its docstring for the model).
"""

from __future__ import annotations

import math
import os

import numpy as np

from ...errors import ReconInputError
from ...jit import PARALLEL, njit, prange

WORKERS = os.cpu_count() or 1
TWO_PI = 2.0 * math.pi
#: Largest fine grid accepted (samples); 2**27 complex64 samples are 1 GiB.
MAX_FINE_SAMPLES = 2**27

# --------------------------------------------------------------------------- kernels


@njit(**PARALLEL)
def render_mask_kernel(bits, margin, q, ss, hx, hy, ainv, tx, ty, radial, rc,
                        poly_x, poly_y, v0, v1, vout, out):  # pragma: no cover - jitted
    """Nearest-neighbour lookup of the mask at inverse-mapped fine-sample positions.

    ``out[i, j] = v(bits[I, J])`` with ``(X, Y) = ainv @ (x - t - D(x))`` and
    ``I = floor(Y + hy) + margin``, ``J = floor(X + hx) + margin``; ``vout`` outside.
    With ``ss > 1`` each fine sample is the mean over ``ss x ss`` sub-sample lookups.
    """
    ny, nx = out.shape
    nbi, nbj = bits.shape
    npy, npx = poly_x.shape
    use_poly = npy > 1 or npx > 1 or poly_x[0, 0] != 0.0 or poly_y[0, 0] != 0.0
    inv_n = 1.0 / (ss * ss)
    for i in prange(ny):
        for j in range(nx):
            acc = 0j
            for si in range(ss):
                y = (i + (si + 0.5) / ss) / q - hy
                for sj in range(ss):
                    x = (j + (sj + 0.5) / ss) / q - hx
                    dx = 0.0
                    dy = 0.0
                    if radial != 0.0:
                        r2 = (x * x + y * y) / (rc * rc)
                        dx += radial * (x / rc) * r2
                        dy += radial * (y / rc) * r2
                    if use_poly:
                        xn = x / hx
                        yn = y / hy
                        ya = 1.0
                        for a in range(npy):
                            xb = 1.0
                            for b in range(npx):
                                t = ya * xb
                                dx += poly_x[a, b] * t
                                dy += poly_y[a, b] * t
                                xb *= xn
                            ya *= yn
                    u = x - tx - dx
                    v = y - ty - dy
                    xx = ainv[0, 0] * u + ainv[0, 1] * v
                    yy = ainv[1, 0] * u + ainv[1, 1] * v
                    jj = int(math.floor(xx + hx)) + margin
                    ii = int(math.floor(yy + hy)) + margin
                    if ii >= 0 and ii < nbi and jj >= 0 and jj < nbj:
                        if bits[ii, jj]:
                            acc += v1
                        else:
                            acc += v0
                    else:
                        acc += vout
            out[i, j] = acc * inv_n


@njit(**PARALLEL)
def block_reduce_kernel(vals, ry, rx, wy, wx, n, out_ap, out_full):  # pragma: no cover
    """Per-block sums ``out_full[r, c] = sum_{blk} v ry rx`` and ``out_ap`` (x wy wx)."""
    rows, cols = out_ap.shape
    for r in prange(rows):
        for a in range(n):
            i = r * n + a
            ryi = ry[i]
            wyi = wy[i]
            for c in range(cols):
                acc_ap = 0j
                acc_full = 0j
                for e in range(n):
                    j = c * n + e
                    t = vals[i, j] * rx[j]
                    acc_full += t
                    acc_ap += t * wx[j]
                out_full[r, c] += acc_full * ryi
                out_ap[r, c] += acc_ap * (ryi * wyi)


# --------------------------------------------------------------------------- validation


def check_gray(gray, shape: tuple[int, int]) -> np.ndarray:
    """An SLM image: a uint8 numpy array of ``shape`` (rows, cols), returned as is.

    Raises
    ------
    ReconInputError
        Not a numpy array, not uint8, or the wrong shape.
    """
    if not isinstance(gray, np.ndarray):
        raise ReconInputError(
            f"SLM image must be a numpy uint8 array of shape {shape}, got {type(gray).__name__}")
    if gray.dtype != np.uint8:
        raise ReconInputError(
            f"SLM image must be uint8 (8-bit gray levels), got dtype {gray.dtype}; "
            "convert phases with phase_to_gray()")
    if gray.shape != shape:
        raise ReconInputError(f"SLM image must have shape {shape} (rows, cols), got {gray.shape}")
    return gray


def check_phase(phase, shape: tuple[int, int]) -> np.ndarray:
    """An SLM phase map (radians): a real numpy array of ``shape``, as float64.

    Raises
    ------
    ReconInputError
        Not a real numpy array, the wrong shape, or NaN/inf.
    """
    if not isinstance(phase, np.ndarray):
        raise ReconInputError(
            f"SLM phase must be a real numpy array of shape {shape}, got {type(phase).__name__}")
    if phase.dtype.kind not in "fiu" or phase.dtype == np.bool_:
        raise ReconInputError(f"SLM phase must be real (radians), got dtype {phase.dtype}")
    if phase.shape != shape:
        raise ReconInputError(f"SLM phase must have shape {shape} (rows, cols), got {phase.shape}")
    out = phase.astype(np.float64, copy=False)
    if not np.all(np.isfinite(out)):
        raise ReconInputError("SLM phase contains NaN or inf")
    return out


# --------------------------------------------------------------------------- LUT


def linear_lut() -> np.ndarray:
    """The default phase response: ``phase(g) = 2 pi g / 256`` for gray ``g = 0..255``.

    Returns
    -------
    numpy.ndarray
        float64, shape (256,), radians in ``[0, 2 pi)``.
    """
    return TWO_PI * np.arange(256, dtype=np.float64) / 256.0


def check_lut(lut) -> np.ndarray:
    """A phase-response LUT: 256 finite phases (radians), float64 copy; ``None`` -> linear.

    Raises
    ------
    ReconInputError
        Not 256 finite numbers.
    """
    if lut is None:
        return linear_lut()
    try:
        arr = np.asarray(lut, dtype=np.float64)
    except (TypeError, ValueError):
        raise ReconInputError("phase LUT must be 256 finite phases (radians)") from None
    if arr.shape != (256,) or not np.all(np.isfinite(arr)):
        raise ReconInputError(
            f"phase LUT must be 256 finite phases (radians), got shape {arr.shape}")
    return arr.copy()


def gray_to_phase(gray: np.ndarray, lut=None) -> np.ndarray:
    """SLM phase of 8-bit gray levels through the phase-response LUT.

    Parameters
    ----------
    gray : numpy.ndarray
        uint8, any shape: gray levels.
    lut : array_like, optional
        256 phases (radians), ``lut[g]`` is the phase of gray ``g``; default
        :func:`linear_lut`.

    Returns
    -------
    numpy.ndarray
        float64, ``gray.shape``, radians.
    """
    if not isinstance(gray, np.ndarray) or gray.dtype != np.uint8:
        raise ReconInputError("gray levels must be a numpy uint8 array")
    return check_lut(lut)[gray]


def phase_to_gray(phase, lut=None) -> np.ndarray:
    """8-bit gray levels whose LUT phase is nearest (modulo 2 pi) to the given phase.

    The inverse of :func:`gray_to_phase` for any LUT (monotonic or not): each phase is
    wrapped to ``[0, 2 pi)`` and matched to the LUT entry at the smallest circular
    distance ``|angle(exp(i (phase - lut[g])))|`` (the two neighbours in the sorted,
    wrapped LUT are compared, so the match is exact). For the linear LUT this is
    ``round(256 phase / 2 pi) mod 256``; the quantisation error is at most
    ``pi / 256``.

    Parameters
    ----------
    phase : array_like
        Real, any shape, radians (any range).
    lut : array_like, optional
        256 phases (radians); default :func:`linear_lut`.

    Returns
    -------
    numpy.ndarray
        uint8, same shape as ``phase``.
    """
    lut_arr = check_lut(lut)
    p = np.asarray(phase)
    if p.dtype.kind not in "fiu" or p.dtype == np.bool_:
        raise ReconInputError(f"phase must be real (radians), got dtype {p.dtype}")
    p = p.astype(np.float64, copy=False)
    if not np.all(np.isfinite(p)):
        raise ReconInputError("phase contains NaN or inf")
    lw = np.mod(lut_arr, TWO_PI)
    order = np.argsort(lw, kind="stable")
    sv = lw[order]
    pw = np.mod(p, TWO_PI)
    idx = np.searchsorted(sv, pw, side="right")
    lo = order[(idx - 1) % 256]
    hi = order[idx % 256]

    def circ(a, b):
        d = np.abs(a - b) % TWO_PI
        return np.minimum(d, TWO_PI - d)

    pick_hi = circ(pw, lw[hi]) < circ(pw, lw[lo])
    return np.where(pick_hi, hi, lo).astype(np.uint8)


# --------------------------------------------------------------------------- poses
