"""Holographic display with a random binary-phase scattering mask (Kuo 2020, Ch. 7).

A deterministic, seeded forward model of the bench

    laser -> SLM (8-bit gray -> phase LUT) -> relay (defocus/tilt from the stage pose)
          -> random binary-phase mask (true pose) -> Fourier lens -> camera pixels

returning the camera irradiance in photo-electrons per second per camera pixel, plus
the helpers the mask-alignment procedure needs (phase-conjugated spot patterns, the
LUT inverse, a cheap direct evaluation of one far-field spot and the window
efficiency metric). There is no camera noise here (the simulated camera driver adds
shot and read noise, offsets, saturation); slow laser-power drift is part of the
model (:class:`LaserDrift`, advanced explicitly by the caller).

Image formation (Eq. 7.8 with the relay of Sec. 7.4 and the box upsampling of
Eq. 7.15)::

    s(x) = sum_p [ a(x - x_p) exp(i phi_p) + g (1 - a(x - x_p)) ] R(x - x_p)   (SLM, Eq. 7.15)
    U(x) = P_dz(x) { s }(x)                                  (relay, angular spectrum)
    F(u) = sum_x U(x) m(x) exp(-i 2 pi u . x / N)            (Fourier lens: FFT)
    I_cam = affine-binned |F|^2 * power * drift / (N * N_pad)

with ``R`` the SLM pixel box, ``a`` its fill-factor aperture, ``g`` the gap
amplitude, ``m`` the *true* mask transmission and ``N`` the number of fine samples.

Grids and units
---------------
* SLM: ``slm_shape = (R, C)`` pixels of pitch ``slm_pitch_um`` as imaged onto the mask
  plane by the relay (the relay is nominally designed so that one SLM pixel covers
  exactly ``k x k`` mask pixels; a relay magnification error is part of the mask
  ground truth, :attr:`MaskTransform.magnification`).
* Mask: pixel pitch ``Delta_m = slm_pitch_um / k``; the physical mask is larger than
  the SLM footprint by ``margin`` mask pixels on each side (so that shifts bring in
  new mask content, as on the bench). The dissertation's etendue factor (Eq. 7.10) is
  ``(Delta / Delta_m)^2 = k^2``.
* Fine grid: ``q`` samples per mask pixel, ``n = k q`` per SLM pixel; fine shape
  ``(Ny, Nx) = (R k q, C k q)``, sample pitch ``Delta_m / q``.
* Plane coordinates (mask geometry, distortion, tilt): mask pixels, origin at the
  centre of the SLM footprint (the optical axis), ``x`` along columns, ``y`` along
  rows. Fine sample ``[i, j]`` sits at ``x = (j + 0.5)/q - C k/2``,
  ``y = (i + 0.5)/q - R k/2``.
* Far field: spatial frequencies ``u = (ux, uy)`` in far-field samples (cycles per
  SLM aperture along each axis; the FFT index relative to the zero order). The phase
  ramp of a frequency ``u`` on the fine grid is ``exp(-i 2 pi (ux j / Nx + uy i / Ny))``
  (the FFT convention). The display's field of view (Eq. 7.9) is ``|ux| < C k/2``,
  ``|uy| < R k/2``; the mask-free SLM band is ``|ux| < C/2``, ``|uy| < R/2``.
* Camera: pixel centres at integer ``(x, y) = (col, row)``; far field -> camera through
  the affine ``c = M u + b`` (slmsuite ``SimulatedCamera`` style, :class:`CameraMapping`).

Every 2-vector in this module (``u0``, translations, shifts, camera positions) is in
``(x, y)`` = ``(column, row)`` order; arrays are indexed ``[row, col]``.

Physics checks (holography-evaluation.md, Sec. 8(c)): with the spot pattern of the
model mask, a true-mask shift ``d`` scales the spot by ``(1-|dx|/k)^2 (1-|dy|/k)^2``
(triangle law), a random SLM phase gives a background of about ``4/(pi N_SLM)`` of
the spot peak, and rotation lowers the spot; these are tested in
``tests/recon/test_optics_holography.py``.
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass

# numba's OpenMP workers must sleep, not spin, between parallel regions (see
# recon/_kernels.py): spinning threads steal the cores from scipy.fft's workers.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import scipy.fft as sfft  # noqa: E402
from numba import njit, prange  # noqa: E402

from ..errors import ReconInputError  # noqa: E402

__all__ = [
    "CameraMapping",
    "HolographicDisplayModel",
    "LaserDrift",
    "MaskModel",
    "MaskTransform",
    "RelayModel",
    "SlmModel",
    "StagePose",
    "efficiency",
    "gray_to_phase",
    "linear_lut",
    "phase_to_gray",
    "spot_phase",
]

WORKERS = os.cpu_count() or 1
TWO_PI = 2.0 * math.pi
#: Largest fine grid accepted (samples); 2**27 complex64 samples are 1 GiB.
MAX_FINE_SAMPLES = 2**27

_JIT = dict(parallel=True, cache=True, nogil=True)


# --------------------------------------------------------------------------- kernels


@njit(**_JIT)
def _render_mask_kernel(bits, margin, q, ss, hx, hy, ainv, tx, ty, radial, rc,
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


@njit(**_JIT)
def _block_reduce_kernel(vals, ry, rx, wy, wx, n, out_ap, out_full):  # pragma: no cover
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


def _int_param(name: str, value, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ReconInputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if int(value) < minimum:
        raise ReconInputError(f"{name} must be an integer >= {minimum}, got {value}")
    return int(value)


def _float_param(name: str, value, *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ReconInputError(f"{name} must be a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise ReconInputError(f"{name} must be a finite number, got {value!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        rel = ">" if lo_open else ">="
        raise ReconInputError(f"{name} must be {rel} {lo}, got {v}")
    if hi is not None and v > hi:
        raise ReconInputError(f"{name} must be <= {hi}, got {v}")
    return v


def _vec2(name: str, value) -> tuple[float, float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ReconInputError(f"{name} must be a pair of finite numbers (x, y), "
                              f"got {value!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ReconInputError(f"{name} must be a pair of finite numbers (x, y), got {value!r}")
    return float(arr[0]), float(arr[1])


def _shape2(name: str, value) -> tuple[int, int]:
    try:
        t = tuple(value)
    except TypeError:
        raise ReconInputError(f"{name} must be (rows, cols), got {value!r}") from None
    if len(t) != 2:
        raise ReconInputError(f"{name} must be (rows, cols), got {value!r}")
    return (_int_param(f"{name}[0]", t[0], 1), _int_param(f"{name}[1]", t[1], 1))


def _check_gray(gray, shape: tuple[int, int]) -> np.ndarray:
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


def _check_phase(phase, shape: tuple[int, int]) -> np.ndarray:
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


def _check_lut(lut) -> np.ndarray:
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
    return _check_lut(lut)[gray]


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
    lut_arr = _check_lut(lut)
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


@dataclass(frozen=True)
class StagePose:
    """Commanded-and-reached pose of the 6-axis stage carrying the mask mount.

    Attributes
    ----------
    x_mm, y_mm : float
        Lateral translation (mm); moves the true mask by ``+x_mm * 1000 / Delta_m``
        mask pixels along plane ``x`` (columns) and likewise ``y`` (rows).
    z_mm : float
        Axial translation (mm), positive away from the SLM (downstream). The mask's
        distance from the SLM image is ``dz = MaskTransform.defocus_mm + z_mm``.
    rx_rad, ry_rad : float
        Small rotations about the plane's x and y axes (right-handed, rad): the local
        defocus is ``dz(x, y) = dz + rx * y - ry * x`` (x, y in mm from the axis).
    rz_rad : float
        Rotation about the optical axis (rad, counter-clockwise from +x to +y); adds
        to :attr:`MaskTransform.theta`. The stage's z-rotation axis is taken to pass
        through the optical axis.

    Notes
    -----
    Tip/tilt act only through the local defocus; the lateral foreshortening of a
    tilted mask (``1 - cos``, 2e-5 at 6 mrad) is neglected.
    """

    x_mm: float = 0.0
    y_mm: float = 0.0
    z_mm: float = 0.0
    rx_rad: float = 0.0
    ry_rad: float = 0.0
    rz_rad: float = 0.0

    def __post_init__(self):
        for name in ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad"):
            object.__setattr__(self, name, _float_param(f"pose.{name}", getattr(self, name)))

    @classmethod
    def coerce(cls, pose) -> StagePose:
        """A :class:`StagePose` from ``None`` (all zero), a pose, or 6 numbers
        ``(x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad)``."""
        if pose is None:
            return cls()
        if isinstance(pose, StagePose):
            return pose
        try:
            vals = [float(v) for v in pose]
        except (TypeError, ValueError):
            raise ReconInputError(
                "stage pose must be a StagePose or 6 numbers (x_mm, y_mm, z_mm, rx_rad, "
                f"ry_rad, rz_rad), got {pose!r}") from None
        if len(vals) != 6:
            raise ReconInputError(
                "stage pose must have 6 values (x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad), "
                f"got {len(vals)}")
        return cls(*vals)

    def as_tuple(self) -> tuple[float, ...]:
        """``(x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad)``."""
        return (self.x_mm, self.y_mm, self.z_mm, self.rx_rad, self.ry_rad, self.rz_rad)


@dataclass(frozen=True)
class MaskTransform:
    """Ground-truth pose of the physical mask relative to the software's model.

    The model-mask content at model position ``X`` (plane coordinates, mask px)
    appears at plane position ``x`` with (inverse map, evaluated per fine sample)::

        X = A^-1 (x - t - D(x)),   A = m R(theta),
        D(x) = radial * (x / r_c) * (|x| / r_c)^2 + sum_ab poly[:, a, b] yh^a xh^b

    ``r_c`` is the footprint half-diagonal, ``xh = x / (C k/2)``, ``yh = y / (R k/2)``.
    The apparent displacement ``x - X`` is, to first order,
    ``t + theta (-y, x) + (m - 1) (x, y) + D(x)`` (the similarity model of the
    alignment notes plus distortion). ``D`` is defined on plane positions (so the
    inverse map is exact); it is smooth and small, so ``D(x)`` and ``D(X)`` differ by
    far less than a mask pixel.

    Attributes
    ----------
    translation : (float, float)
        ``t = (tx, ty)`` in mask pixels (fractions allowed).
    theta : float
        Rotation about the optical axis (rad, counter-clockwise from +x to +y).
    magnification : float
        ``m`` (> 0): relay magnification error / mask scale.
    radial_px : float
        Radial (cubic) distortion: displacement in mask px at the footprint corners.
    poly : tuple or None
        Polynomial distortion coefficients, shape (2, n, n): ``poly[0]`` for ``Dx``,
        ``poly[1]`` for ``Dy``, ``[a, b]`` multiplies ``yh^a xh^b``; mask px.
    defocus_mm : float
        Distance of the mask from the SLM image plane at stage ``z = 0`` (mm,
        positive downstream); the stage focuses at ``z = -defocus_mm``.
    tip_rad, tilt_rad : float
        Mount rotation about x and y at stage zero (rad); add to the stage's rx, ry.
    """

    translation: tuple[float, float] = (0.0, 0.0)
    theta: float = 0.0
    magnification: float = 1.0
    radial_px: float = 0.0
    poly: tuple | None = None
    defocus_mm: float = 0.0
    tip_rad: float = 0.0
    tilt_rad: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "translation", _vec2("translation", self.translation))
        object.__setattr__(self, "theta", _float_param("theta", self.theta))
        object.__setattr__(self, "magnification",
                           _float_param("magnification", self.magnification, lo=0.0,
                                        lo_open=True))
        object.__setattr__(self, "radial_px", _float_param("radial_px", self.radial_px))
        for name in ("defocus_mm", "tip_rad", "tilt_rad"):
            object.__setattr__(self, name, _float_param(name, getattr(self, name)))
        if self.poly is not None:
            try:
                arr = np.asarray(self.poly, dtype=np.float64)
            except (TypeError, ValueError):
                raise ReconInputError("poly must be numbers of shape (2, n, n)") from None
            if arr.ndim != 3 or arr.shape[0] != 2 or arr.shape[1] != arr.shape[2] \
                    or arr.shape[1] < 1 or not np.all(np.isfinite(arr)):
                raise ReconInputError(
                    f"poly must be finite numbers of shape (2, n, n), got shape {arr.shape}")
            object.__setattr__(self, "poly", _freeze(arr))

    def poly_array(self) -> np.ndarray:
        """Polynomial coefficients as float64 (2, n, n) (zeros (2, 1, 1) if none)."""
        if self.poly is None:
            return np.zeros((2, 1, 1))
        return np.asarray(self.poly, dtype=np.float64)

    def moved(self, dx_px: float = 0.0, dy_px: float = 0.0, dtheta: float = 0.0,
              dz_mm: float = 0.0, drx: float = 0.0, dry: float = 0.0) -> MaskTransform:
        """This transform with extra translation, rotation, defocus and tip/tilt."""
        tx, ty = self.translation
        return MaskTransform(
            translation=(tx + dx_px, ty + dy_px), theta=self.theta + dtheta,
            magnification=self.magnification, radial_px=self.radial_px, poly=self.poly,
            defocus_mm=self.defocus_mm + dz_mm, tip_rad=self.tip_rad + drx,
            tilt_rad=self.tilt_rad + dry)

    def key(self) -> tuple:
        """Hashable summary of the lateral geometry (used for render caches)."""
        return (self.translation, self.theta, self.magnification, self.radial_px, self.poly)


def _freeze(arr: np.ndarray) -> tuple:
    """Nested tuples (hashable) of a float array."""
    if arr.ndim == 1:
        return tuple(float(v) for v in arr)
    return tuple(_freeze(a) for a in arr)


# --------------------------------------------------------------------------- mask


class MaskModel:
    """Random binary-phase mask: the software's model ``M`` and the true mask.

    The model mask is a seeded random array of bits (phase 0 or pi, i.e.
    ``M = +1 / -1``, Sec. 7.3) covering the SLM footprint (``R k x C k`` mask pixels)
    plus ``margin`` mask pixels on every side. The true mask is the model after the
    ground-truth transform (:class:`MaskTransform`) and the stage pose, with optional
    fabrication errors: phase depth ``pi (1 + phase_error)`` and a fraction of
    defective (flipped) pixels. It is rendered on the fine grid by nearest-neighbour
    lookup of the bits at inverse-mapped fine-sample positions (exact for a binary
    mask); beyond the physical mask the substrate is clear (transmission 1).

    Parameters
    ----------
    slm_shape : (int, int)
        SLM pixels (rows, cols), e.g. (96, 120).
    slm_pitch_um : float
        SLM pixel pitch as imaged on the mask plane (um).
    k : int
        Mask pixels per SLM pixel along each axis (>= 1); etendue factor ``k^2``.
    q : int
        Fine samples per mask pixel along each axis (>= 1; >= 4 needed for sub-pixel
        shifts and rotation).
    seed : int
        Seed of the mask pattern (and, through a separate stream, the defects).
    margin : int
        Extra mask pixels on each side of the SLM footprint (>= 0).
    truth : MaskTransform, optional
        Ground-truth misalignment (default: perfectly aligned).
    phase_error : float
        ``epsilon``: the true pi pixels have phase ``pi (1 + epsilon)``.
    defect_fraction : float
        Fraction of mask pixels whose true phase is flipped relative to the model
        (fabrication defects), in [0, 1].
    supersample : int
        ``s >= 1``: each fine sample is the mean of ``s x s`` nearest-neighbour lookups
        (a box-filtered, no longer binary, rendering). With ``s = 1`` (default, exact
        point sampling) mask boundaries snap to the fine grid, so displacements
        smaller than ``1 / (2 q)`` mask px vanish; ``s = 2..4`` restores them at
        ``s^2`` times the (cached) rendering cost.

    Attributes
    ----------
    bits : numpy.ndarray
        uint8 (R k + 2 margin, C k + 2 margin): the model's bits (1 = phase pi).
    true_bits : numpy.ndarray
        uint8, same shape: the bits of the physical mask (with defects).
    fine_shape : (int, int)
        ``(R k q, C k q)``.
    mask_pitch_um, fine_pitch_um : float
        ``slm_pitch_um / k`` and ``slm_pitch_um / (k q)``.
    version : int
        Incremented whenever :attr:`truth` changes (invalidates caches).
    """

    def __init__(self, slm_shape=(96, 120), slm_pitch_um: float = 16.0, k: int = 4,
                 q: int = 4, seed: int = 0, *, margin: int = 16,
                 truth: MaskTransform | None = None, phase_error: float = 0.0,
                 defect_fraction: float = 0.0, supersample: int = 1):
        self.slm_shape = _shape2("slm_shape", slm_shape)
        self.slm_pitch_um = _float_param("slm_pitch_um", slm_pitch_um, lo=0.0, lo_open=True)
        self.k = _int_param("k", k, 1)
        self.q = _int_param("q", q, 1)
        self.seed = _int_param("seed", seed, 0)
        self.margin = _int_param("margin", margin, 0)
        self.supersample = _int_param("supersample", supersample, 1)
        self.phase_error = _float_param("phase_error", phase_error, lo=-1.0, hi=1.0)
        self.defect_fraction = _float_param("defect_fraction", defect_fraction, lo=0.0, hi=1.0)
        r, c = self.slm_shape
        self.fine_shape = (r * self.k * self.q, c * self.k * self.q)
        if self.fine_shape[0] * self.fine_shape[1] > MAX_FINE_SAMPLES:
            raise ReconInputError(
                f"fine grid {self.fine_shape} exceeds {MAX_FINE_SAMPLES} samples; "
                "reduce slm_shape, k or q")
        self.mask_pitch_um = self.slm_pitch_um / self.k
        self.fine_pitch_um = self.mask_pitch_um / self.q
        shape = (r * self.k + 2 * self.margin, c * self.k + 2 * self.margin)
        self.bits = np.random.default_rng(self.seed).integers(0, 2, shape, dtype=np.uint8)
        self.bits.setflags(write=False)
        flips = np.random.default_rng([self.seed, 1]).random(shape) < self.defect_fraction
        self.true_bits = self.bits ^ flips.astype(np.uint8)
        self.true_bits.setflags(write=False)
        self.version = 0
        self._truth = MaskTransform()
        self.truth = truth if truth is not None else MaskTransform()
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    # -- geometry ----------------------------------------------------------------------

    @property
    def truth(self) -> MaskTransform:
        """Ground-truth :class:`MaskTransform` (assigning it invalidates caches)."""
        return self._truth

    @truth.setter
    def truth(self, value: MaskTransform) -> None:
        if not isinstance(value, MaskTransform):
            raise ReconInputError(f"truth must be a MaskTransform, got {type(value).__name__}")
        self._truth = value
        self.version += 1

    @property
    def half_size(self) -> tuple[float, float]:
        """Footprint half-size ``(C k / 2, R k / 2)`` in mask px (x, y)."""
        r, c = self.slm_shape
        return (c * self.k / 2.0, r * self.k / 2.0)

    @property
    def model(self) -> np.ndarray:
        """The model mask ``M`` at mask resolution: float32 +1/-1, shape of :attr:`bits`."""
        return (1.0 - 2.0 * self.bits).astype(np.float32)

    def slm_to_plane(self, row, col) -> tuple[np.ndarray, np.ndarray]:
        """Plane coordinates (mask px) of continuous SLM pixel coordinates.

        SLM pixel ``(r, c)`` spans ``[r, r+1) x [c, c+1)``; its centre is
        ``(r + 0.5, c + 0.5)``. Returns ``(x, y)`` with ``x = c k - C k/2``.
        """
        hx, hy = self.half_size
        return (np.asarray(col, np.float64) * self.k - hx,
                np.asarray(row, np.float64) * self.k - hy)

    def effective_transform(self, pose=None) -> MaskTransform:
        """Ground truth combined with a stage pose (translation in mask px, angles added)."""
        p = StagePose.coerce(pose)
        scale = 1000.0 / self.mask_pitch_um
        return self._truth.moved(p.x_mm * scale, p.y_mm * scale, p.rz_rad, p.z_mm,
                                 p.rx_rad, p.ry_rad)

    def displacement(self, x, y, pose=None) -> tuple[np.ndarray, np.ndarray]:
        """True apparent displacement ``x - X(x)`` of the mask content (mask px).

        Parameters
        ----------
        x, y : array_like
            Plane positions (mask px from the optical axis), broadcastable.
        pose : StagePose or sequence of 6, optional
            Stage pose (default zero).

        Returns
        -------
        (numpy.ndarray, numpy.ndarray)
            float64 ``(dx, dy)``: where the model content that should be at ``x``
            actually is, relative to ``x``; an ideal alignment gives zeros.
        """
        tr = self.effective_transform(pose)
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        ddx, ddy = self._distortion(tr, x, y)
        ainv = self._ainv(tr)
        u = x - tr.translation[0] - ddx
        v = y - tr.translation[1] - ddy
        big_x = ainv[0, 0] * u + ainv[0, 1] * v
        big_y = ainv[1, 0] * u + ainv[1, 1] * v
        return x - big_x, y - big_y

    def _distortion(self, tr: MaskTransform, x, y):
        hx, hy = self.half_size
        rc = math.hypot(hx, hy)
        r2 = (x * x + y * y) / (rc * rc)
        dx = tr.radial_px * (x / rc) * r2
        dy = tr.radial_px * (y / rc) * r2
        if tr.poly is not None:
            p = tr.poly_array()
            n = p.shape[1]
            xn, yn = x / hx, y / hy
            for a in range(n):
                for b in range(n):
                    t = yn**a * xn**b
                    dx = dx + p[0, a, b] * t
                    dy = dy + p[1, a, b] * t
        return dx, dy

    @staticmethod
    def _ainv(tr: MaskTransform) -> np.ndarray:
        c, s = math.cos(tr.theta), math.sin(tr.theta)
        return np.array([[c, s], [-s, c]]) / tr.magnification

    # -- rendering ---------------------------------------------------------------------

    def _render(self, bits, tr: MaskTransform, v0: complex, v1: complex,
                vout: complex) -> np.ndarray:
        hx, hy = self.half_size
        p = tr.poly_array()
        out = np.empty(self.fine_shape, np.complex64)
        _render_mask_kernel(bits, self.margin, float(self.q), self.supersample, hx, hy,
                            self._ainv(tr),
                            tr.translation[0], tr.translation[1], tr.radial_px,
                            math.hypot(hx, hy), np.ascontiguousarray(p[0]),
                            np.ascontiguousarray(p[1]), complex(v0), complex(v1),
                            complex(vout), out)
        return out

    def _cached(self, key, make):
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        val = make()
        val.setflags(write=False)
        with self._lock:
            self._cache[key] = val
            while len(self._cache) > 3:
                self._cache.popitem(last=False)
        return val

    def true_fine(self, pose=None) -> np.ndarray:
        """The true mask transmission on the fine grid for a stage pose.

        Returns
        -------
        numpy.ndarray
            complex64, :attr:`fine_shape`, read-only (cached): ``1`` for phase-0
            pixels, ``exp(i pi (1 + phase_error))`` for phase-pi pixels, ``1`` beyond
            the physical mask.
        """
        tr = self.effective_transform(pose)
        v1 = complex(np.exp(1j * math.pi * (1.0 + self.phase_error)))
        key = ("true", self.version, tr.key())
        return self._cached(key, lambda: self._render(self.true_bits, tr, 1.0, v1, 1.0))

    def model_fine(self, shift=(0.0, 0.0)) -> np.ndarray:
        """The model mask ``M(x - s)`` on the fine grid (software shift ``s``, mask px).

        Returns
        -------
        numpy.ndarray
            complex64 +1/-1, :attr:`fine_shape`, read-only (cached); +1 beyond the
            modelled mask.
        """
        s = _vec2("shift", shift)
        key = ("model", s)
        tr = MaskTransform(translation=s)
        return self._cached(key, lambda: self._render(self.bits, tr, 1.0, -1.0, 1.0))


# --------------------------------------------------------------------------- block sums


def _ramp(u: float, n_total: int, n: int, q_sub: int = 1) -> np.ndarray:
    """``exp(-i 2 pi u j / n_total)`` for ``j = 0, q_sub, 2 q_sub, ...`` (n samples)."""
    j = np.arange(n, dtype=np.float64) * q_sub
    return np.exp(-2j * math.pi * u * j / n_total).astype(np.complex64)


def _block_reduce(vals: np.ndarray, ry, rx, wy, wx, n: int, out_shape):
    out_ap = np.zeros(out_shape, np.complex128)
    out_full = np.zeros(out_shape, np.complex128)
    _block_reduce_kernel(vals, ry.astype(np.complex64), rx.astype(np.complex64),
                         wy.astype(np.float32), wx.astype(np.float32), int(n), out_ap, out_full)
    return out_ap, out_full


def _check_u0(u0, fine_shape) -> tuple[float, float]:
    ux, uy = _vec2("u0", u0)
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

    Phase conjugation per SLM pixel (holography-evaluation.md 8(c); Eq. 7.12 with a
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
        fill = _float_param("fill", fill)
        r0, r1, c0, c1 = pt
        out = np.full(mask_model.slm_shape, fill, np.float64)
        out[r0:r1, c0:c1] = phase[r0:r1, c0:c1]
        return out
    return phase


def _model_coefficients(mm: MaskModel, u0, shift) -> np.ndarray:
    """``b_p`` of :func:`spot_phase` (complex128 (R, C))."""
    ux, uy = _check_u0(u0, mm.fine_shape)
    sx, sy = _vec2("shift", shift)
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
        ry = _ramp(uy, ny, hb, q)
        rx = _ramp(ux, nx, wb, q)
        _, full = _block_reduce(vals.astype(np.complex64), ry, rx, np.ones(hb), np.ones(wb), k,
                                (rows, cols))
        return full * (gx * gy)
    vals = mm.model_fine((sx, sy))
    ry = _ramp(uy, ny, ny)
    rx = _ramp(ux, nx, nx)
    _, full = _block_reduce(vals, ry, rx, np.ones(ny), np.ones(nx), k * q, (rows, cols))
    return full


# --------------------------------------------------------------------------- SLM, relay


@dataclass(frozen=True)
class SlmModel:
    """Phase-only SLM: gray -> phase LUT, fill factor, gap, crosstalk.

    Each SLM pixel spans ``n = k q`` fine samples per axis; its active area is the
    centred square of ``n_a = max(1, round(sqrt(fill_factor) n))`` samples per axis
    with field ``exp(i phi_p)``, the inter-pixel gap carries the unmodulated field
    ``gap_amplitude`` (real; 0 = dark gaps). ``crosstalk_px > 0`` blurs the *phase*
    (fringing fields act on the liquid-crystal response, before the exponential) with
    a Gaussian of standard deviation ``crosstalk_px`` SLM pixels on the fine grid
    (nearest-edge boundary), which makes the field inside a pixel non-uniform.

    Parameters
    ----------
    lut : array_like, optional
        256 phases (radians); default :func:`linear_lut` (``2 pi g / 256``).
    fill_factor : float
        Active area fraction in (0, 1].
    gap_amplitude : float
        Field amplitude of the gaps, in [0, 1].
    crosstalk_px : float
        Phase blur sigma in SLM pixels (>= 0; 0 = off).
    """

    lut: tuple | None = None
    fill_factor: float = 1.0
    gap_amplitude: float = 0.0
    crosstalk_px: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "lut", tuple(_check_lut(self.lut).tolist()))
        object.__setattr__(self, "fill_factor",
                           _float_param("fill_factor", self.fill_factor, lo=0.0, hi=1.0,
                                        lo_open=True))
        object.__setattr__(self, "gap_amplitude",
                           _float_param("gap_amplitude", self.gap_amplitude, lo=0.0, hi=1.0))
        object.__setattr__(self, "crosstalk_px",
                           _float_param("crosstalk_px", self.crosstalk_px, lo=0.0, hi=2.0))

    @property
    def lut_array(self) -> np.ndarray:
        """The LUT as float64 (256,)."""
        return np.asarray(self.lut, np.float64)

    def gray_to_phase(self, gray: np.ndarray) -> np.ndarray:
        """Phase (float64 rad) of uint8 gray levels through this SLM's LUT."""
        return gray_to_phase(gray, self.lut_array)

    def phase_to_gray(self, phase) -> np.ndarray:
        """uint8 gray levels nearest to ``phase`` through this SLM's LUT inverse."""
        return phase_to_gray(phase, self.lut_array)

    def aperture(self, n: int) -> np.ndarray:
        """1-D active-area profile of one pixel over its ``n`` fine samples (float32 0/1)."""
        na = max(1, min(n, int(round(math.sqrt(self.fill_factor) * n))))
        a = np.zeros(n, np.float32)
        start = (n - na) // 2
        a[start:start + na] = 1.0
        return a


@dataclass(frozen=True)
class RelayModel:
    """Relay SLM -> mask: defocus and tilt by angular-spectrum propagation.

    The field at the mask is the SLM field propagated over the local distance
    ``dz(x, y)`` on the fine grid (angular spectrum method, circular boundary)::

        U = IFFT{ FFT{s} P(f) H_dz(f) },
        H_dz(f) = exp(-i pi lambda dz |f|^2)                          (paraxial, default)
        H_dz(f) = exp(-i 2 pi dz (1/lambda - sqrt(1/lambda^2 - |f|^2)))  (exact)

    (the piston ``exp(i 2 pi dz / lambda)`` is dropped: the path from a tilted mask
    onwards to the Fourier lens compensates it). ``P`` is the relay pupil, ``|f| <=
    NA / lambda`` (``na=None``: no pupil within the fine grid's band). A tilted mask
    (``dz`` linear in x, y) is handled by propagating to ``L`` equally spaced planes
    spanning the field's ``dz`` range, ``level_step_um`` or less apart, and blending
    them with linear (tent) weights per fine sample:
    ``U(x) = sum_l w_l(x) U_l(x)``. With ``dz = 0`` everywhere and no pupil the relay
    is the identity (no FFT).

    Parameters
    ----------
    wavelength_um : float
        Laser wavelength (um), e.g. 0.66.
    na : float or None
        Image-side numerical aperture of the relay, or None (unlimited).
    paraxial : bool
        Fresnel (separable, faster) or exact angular-spectrum transfer function.
    level_step_um : float or None
        Largest spacing of the blended planes for tilt; default
        ``0.25 Delta^2 / (pi lambda)`` (quarter-radian phase at the SLM pixel frequency
        ``1/Delta``).
    max_levels : int
        Cap on the number of planes (>= 2).

    Notes
    -----
    Behaviour of the spot metric (16 um SLM pixels, k = 4, 0.66 um): with ideal
    sharp-edged pixels and no pupil the response to defocus has a cusp at focus (the
    pixel edges carry ~20 % of the phase-conjugation overlap: 0.80 of the peak at
    25 um, 0.51 at 0.2 mm) and a Talbot-like partial revival near 0.3 mm; with a pupil
    (``na = 0.05``) or SLM crosstalk (0.5 px) it is smooth and monotonic out to
    0.8 mm, as a parabola fit expects. The default plane spacing reproduces a 3x finer
    spacing to ~1 % of the spot power. Cost: one plane (defocus only) adds two fine
    FFTs (~+50 ms at 1536 x 1920); a tilt adds one inverse FFT and a weight pass per
    plane (e.g. 0.2 rad over 1.9 mm: 14 planes, 0.45-0.6 s per render).
    """

    wavelength_um: float = 0.66
    na: float | None = None
    paraxial: bool = True
    level_step_um: float | None = None
    max_levels: int = 33

    def __post_init__(self):
        object.__setattr__(self, "wavelength_um",
                           _float_param("wavelength_um", self.wavelength_um, lo=0.0,
                                        lo_open=True))
        if self.na is not None:
            object.__setattr__(self, "na", _float_param("na", self.na, lo=0.0, hi=1.0,
                                                        lo_open=True))
        if self.level_step_um is not None:
            object.__setattr__(self, "level_step_um",
                               _float_param("level_step_um", self.level_step_um, lo=0.0,
                                            lo_open=True))
        object.__setattr__(self, "max_levels", _int_param("max_levels", self.max_levels, 2))


# --------------------------------------------------------------------------- camera


@dataclass(frozen=True)
class CameraMapping:
    """Far field -> camera pixels: the affine ``c = M u + b`` and the camera shape.

    ``u = (ux, uy)`` in far-field samples (cycles per SLM aperture), ``c = (x, y)``
    camera pixels (centres at integers). Energy is conserved: when a camera pixel
    covers at least one far-field grid point (``|det M| <= pad^2``) each grid point's
    energy is split bilinearly among the 4 nearest pixel centres (binning); otherwise
    each camera pixel samples the far-field intensity by bilinear interpolation times
    the grid points per pixel ``pad^2 / |det M|``. Far field beyond the fine grid's band
    is not modelled (zero).

    Parameters
    ----------
    shape : (int, int)
        Camera (rows, cols).
    matrix : 2x2
        ``M`` in camera px per far-field sample (x, y order).
    offset : (float, float) or None
        ``b``, camera position of the zero order; default ``(cols // 2, rows // 2)``.
    """

    shape: tuple[int, int] = (480, 640)
    matrix: tuple = ((1.0, 0.0), (0.0, 1.0))
    offset: tuple[float, float] | None = None

    def __post_init__(self):
        shape = _shape2("camera shape", self.shape)
        object.__setattr__(self, "shape", shape)
        try:
            m = np.asarray(self.matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise ReconInputError("camera matrix must be 2x2 finite numbers") from None
        if m.shape != (2, 2) or not np.all(np.isfinite(m)):
            raise ReconInputError(f"camera matrix must be 2x2 finite numbers, got {m.shape}")
        if abs(np.linalg.det(m)) < 1e-9:
            raise ReconInputError("camera matrix is singular")
        object.__setattr__(self, "matrix", _freeze(m))
        off = (shape[1] // 2, shape[0] // 2) if self.offset is None else self.offset
        object.__setattr__(self, "offset", _vec2("camera offset", off))

    @classmethod
    def from_params(cls, shape=(480, 640), scale: float = 1.0, rotation: float = 0.0,
                    offset=None, scale_y: float | None = None,
                    flip_x: bool = False) -> CameraMapping:
        """Affine from a scale (camera px per far-field sample), rotation (rad) and offset.

        ``M = R(rotation) diag(+-scale, scale_y)`` (``scale_y`` defaults to ``scale``;
        ``flip_x`` mirrors x).
        """
        sx = _float_param("scale", scale, lo=0.0, lo_open=True)
        sy = sx if scale_y is None else _float_param("scale_y", scale_y, lo=0.0, lo_open=True)
        th = _float_param("rotation", rotation)
        c, s = math.cos(th), math.sin(th)
        m = np.array([[c, -s], [s, c]]) @ np.diag([-sx if flip_x else sx, sy])
        return cls(shape=shape, matrix=_freeze(m), offset=offset)

    @property
    def matrix_array(self) -> np.ndarray:
        """``M`` as float64 (2, 2)."""
        return np.asarray(self.matrix, np.float64)

    def to_camera(self, u) -> np.ndarray:
        """Camera ``(x, y)`` of far-field ``u`` (..., 2) -> float64 (..., 2)."""
        u = np.asarray(u, np.float64)
        return u @ self.matrix_array.T + np.asarray(self.offset)

    def to_far_field(self, c) -> np.ndarray:
        """Far-field ``u`` of camera ``(x, y)`` (..., 2) -> float64 (..., 2)."""
        c = np.asarray(c, np.float64) - np.asarray(self.offset)
        return c @ np.linalg.inv(self.matrix_array).T


# --------------------------------------------------------------------------- drift


class LaserDrift:
    """Slow multiplicative random walk of the laser power (seeded, advanced explicitly).

    ``factor = factor0 * exp(X)`` with ``X`` an Ornstein-Uhlenbeck process (a random
    walk pulled back to 0 with time constant ``tau_s``; ``tau_s=None`` gives a pure
    random walk), sampled exactly::

        X(t + dt) = X(t) e^{-dt/tau} + sigma sqrt(tau/2 (1 - e^{-2 dt/tau})) N(0, 1)

    (``sigma sqrt(dt) N(0, 1)`` for the pure walk). The same seed and the same sequence
    of :meth:`advance` calls reproduce the same factors.

    Parameters
    ----------
    seed : int
        RNG seed.
    sigma_per_sqrt_s : float
        Diffusion of ``log(power)`` per square-root second (e.g. 1e-3).
    tau_s : float or None
        Mean-reversion time (s), or None.
    factor0 : float
        Initial (and mean) factor.
    """

    def __init__(self, seed: int = 0, sigma_per_sqrt_s: float = 1e-3,
                 tau_s: float | None = 600.0, factor0: float = 1.0):
        self.seed = _int_param("seed", seed, 0)
        self.sigma = _float_param("sigma_per_sqrt_s", sigma_per_sqrt_s, lo=0.0)
        self.tau_s = None if tau_s is None else _float_param("tau_s", tau_s, lo=0.0,
                                                              lo_open=True)
        self.factor0 = _float_param("factor0", factor0, lo=0.0, lo_open=True)
        self.reset()

    def reset(self) -> None:
        """Back to time 0, factor ``factor0``, and the seed's first draw."""
        self._rng = np.random.default_rng(self.seed)
        self._x = 0.0
        self.time_s = 0.0

    @property
    def factor(self) -> float:
        """Current multiplicative power factor."""
        return self.factor0 * math.exp(self._x)

    def advance(self, dt_s: float) -> float:
        """Advance the clock by ``dt_s`` seconds (>= 0); returns the new factor."""
        dt = _float_param("dt_s", dt_s, lo=0.0)
        if dt > 0.0 and self.sigma > 0.0:
            z = float(self._rng.standard_normal())
            if self.tau_s is None:
                self._x += self.sigma * math.sqrt(dt) * z
            else:
                a = math.exp(-dt / self.tau_s)
                self._x = self._x * a + self.sigma * math.sqrt(
                    self.tau_s / 2.0 * (1.0 - a * a)) * z
        self.time_s += dt
        return self.factor


# --------------------------------------------------------------------------- display


@dataclass
class _Relayed:
    """Defocus field of a pose: ``dz(i, j) = dz0 + gy y_um(i) + gx x_um(j)`` (um)."""

    dz0: float
    gy: float
    gx: float


class HolographicDisplayModel:
    """SLM -> relay -> random mask -> Fourier lens -> camera, for a gray image and pose.

    Parameters
    ----------
    mask : MaskModel
        Mask model with its ground truth (sets the SLM shape, k, q and pitches).
    slm : SlmModel, optional
        SLM response (default: linear LUT, fill factor 1, no crosstalk).
    relay : RelayModel, optional
        Relay optics (default: 0.66 um, no pupil, paraxial).
    camera : CameraMapping, optional
        Far field -> camera affine and camera shape (default 480 x 640, identity,
        zero order at the centre).
    drift : LaserDrift, optional
        Laser power drift (default: a seeded drift with factor 1 until advanced).
    power_e_per_s : float
        Laser power scale: photo-electrons per second the camera would collect if the
        entire far field of a fully transmitting SLM fell on it.
    pad : int
        Far-field oversampling (zero padding of the fine field before the FFT, >= 1):
        ``pad = 2`` resolves the sinc profile of a spot; the cost grows as ``pad^2``.

    Notes
    -----
    Normalisation: with ``N`` fine samples and ``N_pad = pad^2 N`` FFT samples, the
    far-field grid value is ``power * drift * |F|^2 / (N N_pad)``; by Parseval the
    whole far field sums to ``power * drift * mean |U m|^2 <= power * drift``.
    """

    def __init__(self, mask: MaskModel, slm: SlmModel | None = None,
                 relay: RelayModel | None = None, camera: CameraMapping | None = None,
                 drift: LaserDrift | None = None, power_e_per_s: float = 1e9, pad: int = 1):
        if not isinstance(mask, MaskModel):
            raise ReconInputError(f"mask must be a MaskModel, got {type(mask).__name__}")
        self._mask = mask
        self._slm = slm if slm is not None else SlmModel()
        self._relay = relay if relay is not None else RelayModel()
        self._camera = camera if camera is not None else CameraMapping()
        for name, val, typ in (("slm", self._slm, SlmModel), ("relay", self._relay, RelayModel),
                               ("camera", self._camera, CameraMapping)):
            if not isinstance(val, typ):
                raise ReconInputError(f"{name} must be a {typ.__name__}, got {type(val).__name__}")
        self.drift = drift if drift is not None else LaserDrift()
        if not isinstance(self.drift, LaserDrift):
            raise ReconInputError("drift must be a LaserDrift")
        self.power_e_per_s = _float_param("power_e_per_s", power_e_per_s, lo=0.0)
        self.pad = _int_param("pad", pad, 1)
        self._n = mask.k * mask.q
        ap = self._slm.aperture(self._n)
        rows, cols = mask.slm_shape
        self._wy = np.tile(ap, rows)
        self._wx = np.tile(ap, cols)
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    # -- properties --------------------------------------------------------------------

    mask = property(lambda self: self._mask, doc="The :class:`MaskModel`.")
    slm = property(lambda self: self._slm, doc="The :class:`SlmModel`.")
    relay = property(lambda self: self._relay, doc="The :class:`RelayModel`.")
    camera = property(lambda self: self._camera, doc="The :class:`CameraMapping`.")

    @property
    def slm_shape(self) -> tuple[int, int]:
        """SLM (rows, cols)."""
        return self._mask.slm_shape

    @property
    def fov_samples(self) -> tuple[int, int]:
        """Display field of view (Eq. 7.9) in far-field samples, ``(C k, R k)`` (x, y)."""
        r, c = self._mask.slm_shape
        return (c * self._mask.k, r * self._mask.k)

    @property
    def slm_band_samples(self) -> tuple[int, int]:
        """Width of the mask-free SLM band in far-field samples, ``(C, R)`` (x, y)."""
        r, c = self._mask.slm_shape
        return (c, r)

    def spot_camera_px(self, u0) -> tuple[float, float]:
        """Camera position ``(x, y)`` of far-field frequency ``u0`` (the affine)."""
        return tuple(float(v) for v in self._camera.to_camera(_vec2("u0", u0)))

    # -- geometry of a pose ------------------------------------------------------------

    def _defocus(self, pose: StagePose) -> _Relayed:
        tr = self._mask.effective_transform(pose)
        # dz(x, y) = dz0 + rx * y - ry * x   (x, y, dz in um)
        return _Relayed(dz0=tr.defocus_mm * 1000.0, gy=tr.tip_rad, gx=-tr.tilt_rad)

    def _plane_um(self):
        mm = self._mask
        ny, nx = mm.fine_shape
        hx, hy = mm.half_size
        y = ((np.arange(ny) + 0.5) / mm.q - hy) * mm.mask_pitch_um
        x = ((np.arange(nx) + 0.5) / mm.q - hx) * mm.mask_pitch_um
        return y, x

    def _levels(self, rel: _Relayed):
        """Planes ``z_l`` and tent spacing for the blended propagation (or None)."""
        y, x = self._plane_um()
        span = abs(rel.gy) * (y[-1] - y[0]) + abs(rel.gx) * (x[-1] - x[0])
        if span == 0.0:
            return [rel.dz0], None
        lo = rel.dz0 - 0.5 * span
        step = self._relay.level_step_um
        if step is None:
            step = 0.25 * self._mask.slm_pitch_um**2 / (math.pi * self._relay.wavelength_um)
        n_lv = min(self._relay.max_levels, max(2, int(math.ceil(span / step)) + 1))
        spacing = span / (n_lv - 1)
        return [lo + i * spacing for i in range(n_lv)], spacing

    def _transfer(self, dz_um: float) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        mm = self._mask
        ny, nx = mm.fine_shape
        lam = self._relay.wavelength_um
        fy = sfft.fftfreq(ny, d=mm.fine_pitch_um)
        fx = sfft.fftfreq(nx, d=mm.fine_pitch_um)
        if self._relay.paraxial:
            hy = np.exp(-1j * math.pi * lam * dz_um * fy * fy).astype(np.complex64)
            hx = np.exp(-1j * math.pi * lam * dz_um * fx * fx).astype(np.complex64)
            return hy, hx
        f2 = (fy * fy)[:, None] + (fx * fx)[None, :]
        arg = np.maximum(1.0 / lam**2 - f2, 0.0)
        h = np.exp(-2j * math.pi * dz_um * (1.0 / lam - np.sqrt(arg)))
        h[f2 > 1.0 / lam**2] = 0.0
        return h.astype(np.complex64)

    def _pupil(self) -> np.ndarray | None:
        if self._relay.na is None:
            return None
        mm = self._mask
        ny, nx = mm.fine_shape
        fy = sfft.fftfreq(ny, d=mm.fine_pitch_um)
        fx = sfft.fftfreq(nx, d=mm.fine_pitch_um)
        fc = self._relay.na / self._relay.wavelength_um
        return ((fy * fy)[:, None] + (fx * fx)[None, :]) <= fc * fc

    def _is_identity(self, rel: _Relayed) -> bool:
        levels, spacing = self._levels(rel)
        return self._relay.na is None and spacing is None and levels[0] == 0.0

    def _tent(self, rel: _Relayed, z_l: float, spacing: float) -> np.ndarray:
        """Blending weight ``max(0, 1 - |dz(x) - z_l| / spacing)`` (float32 fine grid)."""
        y, x = self._plane_um()
        dz_y = (rel.dz0 + rel.gy * y - z_l).astype(np.float32)
        dz_x = (rel.gx * x).astype(np.float32)
        w = np.abs(dz_y[:, None] + dz_x[None, :])
        w *= np.float32(-1.0 / spacing)
        w += np.float32(1.0)
        np.maximum(w, 0.0, out=w)
        return w

    def _propagate(self, field: np.ndarray, rel: _Relayed,
                   transpose: bool = False) -> np.ndarray:
        """Relay: ``U = sum_l w_l P_l field``; with ``transpose``: ``sum_l P_l (w_l field)``.

        ``P_l`` is symmetric (``H(-f) = H(f)`` on the FFT grid), so the second form is
        the transpose of the first (used by the direct spot evaluation). Returns
        ``field`` itself (no copy) when the relay is the identity for this pose.
        """
        if self._is_identity(rel):
            return field
        levels, spacing = self._levels(rel)
        pupil = self._pupil()
        if spacing is None:  # one plane: a shift-invariant transfer function
            spec = sfft.fft2(field, workers=WORKERS)
            if pupil is not None:
                spec *= pupil
            self._apply_transfer(spec, levels[0])
            return sfft.ifft2(spec, workers=WORKERS, overwrite_x=True)
        if transpose:
            acc = np.zeros(field.shape, np.complex64)
            for z_l in levels:
                w = self._tent(rel, z_l, spacing)
                if not np.any(w):
                    continue
                spec = sfft.fft2(field * w, workers=WORKERS, overwrite_x=True)
                self._apply_transfer(spec, z_l)
                acc += spec
            if pupil is not None:
                acc *= pupil
            return sfft.ifft2(acc, workers=WORKERS, overwrite_x=True)
        spec0 = sfft.fft2(field, workers=WORKERS)
        if pupil is not None:
            spec0 *= pupil
        out = np.zeros(field.shape, np.complex64)
        for z_l in levels:
            w = self._tent(rel, z_l, spacing)
            if not np.any(w):
                continue
            spec = spec0.copy()
            self._apply_transfer(spec, z_l)
            u_l = sfft.ifft2(spec, workers=WORKERS, overwrite_x=True)
            u_l *= w
            out += u_l
        return out

    def _apply_transfer(self, spec: np.ndarray, dz_um: float) -> None:
        """In place: ``spec *= H_dz``."""
        if dz_um == 0.0:
            return
        h = self._transfer(dz_um)
        if isinstance(h, tuple):
            spec *= h[1][None, :]
            spec *= h[0][:, None]
        else:
            spec *= h

    # -- SLM field ---------------------------------------------------------------------

    def _slm_fine_field(self, phase: np.ndarray) -> np.ndarray:
        """Box-upsampled SLM field on the fine grid (Eq. 7.15), complex64 (Ny, Nx)."""
        rows, cols = self.slm_shape
        n = self._n
        slm = self._slm
        ap = slm.aperture(n)
        a4 = (ap[:, None] * ap[None, :])[None, :, None, :]
        if slm.crosstalk_px > 0.0:
            from scipy.ndimage import gaussian_filter1d

            ph = np.repeat(np.repeat(phase.astype(np.float32), n, axis=0), n, axis=1)
            sigma = slm.crosstalk_px * n
            ph = gaussian_filter1d(ph, sigma, axis=0, mode="nearest")
            ph = gaussian_filter1d(ph, sigma, axis=1, mode="nearest")
            field = np.empty(ph.shape, np.complex64)
            field.real = np.cos(ph)
            field.imag = np.sin(ph)
            a_full = np.tile(a4[0, :, 0, :], (rows, cols))
            field *= a_full
            if slm.gap_amplitude:
                field += np.float32(slm.gap_amplitude) * (1.0 - a_full)
            return field
        s = np.exp(1j * phase).astype(np.complex64)
        out = np.empty((rows, n, cols, n), np.complex64)
        np.multiply(s[:, None, :, None], a4, out=out)
        if slm.gap_amplitude and slm.fill_factor < 1.0:
            out += (np.float32(slm.gap_amplitude) * (1.0 - a4)).astype(np.complex64)
        return out.reshape(rows * n, cols * n)

    def _phase_of(self, gray) -> np.ndarray:
        return self._slm.gray_to_phase(_check_gray(gray, self.slm_shape))

    # -- far field ---------------------------------------------------------------------

    def _spectrum(self, phase: np.ndarray, pose) -> np.ndarray:
        pose = StagePose.coerce(pose)
        u = self._propagate(self._slm_fine_field(phase), self._defocus(pose))
        u *= self._mask.true_fine(pose)
        ny, nx = self._mask.fine_shape
        shape = (ny * self.pad, nx * self.pad)
        return sfft.fft2(u, s=shape, workers=WORKERS, overwrite_x=True)

    def _scale(self) -> float:
        ny, nx = self._mask.fine_shape
        n = float(ny * nx)
        return self.power_e_per_s * self.drift.factor / (n * n * self.pad**2)

    def far_field(self, gray: np.ndarray, pose=None) -> np.ndarray:
        """Far-field intensity on the (padded) FFT grid, zero order at the centre.

        Parameters
        ----------
        gray : numpy.ndarray
            uint8 (R, C) gray levels.
        pose : StagePose or sequence of 6, optional
            Stage pose (default zero).

        Returns
        -------
        numpy.ndarray
            float64 ``(pad Ny, pad Nx)``, e-/s per grid point; index ``[i, j]`` is
            ``u = ((j - pad Nx // 2) / pad, (i - pad Ny // 2) / pad)``.
        """
        return self.far_field_phase(self._phase_of(gray), pose)

    def far_field_phase(self, phase: np.ndarray, pose=None) -> np.ndarray:
        """:meth:`far_field` for an ideal (unquantised) SLM phase (float (R, C), rad)."""
        phase = _check_phase(phase, self.slm_shape)
        spec = self._spectrum(phase, pose)
        inten = spec.real * spec.real + spec.imag * spec.imag
        return sfft.fftshift(inten).astype(np.float64) * self._scale()

    def render(self, gray: np.ndarray, pose=None) -> np.ndarray:
        """Camera irradiance for a displayed gray image and a stage pose.

        Parameters
        ----------
        gray : numpy.ndarray
            uint8 (R, C): SLM gray levels (through the LUT).
        pose : StagePose or sequence of 6, optional
            ``(x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad)`` (default zero).

        Returns
        -------
        numpy.ndarray
            float64, camera shape, photo-electrons per second per pixel (no noise;
            current laser drift factor applied).
        """
        return self.render_phase(self._phase_of(gray), pose)

    def render_phase(self, phase: np.ndarray, pose=None) -> np.ndarray:
        """:meth:`render` for an ideal (unquantised) SLM phase (float (R, C), rad)."""
        phase = _check_phase(phase, self.slm_shape)
        return self._to_camera(self._spectrum(phase, pose))

    def _to_camera(self, spec: np.ndarray) -> np.ndarray:
        cam = self._camera
        rows, cols = cam.shape
        m = cam.matrix_array
        b = np.asarray(cam.offset)
        pny, pnx = spec.shape
        pad = self.pad
        scale = self._scale()
        # far-field grid index range visible by the camera (with a 2-px border)
        corners = np.array([[-2, -2], [cols + 1, -2], [-2, rows + 1], [cols + 1, rows + 1]],
                           np.float64)
        uc = cam.to_far_field(corners) * pad  # grid units
        jlo = max(int(math.floor(uc[:, 0].min())) - 1, -(pnx // 2))
        jhi = min(int(math.ceil(uc[:, 0].max())) + 1, (pnx - 1) // 2)
        ilo = max(int(math.floor(uc[:, 1].min())) - 1, -(pny // 2))
        ihi = min(int(math.ceil(uc[:, 1].max())) + 1, (pny - 1) // 2)
        out = np.zeros(rows * cols, np.float64)
        if jlo > jhi or ilo > ihi:
            return out.reshape(rows, cols)
        gi = np.arange(ilo, ihi + 1)
        gj = np.arange(jlo, jhi + 1)
        sub = spec[np.ix_(gi % pny, gj % pnx)]
        inten = (sub.real * sub.real + sub.imag * sub.imag).astype(np.float64) * scale
        det = abs(np.linalg.det(m))
        if det <= pad * pad:  # bin: split each grid point over 4 pixel centres
            uy = (gi / pad)[:, None]
            ux = (gj / pad)[None, :]
            cx = (m[0, 0] * ux + m[0, 1] * uy + b[0]).ravel()
            cy = (m[1, 0] * ux + m[1, 1] * uy + b[1]).ravel()
            w = inten.ravel()
            x0 = np.floor(cx)
            y0 = np.floor(cy)
            fx = cx - x0
            fy = cy - y0
            x0 = x0.astype(np.int64)
            y0 = y0.astype(np.int64)
            for dx, dy, ww in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                               (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
                xx = x0 + dx
                yy = y0 + dy
                ok = (xx >= 0) & (xx < cols) & (yy >= 0) & (yy < rows)
                out += np.bincount(yy[ok] * cols + xx[ok], weights=(w * ww)[ok],
                                   minlength=rows * cols)
            return out.reshape(rows, cols)
        # interpolate: sample the intensity at each pixel centre (grid points per pixel)
        yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64)
        minv = np.linalg.inv(m)
        gx = (minv[0, 0] * (xx - b[0]) + minv[0, 1] * (yy - b[1])) * pad - jlo
        gy = (minv[1, 0] * (xx - b[0]) + minv[1, 1] * (yy - b[1])) * pad - ilo
        h, w_ = inten.shape
        x0 = np.floor(gx).astype(np.int64)
        y0 = np.floor(gy).astype(np.int64)
        fx = gx - x0
        fy = gy - y0
        val = np.zeros((rows, cols), np.float64)
        for dx, dy, ww in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                           (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            xi = x0 + dx
            yi = y0 + dy
            ok = (xi >= 0) & (xi < w_) & (yi >= 0) & (yi < h)
            val[ok] += ww[ok] * inten[yi[ok], xi[ok]]
        return val * (pad * pad / det)

    # -- direct spot evaluation --------------------------------------------------------

    def _spot_kernel(self, pose: StagePose, u0: tuple[float, float]):
        """Cached ``(c, c_gap)`` or fine ``G`` such that the spot amplitude is linear.

        ``A(u0) = sum_x U(x) m(x) e^{-i 2 pi u0 . x} = sum_x s(x) G(x)`` with
        ``G = sum_l P_l(w_l T)``, ``T = m e^{-i 2 pi u0 . x}``; without crosstalk the
        SLM field is piecewise constant, so ``A = sum_p e^{i phi_p} c_p + c_gap`` with
        ``c_p`` the aperture-weighted block sums of ``G``.
        """
        key = (self._mask.version, pose.as_tuple(), u0)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        mm = self._mask
        ny, nx = mm.fine_shape
        rows, cols = mm.slm_shape
        rel = self._defocus(pose)
        ry = _ramp(u0[1], ny, ny)
        rx = _ramp(u0[0], nx, nx)
        mtrue = mm.true_fine(pose)
        trivial = self._is_identity(rel)
        if trivial:
            g = mtrue
        else:
            t = mtrue * ry[:, None]
            t *= rx[None, :]
            g = self._propagate(t, rel, transpose=True)
            ry = np.ones(ny, np.complex64)
            rx = np.ones(nx, np.complex64)
        if self._slm.crosstalk_px > 0.0:
            if trivial:
                g = mtrue * ry[:, None]
                g *= rx[None, :]
            val = ("fine", g)
        else:
            c_ap, c_full = _block_reduce(g, ry, rx, self._wy, self._wx, self._n, (rows, cols))
            c_gap = complex((c_full - c_ap).sum()) * self._slm.gap_amplitude
            val = ("coef", c_ap, c_gap)
        with self._lock:
            self._cache[key] = val
            while len(self._cache) > (4 if val[0] == "fine" else 64):
                self._cache.popitem(last=False)
        return val

    def spot_amplitude_phase(self, phase: np.ndarray, u0, pose=None) -> complex:
        """Complex far-field amplitude ``A(u0)`` for an ideal SLM phase (unnormalised).

        ``A(u0) = sum_x U(x) m(x) exp(-i 2 pi (ux j/Nx + uy i/Ny))``, the FFT of the
        field behind the mask evaluated at ``u0`` (any real ``u0``, also off-grid).
        """
        phase = _check_phase(phase, self.slm_shape)
        pose = StagePose.coerce(pose)
        u0 = _check_u0(u0, self._mask.fine_shape)
        kern = self._spot_kernel(pose, u0)
        if kern[0] == "coef":
            s = np.exp(1j * phase)
            return complex(np.sum(s * kern[1]) + kern[2])
        field = self._slm_fine_field(phase)
        return complex(np.dot(field.ravel(), kern[1].ravel()))

    def spot_power(self, gray: np.ndarray, u0, pose=None) -> float:
        """Direct spot evaluation: far-field intensity at ``u0`` without the full FFT.

        Parameters
        ----------
        gray : numpy.ndarray
            uint8 (R, C) gray levels.
        u0 : (float, float)
            Far-field frequency (samples).
        pose : StagePose or sequence of 6, optional
            Stage pose.

        Returns
        -------
        float
            ``power * drift * |A(u0)|^2 / N^2``: e-/s in one (unpadded) far-field
            sample at ``u0``, equal to :meth:`far_field` at that sample for ``pad = 1``.
            The first call for a (pose, u0) costs one pass over the fine grid (plus the
            relay FFTs when defocused); later calls cost O(R C).
        """
        return self.spot_power_phase(self._phase_of(gray), u0, pose)

    def spot_power_phase(self, phase: np.ndarray, u0, pose=None) -> float:
        """:meth:`spot_power` for an ideal (unquantised) SLM phase (float (R, C), rad)."""
        a = self.spot_amplitude_phase(phase, u0, pose)
        ny, nx = self._mask.fine_shape
        n = float(ny * nx)
        return self.power_e_per_s * self.drift.factor * (a.real**2 + a.imag**2) / (n * n)


# --------------------------------------------------------------------------- metric


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
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 2 or frame.dtype.kind not in "fiu":
        raise ReconInputError("frame must be a 2-D real numpy array")
    window = _int_param("window", window, 1)
    if window % 2 == 0:
        raise ReconInputError(f"window must be odd, got {window}")
    ring = window if ring is None else _int_param("ring", ring, 1)
    rows, cols = frame.shape
    if window > min(rows, cols):
        raise ReconInputError(f"window {window} is larger than the frame {frame.shape}")
    x, y = _vec2("spot_px", spot_px)
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
