"""SLM response, relay optics, far-field-to-camera mapping and laser drift.

Part of :mod:`recon.optics.holo_display` (see its docstring for the model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import ReconInputError
from ...validate import as_int, as_shape2, as_vec2, finite_float
from .basics import check_lut, gray_to_phase, phase_to_gray
from .mask import freeze_array


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
        object.__setattr__(self, "lut", tuple(check_lut(self.lut).tolist()))
        object.__setattr__(self, "fill_factor",
                           finite_float(self.fill_factor, "fill_factor", lo=0.0, hi=1.0,
                                        lo_open=True))
        object.__setattr__(self, "gap_amplitude",
                           finite_float(self.gap_amplitude, "gap_amplitude", lo=0.0, hi=1.0))
        object.__setattr__(self, "crosstalk_px",
                           finite_float(self.crosstalk_px, "crosstalk_px", lo=0.0, hi=2.0))

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
        ``0.25 / (pi lambda f^2)``, a quarter-radian phase at ``f``, the SLM pixel
        frequency ``1/Delta`` or the pupil's cut-off ``NA / lambda`` if lower.
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
                           finite_float(self.wavelength_um, "wavelength_um", lo=0.0,
                                        lo_open=True))
        if self.na is not None:
            object.__setattr__(self, "na", finite_float(self.na, "na", lo=0.0, hi=1.0,
                                                        lo_open=True))
        if self.level_step_um is not None:
            object.__setattr__(self, "level_step_um",
                               finite_float(self.level_step_um, "level_step_um", lo=0.0,
                                            lo_open=True))
        object.__setattr__(self, "max_levels", as_int(self.max_levels, "max_levels", 2))


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
        shape = as_shape2(self.shape, "camera shape")
        object.__setattr__(self, "shape", shape)
        try:
            m = np.asarray(self.matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise ReconInputError("camera matrix must be 2x2 finite numbers") from None
        if m.shape != (2, 2) or not np.all(np.isfinite(m)):
            raise ReconInputError(f"camera matrix must be 2x2 finite numbers, got {m.shape}")
        if abs(np.linalg.det(m)) < 1e-9:
            raise ReconInputError("camera matrix is singular")
        object.__setattr__(self, "matrix", freeze_array(m))
        off = (shape[1] // 2, shape[0] // 2) if self.offset is None else self.offset
        object.__setattr__(self, "offset", as_vec2(off, "camera offset"))

    @classmethod
    def from_params(cls, shape=(480, 640), scale: float = 1.0, rotation: float = 0.0,
                    offset=None, scale_y: float | None = None,
                    flip_x: bool = False) -> CameraMapping:
        """Affine from a scale (camera px per far-field sample), rotation (rad) and offset.

        ``M = R(rotation) diag(+-scale, scale_y)`` (``scale_y`` defaults to ``scale``;
        ``flip_x`` mirrors x).
        """
        sx = finite_float(scale, "scale", lo=0.0, lo_open=True)
        sy = sx if scale_y is None else finite_float(scale_y, "scale_y", lo=0.0, lo_open=True)
        th = finite_float(rotation, "rotation")
        c, s = math.cos(th), math.sin(th)
        m = np.array([[c, -s], [s, c]]) @ np.diag([-sx if flip_x else sx, sy])
        return cls(shape=shape, matrix=freeze_array(m), offset=offset)

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
        self.seed = as_int(seed, "seed", 0)
        self.sigma = finite_float(sigma_per_sqrt_s, "sigma_per_sqrt_s", lo=0.0)
        self.tau_s = None if tau_s is None else finite_float(tau_s, "tau_s", lo=0.0,
                                                              lo_open=True)
        self.factor0 = finite_float(factor0, "factor0", lo=0.0, lo_open=True)
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
        dt = finite_float(dt_s, "dt_s", lo=0.0)
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
