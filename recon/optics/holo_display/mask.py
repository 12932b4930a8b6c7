"""Stage pose, ground-truth mask transform and the random binary-phase mask (fine grid).

Part of :mod:`recon.optics.holo_display` (see its docstring for the model).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...errors import ReconInputError
from ...validate import as_int, as_shape2, as_vec2, finite_float
from .basics import MAX_FINE_SAMPLES, render_mask_kernel


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
        to ``MaskTransform.theta``. The stage's z-rotation axis is taken to pass
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
            object.__setattr__(self, name, finite_float(getattr(self, name), f"pose.{name}"))

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
        object.__setattr__(self, "translation", as_vec2(self.translation, "translation"))
        object.__setattr__(self, "theta", finite_float(self.theta, "theta"))
        object.__setattr__(self, "magnification",
                           finite_float(self.magnification, "magnification", lo=0.0,
                                        lo_open=True))
        object.__setattr__(self, "radial_px", finite_float(self.radial_px, "radial_px"))
        for name in ("defocus_mm", "tip_rad", "tilt_rad"):
            object.__setattr__(self, name, finite_float(getattr(self, name), name))
        if self.poly is not None:
            try:
                arr = np.asarray(self.poly, dtype=np.float64)
            except (TypeError, ValueError):
                raise ReconInputError("poly must be numbers of shape (2, n, n)") from None
            if arr.ndim != 3 or arr.shape[0] != 2 or arr.shape[1] != arr.shape[2] \
                    or arr.shape[1] < 1 or not np.all(np.isfinite(arr)):
                raise ReconInputError(
                    f"poly must be finite numbers of shape (2, n, n), got shape {arr.shape}")
            object.__setattr__(self, "poly", freeze_array(arr))

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


def _explicit_bits(bits, shape: tuple[int, int], slm_shape, k: int, margin: int) -> np.ndarray:
    """uint8 0/1 bits (a new array) from an explicit pattern of 0/1 bits or +1/-1 values.

    uint8 and bool arrays are bits (1 = phase pi); signed-integer and float arrays are
    the model ``M = 1 - 2 bits`` (+1/-1).
    """
    a = np.asarray(bits)
    if a.dtype.kind not in "biuf":
        raise ReconInputError(f"bits must be a numeric array (uint8/bool 0/1 or +1/-1), got "
                              f"dtype {a.dtype}")
    if a.shape != shape:
        r, c = slm_shape
        raise ReconInputError(
            f"bits has shape {a.shape}, the mask model needs {shape} = (R k + 2 margin, "
            f"C k + 2 margin) for slm_shape ({r}, {c}), k {k}, margin {margin}; pass the "
            "pattern of that size (crop or pad it) or set slm_shape, k and margin to match it")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise ReconInputError("bits contains NaN or inf; pass a finite 0/1 or +1/-1 pattern")
    if a.dtype.kind == "b" or a.dtype == np.uint8:
        bad = (a != 0) & (a != 1)
        expected = "0/1 bits (1 = phase pi) for uint8/bool"
        fix = ("threshold the pattern to 0/1 (e.g. (pattern > 0).astype(np.uint8)) or pass "
               "+1/-1 values as a float array")
        out = a.astype(np.uint8)
    else:
        bad = (a != 1) & (a != -1)
        expected = f"+1/-1 (M = 1 - 2 bits) for dtype {a.dtype}"
        fix = "pass 0/1 bits as uint8 (bits.astype(np.uint8))"
        out = (a == -1).astype(np.uint8)
    if np.any(bad):
        found = np.unique(a[bad])[:5].tolist()
        raise ReconInputError(f"bits must be {expected}; found other values, e.g. {found}: "
                              f"{fix}")
    return out


def freeze_array(arr: np.ndarray) -> tuple:
    """Nested tuples (hashable) of a float array."""
    if arr.ndim == 1:
        return tuple(float(v) for v in arr)
    return tuple(freeze_array(a) for a in arr)


# --------------------------------------------------------------------------- mask


class MaskModel:
    """Random binary-phase mask: the software's model ``M`` and the true mask.

    The model mask is an array of bits (phase 0 or pi, i.e. ``M = +1 / -1``,
    Sec. 7.3) covering the SLM footprint (``R k x C k`` mask pixels) plus ``margin``
    mask pixels on every side: seeded random bits by default, or an explicit pattern
    (``bits=``), e.g. the fabricated mask's pattern file on a real bench, or a
    corrected (stitched) mask from an alignment record. The true mask is the model
    after the ground-truth transform (:class:`MaskTransform`) and the stage pose,
    with optional fabrication errors: phase depth ``pi (1 + phase_error)`` and a
    fraction of defective (flipped) pixels. It is rendered on the fine grid by nearest-neighbour
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
        Seed of the mask pattern (and, through a separate stream, the defects). With
        explicit ``bits`` it seeds the defects only.
    margin : int
        Extra mask pixels on each side of the SLM footprint (>= 0).
    bits : numpy.ndarray, optional
        Explicit model pattern (keyword only) of shape
        ``(R k + 2 margin, C k + 2 margin)``, finite, either uint8 / bool bits 0/1
        (1 = phase pi) or a signed-integer / float array of +1/-1 (the :attr:`model`
        convention ``M = 1 - 2 bits``). Copied; default None draws the bits from
        ``seed``. A real bench loads its fabricated mask's pattern this way
        (``MaskModel(..., bits=np.load("mask_pattern.npy"))``).
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
        uint8 (R k + 2 margin, C k + 2 margin), read-only: the model's bits
        (1 = phase pi), drawn from ``seed`` or given.
    true_bits : numpy.ndarray
        uint8, same shape: the bits of the physical mask (with defects).
    fine_shape : (int, int)
        ``(R k q, C k q)``.
    mask_pitch_um, fine_pitch_um : float
        ``slm_pitch_um / k`` and ``slm_pitch_um / (k q)``.
    version : int
        Incremented whenever :attr:`truth` changes (invalidates caches).

    Raises
    ------
    ReconInputError
        A parameter out of range, a fine grid above ``MAX_FINE_SAMPLES``, or ``bits``
        of the wrong shape, with values other than 0/1 (uint8/bool) or +1/-1 (other
        numbers), or not finite.
    """

    def __init__(self, slm_shape=(96, 120), slm_pitch_um: float = 16.0, k: int = 4,
                 q: int = 4, seed: int = 0, *, margin: int = 16,
                 truth: MaskTransform | None = None, phase_error: float = 0.0,
                 defect_fraction: float = 0.0, supersample: int = 1, bits=None):
        self.slm_shape = as_shape2(slm_shape, "slm_shape")
        self.slm_pitch_um = finite_float(slm_pitch_um, "slm_pitch_um", lo=0.0, lo_open=True)
        self.k = as_int(k, "k", 1)
        self.q = as_int(q, "q", 1)
        self.seed = as_int(seed, "seed", 0)
        self.margin = as_int(margin, "margin", 0)
        self.supersample = as_int(supersample, "supersample", 1)
        self.phase_error = finite_float(phase_error, "phase_error", lo=-1.0, hi=1.0)
        self.defect_fraction = finite_float(defect_fraction, "defect_fraction", lo=0.0, hi=1.0)
        r, c = self.slm_shape
        self.fine_shape = (r * self.k * self.q, c * self.k * self.q)
        if self.fine_shape[0] * self.fine_shape[1] > MAX_FINE_SAMPLES:
            raise ReconInputError(
                f"fine grid {self.fine_shape} exceeds {MAX_FINE_SAMPLES} samples; "
                "reduce slm_shape, k or q")
        self.mask_pitch_um = self.slm_pitch_um / self.k
        self.fine_pitch_um = self.mask_pitch_um / self.q
        shape = (r * self.k + 2 * self.margin, c * self.k + 2 * self.margin)
        if bits is None:
            self.bits = np.random.default_rng(self.seed).integers(0, 2, shape, dtype=np.uint8)
        else:
            self.bits = _explicit_bits(bits, shape, self.slm_shape, self.k, self.margin)
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
        """The model mask ``M`` at mask resolution: float32 +1/-1, shape of ``bits``."""
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
        render_mask_kernel(bits, self.margin, float(self.q), self.supersample, hx, hy,
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
            complex64, ``fine_shape``, read-only (cached): ``1`` for phase-0
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
            complex64 +1/-1, ``fine_shape``, read-only (cached); +1 beyond the
            modelled mask.
        """
        s = as_vec2(shift, "shift")
        key = ("model", s)
        tr = MaskTransform(translation=s)
        return self._cached(key, lambda: self._render(self.bits, tr, 1.0, -1.0, 1.0))


# --------------------------------------------------------------------------- block sums
