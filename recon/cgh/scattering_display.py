"""The étendue-expanded display model: SLM -> box upsampling -> mask -> Fourier lens.

Kuo 2020, Eq. 7.8, 7.15 and 7.20-7.22 as a linear operator on the complex SLM field
``s`` (the intensity ``|y|^2`` is taken by the losses, not here).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from ..errors import ReconInputError
from ..fft import WORKERS
from ..validate import as_array, as_shape2, positive
from . import _kernels

__all__ = ["ScatteringDisplay", "field_from_phase", "random_binary_mask"]

#: Largest mask grid accepted (samples); 2**27 complex64 samples are 1 GiB.
MAX_GRID_SAMPLES = 2**27


def random_binary_mask(slm_shape, k: int, seed: int = 0, slm_pitch_um: float = 16.0) -> np.ndarray:
    """Random binary 0/pi phase mask ``m = +-1`` at mask-pixel resolution (Sec. 7.3).

    The bits are those of :class:`recon.optics.holo_display.MaskModel` (the virtual
    bench's mask) with no margin, so a hologram computed here and the bench's model
    mask agree pixel for pixel for the same seed.

    Parameters
    ----------
    slm_shape : (int, int)
        SLM pixels ``(N_y, N_x)``.
    k : int
        Mask pixels per SLM pixel along each axis (``q = k^2``, Eq. 7.10).
    seed : int
        Seed of the mask pattern (>= 0).
    slm_pitch_um : float
        SLM pitch (um); only recorded by the bench model.

    Returns
    -------
    numpy.ndarray
        float32 ``(N_y k, N_x k)`` of +1 (phase 0) and -1 (phase pi), read-only.
    """
    from ..optics.holo_display import MaskModel

    mm = MaskModel(as_shape2(slm_shape, "slm_shape"), slm_pitch_um, k=k, q=1, seed=seed, margin=0)
    out = mm.model
    out.setflags(write=False)
    return out


def field_from_phase(phase) -> np.ndarray:
    """Unit-modulus SLM field ``exp(i phase)`` at SLM resolution (complex64).

    Parameters
    ----------
    phase : array_like
        Real, radians, any shape.

    Returns
    -------
    numpy.ndarray
        complex64, same shape: ``cos(phase) + i sin(phase)`` computed in float32.
    """
    p = np.asarray(phase)
    if p.dtype.kind not in "fiu" or p.dtype == np.bool_:
        raise ReconInputError(f"phase must be real (radians), got dtype {p.dtype}")
    p = p.astype(np.float32, copy=False)
    if not np.all(np.isfinite(p)):
        raise ReconInputError("phase contains NaN or inf")
    out = np.empty(p.shape, np.complex64)
    out.real = np.cos(p)
    out.imag = np.sin(p)
    return out


class ScatteringDisplay:
    """Holographic display with a thin scattering mask, as a linear operator on ``s``.

    ``forward`` maps the complex SLM field ``s`` (``N_y x N_x``, pitch ``Delta``) to
    the complex field at each image plane (Eq. 7.8, 7.15, 7.22)::

        y_z = F_c{ m_z (U s) },   m_z(u) = m(u) h_z(u),
        h_z(u) = exp(i pi z |u|^2 / (lambda f^2))

    with ``U`` the box upsampling by ``k`` (each SLM pixel covers ``k x k`` mask
    pixels of pitch ``Delta_m = Delta / k``), ``m`` the mask transmission and ``F_c``
    the centred, unitary 2D DFT ``fftshift(fft2(ifftshift(.), norm="ortho"))``: the
    zero order sits at index ``(G_y // 2, G_x // 2)`` of the ``G_y x G_x = N_y k x N_x k``
    image grid, which spans the expanded field of view ``1 / Delta_m`` (Eq. 7.9).
    ``h_z`` is the Fresnel defocus of Eq. 7.21 written on the SLM plane (``u`` in
    physical units measured from the grid centre, ``f`` the Fourier lens' focal
    length, the constant ``exp(2 pi i z / lambda)`` dropped because intensities do
    not see it). ``adjoint`` is the exact adjoint ``U^T sum_z conj(m_z) F_c^H``.

    Because ``F_c`` is unitary, a unit-modulus ``s`` through a unit-modulus mask puts
    a mean intensity of exactly 1 on every plane.

    Parameters
    ----------
    slm_shape : (int, int)
        SLM pixels ``(N_y, N_x)``, e.g. ``(540, 960)``.
    k : int
        Mask pixels per SLM pixel along each axis (>= 1); étendue expansion
        ``q = k^2`` (Eq. 7.10): 2, 4, 6 for 4x, 16x, 36x.
    mask : numpy.ndarray or None or "clear", optional
        Mask transmission on the ``(N_y k, N_x k)`` grid (real or complex, finite).
        ``None`` (default) draws the random binary 0/pi mask of
        :func:`random_binary_mask` with ``mask_seed``; ``"clear"`` is no mask (ones).
    mask_seed : int
        Seed of the random mask (ignored when ``mask`` is given).
    slm_pitch_um : float
        SLM pixel pitch ``Delta`` as imaged on the mask (um).
    wavelength_nm : float
        Wavelength (nm); used by the Fresnel planes only.
    focal_length_mm : float
        Focal length ``f`` of the Fourier lens (mm); used by the Fresnel planes only.
    planes_mm : sequence of float
        Defocus ``z`` of each image plane from the lens' focal plane (mm, Eq. 7.20);
        default one plane at 0 (Eq. 7.8).

    Attributes
    ----------
    grid_shape : (int, int)
        ``(N_y k, N_x k)``.
    shape_in : (int, int)
        ``slm_shape``.
    shape_out : tuple of int
        ``grid_shape`` for one plane, ``(n_planes, *grid_shape)`` for several.
    dtype : numpy.dtype
        complex64 (input and output).
    ffts_per_apply : int
        FFTs per ``forward`` or ``adjoint``: one per plane.
    plane_masks : list of numpy.ndarray
        ``m_z`` per plane (float32 for a real mask at ``z = 0``, else complex64),
        read-only.
    mask_energy : numpy.ndarray
        float32 ``slm_shape``: ``U^T |m|^2`` (``k^2`` for a unit-modulus mask), so
        that ``sum |y_z|^2 = sum mask_energy |s|^2`` on every plane.

    Raises
    ------
    ReconInputError
        Bad shapes, a non-finite or wrongly sized mask, a grid above
        ``MAX_GRID_SAMPLES``, or non-positive physical parameters.
    """

    dtype = np.dtype(np.complex64)

    def __init__(self, slm_shape, k: int = 4, *, mask=None, mask_seed: int = 0,
                 slm_pitch_um: float = 16.0, wavelength_nm: float = 532.0,
                 focal_length_mm: float = 100.0, planes_mm=(0.0,)):
        self.slm_shape = as_shape2(slm_shape, "slm_shape")
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
            raise ReconInputError(f"k (mask pixels per SLM pixel) must be an integer >= 1, "
                                  f"got {k!r}")
        self.k = int(k)
        self.grid_shape = (self.slm_shape[0] * self.k, self.slm_shape[1] * self.k)
        if self.grid_shape[0] * self.grid_shape[1] > MAX_GRID_SAMPLES:
            raise ReconInputError(f"mask grid {self.grid_shape} exceeds {MAX_GRID_SAMPLES} "
                                  "samples; reduce the SLM size or k")
        self.slm_pitch_um = positive(slm_pitch_um, "slm_pitch_um")
        self.mask_pitch_um = self.slm_pitch_um / self.k
        self.wavelength_nm = positive(wavelength_nm, "wavelength_nm")
        self.focal_length_mm = positive(focal_length_mm, "focal_length_mm")
        z = np.atleast_1d(as_array(planes_mm, "planes_mm"))
        if z.dtype.kind not in "iuf" or z.ndim != 1:
            raise ReconInputError(f"planes_mm must be a sequence of numbers (mm), got "
                                  f"{planes_mm!r}")
        planes = [float(v) for v in z]
        if not planes or not all(math.isfinite(v) for v in planes):
            raise ReconInputError(
                f"planes_mm must be one or more finite numbers, got {planes_mm!r}")
        self.planes_mm = tuple(planes)
        self.mask = self._make_mask(mask, mask_seed)
        self.plane_masks = [self._plane_mask(z) for z in self.planes_mm]
        for m in self.plane_masks:
            m.setflags(write=False)
        e = np.abs(self.mask.astype(np.complex64)) ** 2
        self.mask_energy = e.reshape(self.slm_shape[0], self.k, self.slm_shape[1],
                                     self.k).sum(axis=(1, 3), dtype=np.float64).astype(np.float32)
        self.shape_in = self.slm_shape
        self.shape_out = (self.grid_shape if len(self.planes_mm) == 1
                          else (len(self.planes_mm), *self.grid_shape))
        self.ffts_per_apply = len(self.planes_mm)

    # -- construction ------------------------------------------------------------------

    @classmethod
    def no_mask(cls, slm_shape, **kwargs) -> ScatteringDisplay:
        """The native display without a mask (``k = 1``, clear): the reference étendue.

        Parameters
        ----------
        slm_shape : (int, int)
            SLM pixels.
        **kwargs
            Other :class:`ScatteringDisplay` parameters (pitch, planes, ...).

        Returns
        -------
        ScatteringDisplay
        """
        return cls(slm_shape, 1, mask="clear", **kwargs)

    def _make_mask(self, mask, seed) -> np.ndarray:
        if mask is None:
            return random_binary_mask(self.slm_shape, self.k, seed, self.slm_pitch_um)
        if isinstance(mask, str):
            if mask != "clear":
                raise ReconInputError(f"mask must be an array, None or 'clear', got {mask!r}")
            out = np.ones(self.grid_shape, np.float32)
            out.setflags(write=False)
            return out
        m = as_array(mask, "mask")
        if m.shape != self.grid_shape:
            raise ReconInputError(f"mask has shape {m.shape}; the display needs the mask grid "
                                  f"{self.grid_shape} = SLM shape x k")
        if m.dtype.kind == "c":
            m = m.astype(np.complex64)
        elif m.dtype.kind in "fiub":
            m = m.astype(np.float32)
        else:
            raise ReconInputError(f"mask must be numeric, got dtype {m.dtype}")
        if not np.all(np.isfinite(m)):
            raise ReconInputError("mask contains NaN or inf")
        m.setflags(write=False)
        return m

    def _plane_mask(self, z_mm: float) -> np.ndarray:
        if z_mm == 0.0:
            return np.ascontiguousarray(self.mask)
        gy, gx = self.grid_shape
        pitch_mm = self.mask_pitch_um * 1e-3
        uy = (np.arange(gy) - gy // 2) * pitch_mm
        ux = (np.arange(gx) - gx // 2) * pitch_mm
        a = math.pi * z_mm / (self.wavelength_nm * 1e-6 * self.focal_length_mm ** 2)
        hy = np.exp(1j * a * uy ** 2).astype(np.complex64)
        hx = np.exp(1j * a * ux ** 2).astype(np.complex64)
        return (self.mask * hy[:, None] * hx[None, :]).astype(np.complex64)

    # -- geometry ----------------------------------------------------------------------

    @property
    def n_planes(self) -> int:
        """Number of image planes."""
        return len(self.planes_mm)

    @property
    def expansion(self) -> int:
        """Étendue expansion factor ``q = k^2`` (Eq. 7.10)."""
        return self.k * self.k

    @property
    def native_window(self) -> tuple[slice, slice]:
        """Slices of the centred image grid covered by the native SLM (no mask).

        The orange box of Fig. 7.3: ``N_y x N_x`` samples around the zero order.
        """
        gy, gx = self.grid_shape
        ny, nx = self.slm_shape
        return (slice(gy // 2 - ny // 2, gy // 2 - ny // 2 + ny),
                slice(gx // 2 - nx // 2, gx // 2 - nx // 2 + nx))

    # -- operator ----------------------------------------------------------------------

    def check_slm(self, s) -> np.ndarray:
        """The SLM field ``s`` as a contiguous complex64 array, checked.

        Parameters
        ----------
        s : array_like, ``slm_shape``
            Real or complex SLM field.

        Returns
        -------
        ndarray, complex64, ``slm_shape``

        Raises
        ------
        ReconInputError
            Wrong shape, non-numeric dtype, or NaN/inf values.
        """
        a = as_array(s, "SLM field")
        if a.shape != self.slm_shape:
            raise ReconInputError(f"SLM field has shape {a.shape}, the display expects "
                                  f"{self.slm_shape} (rows, cols)")
        if a.dtype.kind not in "fciu" or a.dtype == np.bool_:
            raise ReconInputError(f"SLM field must be numeric, got dtype {a.dtype}")
        a = np.ascontiguousarray(a, dtype=np.complex64)
        if not np.all(np.isfinite(a)):
            raise ReconInputError("SLM field contains NaN or inf")
        return a

    def upsampled_field(self, s, plane: int = 0, out: np.ndarray | None = None) -> np.ndarray:
        """``m_z (U s)`` on the mask grid (Eq. 7.15 times the mask), complex64.

        Parameters
        ----------
        s : numpy.ndarray
            complex ``slm_shape``.
        plane : int
            Plane index.
        out : numpy.ndarray, optional
            complex64 ``grid_shape`` buffer to fill.

        Returns
        -------
        numpy.ndarray
            complex64 ``grid_shape``.
        """
        s = self.check_slm(s)
        if out is None:
            out = np.empty(self.grid_shape, np.complex64)
        _kernels.upsample_multiply(s, self.plane_masks[plane], self.k, out)
        return out

    def forward(self, s) -> np.ndarray:
        """Complex image-plane field(s) ``y_z = F_c{m_z U s}`` (Eq. 7.8 / 7.22).

        Parameters
        ----------
        s : numpy.ndarray
            Complex SLM field, ``slm_shape`` (a phase-only SLM has ``|s| = 1``; see
            :func:`field_from_phase`).

        Returns
        -------
        numpy.ndarray
            complex64 ``shape_out``, centred (zero order at ``grid // 2``).
        """
        s = self.check_slm(s)
        out = np.empty((self.n_planes, *self.grid_shape), np.complex64)
        for p in range(self.n_planes):
            x = self.upsampled_field(s, p, out=out[p])
            out[p] = sfft.fftshift(sfft.fft2(sfft.ifftshift(x), norm="ortho", workers=WORKERS))
        return out[0] if self.n_planes == 1 else out

    def adjoint(self, y) -> np.ndarray:
        """Adjoint ``U^T sum_z conj(m_z) F_c^H y_z`` (back-propagation, Eq. 7.11-7.12).

        Parameters
        ----------
        y : numpy.ndarray
            Complex image-plane field(s), ``shape_out``.

        Returns
        -------
        numpy.ndarray
            complex64 ``slm_shape``.
        """
        a = as_array(y, "image field")
        if a.shape != tuple(self.shape_out):
            raise ReconInputError(f"image field has shape {a.shape}, the display expects "
                                  f"{self.shape_out}")
        a = np.asarray(a, dtype=np.complex64).reshape(self.n_planes, *self.grid_shape)
        if not np.all(np.isfinite(a)):
            raise ReconInputError("image field contains NaN or inf")
        acc = np.zeros(self.slm_shape, np.complex64)
        tmp = np.empty(self.slm_shape, np.complex64)
        for p in range(self.n_planes):
            x = np.ascontiguousarray(sfft.fftshift(
                sfft.ifft2(sfft.ifftshift(a[p]), norm="ortho", workers=WORKERS)),
                dtype=np.complex64)
            _kernels.bin_conj_multiply(x, self.plane_masks[p], self.k, tmp)
            acc += tmp
        return acc

    def intensity(self, s) -> np.ndarray:
        """Displayed intensity ``|y_z|^2`` (float32, ``shape_out``), centred."""
        y = self.forward(s)
        return (y.real ** 2 + y.imag ** 2).astype(np.float32)


