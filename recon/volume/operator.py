"""The 3D DiffuserCam forward model b = C sum_z h_z * v_z (Kuo 2020, Eq. 4.4).

One sensor image is the cropped sum over depth planes of 2D convolutions of each
plane of the volume with that depth's on-axis PSF. The operator follows the 2D
:class:`recon.operators.ConvolutionOperator` conventions (padded grid, centred PSF,
crop to the sensor, optional sensor weights, float32 / complex64 real FFTs) and
adds helpers for PSF-stack scaling, lateral binning, memory estimates and the FFT
floor of the 3D solvers.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from .. import _kernels
from ..errors import ReconInputError
from ..fft import WORKERS, fast_padded_shape, irfftn, rfftn, time_ffts
from ..operators import (
    ConvolutionOperator,
    LinearOperator,
    SensorWeighted,
    checked_sensor_weights,
    padded_grid,
    real32,
)
from ..preprocess import box_bin
from . import _kernels3d

#: Default size of one chunk of plane spectra (bytes): bounds the FFT temporaries.
CHUNK_BYTES = 64 * 2**20


class VolumeConvolutionOperator(SensorWeighted, LinearOperator):
    r"""Cropped sum over depth of 2D convolutions (Kuo 2020, Eq. 4.4; App. A.3).

    ``A v = diag(w) C F^-1 [ sum_z H_z . F v_z ]`` with ``H_z = F P h_z`` the real FFT
    of the zero-padded, centred PSF of plane ``z``. The volume ``v`` has shape
    ``(n_z, P0, P1)`` on the padded lateral grid (at least twice the sensor per
    axis, fast real-FFT lengths); the output is the ``(rows, cols)`` sensor image.
    The adjoint gives every plane the correlation of the zero-padded (weighted)
    sensor image with its PSF: ``(A^T y)_z = F^-1 [conj(H_z) . F P (w y)]``. A point at
    the lateral centre of plane ``z`` images to ``h_z`` as measured. Sensor weights
    ``w`` are the erasure mask of Eq. 3.10 (ones by default). Depths are metadata:
    the planes may sit on any grid (e.g. uniform in 1/z, Eq. 4.7); the model only
    sums over them.

    Cost (real 2D FFTs at the padded shape ``(P0, P1)``):

    * ``forward``: ``n_z`` rfft2 (one batched call per chunk of planes) + 1 irfft2
      of the summed spectrum;
    * ``adjoint``: 1 rfft2 of the padded residual + ``n_z`` irfft2;
    * ``data_term`` (one FISTA iteration): ``2 n_z + 2`` transforms, i.e.
      ``n_z + 1`` rfft2/irfft2 pairs. ``ffts_per_apply = n_z + 1``.

    Scaling: the operator uses the stack as given. With a non-negative stack scaled
    by :func:`normalize_psf_stack` (``sum_z (sum h_z)^2 = 1``) every frequency has
    ``sum_z |H_z(f)|^2 <= 1``, so the Lipschitz constant is at most ``max(w)^2``
    (the 3D analogue of the 2D unit-sum PSF, :func:`recon.api.scaled_problem`).

    Memory (float32 volumes, complex64 half-spectra), for a 512 x 512 sensor and
    64 planes (padded 1024 x 1024 x 64): the PSF spectra 64 x 1024 x 513 x 8 B =
    257 MiB; the PSF stack 64 MiB; chunk buffers of at most :data:`CHUNK_BYTES`
    for the plane spectra (3 x 64 MiB in flight, FFT outputs included) and a few
    4 MiB planes: about 0.5 GiB for the operator. One volume is 256 MiB; FISTA
    holds x, y, y_next, grad and one snapshot (5 volumes, 1.25 GiB): about 1.8 GiB
    in all, under the 4 GB budget (see :func:`estimate_memory_bytes`). Measured
    (tracemalloc, 3 iterations of :func:`~recon.volume.fista3d` with TV): peak 1.65 GiB
    of arrays, 2.0 GiB maximum resident set with the interpreter and numba; one
    iteration took 1.87 s against an FFT floor (:func:`fft_floor_seconds`) of 1.44 s
    on the shared 2-core machine (ratio 1.3).

    Parameters
    ----------
    psf_stack : ndarray, shape (n_z, rows, cols)
        On-axis PSF per depth plane at sensor size; converted to float32; finite,
        no all-zero plane.
    padded_shape : tuple of int, optional
        Lateral object-domain shape ``(P0, P1)``; default
        :func:`recon.fft.fast_padded_shape` of the sensor (>= 2x per axis).
    sensor_weights : ndarray, shape (rows, cols), optional
        Diagonal sensor weights (finite, non-negative).
    depths : array_like, shape (n_z,), optional
        Depth of each plane (any unit, strictly monotonic); metadata only.
    chunk_bytes : int
        Size bound of the chunked plane-spectrum buffers.

    Attributes
    ----------
    shape_in : (n_z, P0, P1)
    shape_out : (rows, cols)
    spectra : ndarray, complex64, shape (n_z, P0, P1 // 2 + 1)
    crop : tuple of slice
        Where the sensor sits in the padded lateral grid.
    planes_per_chunk : int

    Raises
    ------
    ReconInputError
        Stack not 3D, non-finite, an all-zero plane, bad weights, padded shape
        below twice the sensor, or depths not matching the planes.
    """

    def __init__(self, psf_stack: np.ndarray, *, padded_shape: tuple[int, int] | None = None,
                 sensor_weights: np.ndarray | None = None, depths=None,
                 chunk_bytes: int = CHUNK_BYTES, _spectra=None):
        h = real32(psf_stack, "PSF stack", contiguous=True)
        if h.ndim != 3 or h.shape[0] < 1 or min(h.shape[1:]) < 2:
            raise ReconInputError(
                f"PSF stack must be 3D (n_z, rows, cols) with at least 2 pixels per lateral "
                f"axis, got shape {h.shape}; stack the per-depth PSFs along axis 0"
            )
        if not np.all(np.isfinite(h)):
            raise ReconInputError("PSF stack contains NaN or inf; fix the calibration frames")
        empty = [k for k in range(h.shape[0]) if not np.any(h[k])]
        if empty:
            raise ReconInputError(
                f"PSF planes {empty} are all zero; recapture them or drop those depths"
            )
        self.n_z = h.shape[0]
        self.sensor_shape = h.shape[1:]
        self.padded_shape, self.offset, self.crop = padded_grid(self.sensor_shape, padded_shape)
        self.depths = _check_depths(depths, self.n_z)
        self.shape_in = (self.n_z, *self.padded_shape)
        self.shape_out = self.sensor_shape
        self.ffts_per_apply = self.n_z + 1
        self.psf_stack = h
        self.spectrum_shape = (self.padded_shape[0], self.padded_shape[1] // 2 + 1)
        plane_bytes = 8 * self.spectrum_shape[0] * self.spectrum_shape[1]
        self.planes_per_chunk = int(max(1, min(self.n_z, chunk_bytes // plane_bytes)))
        self._chunks = [slice(k, min(k + self.planes_per_chunk, self.n_z))
                        for k in range(0, self.n_z, self.planes_per_chunk)]
        self.spectra = self._psf_spectra() if _spectra is None else _spectra
        self.sensor_weights = checked_sensor_weights(sensor_weights, self.sensor_shape)
        self._pad_buf = np.zeros(self.padded_shape, np.float32)
        self._sum_spec = np.empty(self.spectrum_shape, np.complex64)
        self._plane_spec = np.empty((self.planes_per_chunk, *self.spectrum_shape), np.complex64)
        self._zero_b = np.zeros(self.sensor_shape, np.float32)

    def _psf_spectra(self) -> np.ndarray:
        spectra = np.empty((self.n_z, *self.spectrum_shape), np.complex64)
        for c in self._chunks:
            spectra[c] = plane_spectra(self.psf_stack[c], self.padded_shape, self.crop)
        return spectra

    # -- composition (PixelErasure @ op: see SensorWeighted) ------------------------
    def with_weights(self, sensor_weights: np.ndarray) -> VolumeConvolutionOperator:
        """A copy with other sensor weights, sharing the PSF spectra."""
        return VolumeConvolutionOperator(self.psf_stack, padded_shape=self.padded_shape,
                                         sensor_weights=sensor_weights, depths=self.depths,
                                         _spectra=self.spectra)

    def plane_operator(self, k: int) -> ConvolutionOperator:
        """The 2D :class:`~recon.operators.ConvolutionOperator` of plane ``k`` alone
        (same padded grid and weights, sharing its spectrum)."""
        return ConvolutionOperator(self.psf_stack[k], self.sensor_weights, self.padded_shape,
                                   _spectrum=self.spectra[k])

    # -- application -----------------------------------------------------------------
    def sum_spectrum(self, x: np.ndarray) -> np.ndarray:
        """``sum_z H_z F x_z`` (n_z rfft2, chunked) into the operator's buffer."""
        for c in self._chunks:
            _kernels3d.accumulate_products(self._sum_spec, rfftn(x[c]), self.spectra[c],
                                           c.start == 0)
        return self._sum_spec

    def backproject(self, spec: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out_z = F^-1 conj(H_z) spec`` for every plane (n_z irfft2, chunked)."""
        for c in self._chunks:
            g = self._plane_spec[:c.stop - c.start]
            _kernels3d.conj_products(g, spec, self.spectra[c])
            out[c] = sfft.irfftn(g, s=self.padded_shape, axes=(-2, -1), workers=WORKERS,
                                 overwrite_x=True)
        return out

    def convolve_full(self, x: np.ndarray) -> np.ndarray:
        """``M x``: the sum over depth of the planes' circular convolutions on the padded
        grid, before the crop (float32, ``padded_shape``; n_z rfft2 + 1 irfft2)."""
        return irfftn(self.sum_spectrum(np.asarray(x, np.float32)), self.padded_shape)

    def forward(self, x):
        x = self._check(x, self.shape_in, "volume")
        return (self.sensor_weights * self.convolve_full(x)[self.crop]).astype(np.float32)

    def adjoint(self, y):
        y = self._check(y, self.shape_out, "sensor image")
        buf = self._pad_buf
        np.multiply(self.sensor_weights, y, out=buf[self.crop])
        return self.backproject(rfftn(buf), np.empty(self.shape_in, np.float32))

    def data_term(self, x, b, out: np.ndarray | None = None):
        """Fused loss 1/2 ||A x - b||^2 and gradient A^T (A x - b): 2 n_z + 2 FFTs.

        Parameters
        ----------
        x : ndarray, shape ``shape_in``, float32
        b : ndarray, shape ``shape_out``, float32
            The (pre-weighted) measurement.
        out : ndarray, shape ``shape_in``, float32, C-contiguous, optional
            Where to write the gradient (a solver's reused buffer); new if omitted.

        Returns
        -------
        loss : float
        grad : ndarray, shape ``shape_in``, float32 (``out`` if given)
        """
        x = self._check(x, self.shape_in, "volume")
        b = self._check(b, self.shape_out, "measurement")
        if out is None:
            out = np.empty(self.shape_in, np.float32)
        elif out.shape != self.shape_in or out.dtype != np.float32:
            raise ReconInputError(f"gradient buffer must be float32 of shape {self.shape_in}")
        full = irfftn(self.sum_spectrum(x), self.padded_shape)
        loss = _kernels.crop_residual(full, np.ascontiguousarray(b), self.sensor_weights,
                                      *self.offset)
        self.backproject(rfftn(full), out)
        return 0.5 * loss, out

    def normal(self, x):
        """A^T A x (2 n_z + 2 FFTs, via the fused data term with b = 0)."""
        return self.data_term(x, self._zero_b)[1]

    def lipschitz_bound(self) -> float:
        """Upper bound of the Lipschitz constant: ``max(w)^2 max_f sum_z |H_z(f)|^2``.

        Exact for the uncropped circular model; the crop only lowers the top
        eigenvalue of A^T A, so 1 / bound is always a safe step (often ~2x smaller
        than the power-iteration :meth:`lipschitz`). No FFTs.
        """
        power = np.zeros(self.spectrum_shape, np.float64)
        for k in range(self.n_z):
            power += np.abs(self.spectra[k].astype(np.complex128)) ** 2
        return float(power.max()) * float(self.sensor_weights.max()) ** 2

    def memory_bytes(self) -> int:
        """Bytes held by this operator (spectra, PSF stack, weights, buffers)."""
        held = (self.spectra, self.psf_stack, self.sensor_weights, self._pad_buf,
                self._sum_spec, self._plane_spec, self._zero_b)
        return int(sum(a.nbytes for a in held))

    def _check(self, a, shape, what):
        a = real32(a, what)
        if a.shape != tuple(shape):
            raise ReconInputError(
                f"{what} has shape {a.shape}, the volume operator expects {tuple(shape)} "
                "(volume: n_z planes on the padded grid; sensor image: the PSF size)"
            )
        return a


def plane_spectra(planes: np.ndarray, padded_shape: tuple[int, int],
                  crop: tuple[slice, slice]) -> np.ndarray:
    """``H_z = F P h_z``: real FFTs of PSF planes zero-padded and centred (Eq. 4.4).

    The one place the model's PSF spectra are made: :class:`VolumeConvolutionOperator`
    and the plane slabs of the streamed solver (:mod:`recon.volume.slab`) call it.

    Parameters
    ----------
    planes : ndarray, float32, shape (k, rows, cols)
        PSF planes at sensor size (already scaled).
    padded_shape : (P0, P1)
    crop : (slice, slice)
        Where the sensor sits in the padded grid (:func:`recon.operators.padded_grid`).

    Returns
    -------
    ndarray, complex64, shape (k, P0, P1 // 2 + 1)
    """
    padded = np.zeros((planes.shape[0], *padded_shape), np.float32)
    padded[(slice(None), *crop)] = planes
    return rfftn(np.fft.ifftshift(padded, axes=(-2, -1)))


def _check_depths(depths, n_z: int) -> np.ndarray | None:
    if depths is None:
        return None
    d = np.asarray(depths, dtype=np.float64)
    if d.shape != (n_z,) or not np.all(np.isfinite(d)):
        raise ReconInputError(
            f"depths must be {n_z} finite values (one per PSF plane), got shape {d.shape}"
        )
    steps = np.diff(d)
    if n_z > 1 and not (np.all(steps > 0) or np.all(steps < 0)):
        raise ReconInputError("depths must be strictly monotonic; sort the PSF stack by depth")
    return d


def normalize_psf_stack(psf_stack: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale a PSF stack so that ``sum_z (sum_pixels h_z)^2 = 1``.

    The relative brightness of the planes (the physics: fall-off with depth) is
    kept. For a non-negative stack ``|H_z(f)| <= H_z(0) = sum h_z``, so afterwards
    ``sum_z |H_z(f)|^2 <= 1`` at every frequency and the Lipschitz constant of the
    unweighted data term is at most 1. Divide the reconstructed volume by ``scale``
    to express it in the units of the unnormalised stack.

    Parameters
    ----------
    psf_stack : ndarray, shape (n_z, rows, cols)

    Returns
    -------
    stack : ndarray, float32, same shape
    scale : float
        The divisor, ``sqrt(sum_z (sum h_z)^2)``.

    Raises
    ------
    ReconInputError
        If the stack is not 3D or its plane sums are all zero or not finite.
    """
    h = np.asarray(psf_stack, dtype=np.float32)
    if h.ndim != 3:
        raise ReconInputError(f"PSF stack must be 3D (n_z, rows, cols), got shape {h.shape}")
    sums = h.sum(axis=(1, 2), dtype=np.float64)
    scale = float(np.sqrt(np.sum(sums**2)))
    if not scale > 0 or not np.isfinite(scale):
        raise ReconInputError(
            "PSF stack has zero or non-finite total power; check the dark subtraction"
        )
    return (h / scale).astype(np.float32), scale


def bin_stack(psf_stack: np.ndarray, factor: int) -> np.ndarray:
    """Lateral box binning of every plane with :func:`recon.preprocess.box_bin`.

    Bin the measurement with ``box_bin(b, factor)`` so both stay on one grid.

    Parameters
    ----------
    psf_stack : ndarray, shape (n_z, rows, cols)
    factor : int
        Block size (see :func:`recon.preprocess.box_bin`).

    Returns
    -------
    ndarray, float32, shape (n_z, rows // factor, cols // factor)
    """
    h = np.asarray(psf_stack)
    if h.ndim != 3:
        raise ReconInputError(f"PSF stack must be 3D (n_z, rows, cols), got shape {h.shape}")
    return np.ascontiguousarray(np.moveaxis(box_bin(np.moveaxis(h, 0, -1), factor), -1, 0))


def estimate_memory_bytes(sensor_shape: tuple[int, int], n_z: int, *, volumes: int = 5,
                          chunk_bytes: int = CHUNK_BYTES) -> dict[str, int]:
    """Estimated peak bytes of a 3D solve without building it.

    Parameters
    ----------
    sensor_shape : (rows, cols)
    n_z : int
    volumes : int
        Float32 volumes the solver keeps (FISTA: x, y, y_next, grad, snapshot = 5).
    chunk_bytes : int

    Returns
    -------
    dict
        ``psf_spectra``, ``psf_stack``, ``chunk_buffers`` (three chunks: the
        rfft2 output, the conj-product buffer, the irfft2 output),
        ``plane_buffers``, ``volumes`` and ``total``, in bytes. For (512, 512) and 64
        planes: total ~1.9e9 B (1.8 GiB).
    """
    p0, p1 = fast_padded_shape(sensor_shape)
    spec_plane = 8 * p0 * (p1 // 2 + 1)
    per_chunk = max(1, min(n_z, chunk_bytes // spec_plane))
    est = {
        "psf_spectra": n_z * spec_plane,
        "psf_stack": 4 * n_z * sensor_shape[0] * sensor_shape[1],
        "chunk_buffers": per_chunk * (2 * spec_plane + 4 * p0 * p1),
        "plane_buffers": 4 * spec_plane + 2 * 4 * p0 * p1,
        "volumes": volumes * 4 * n_z * p0 * p1,
    }
    est["total"] = sum(est.values())
    return est


def fft_floor_seconds(shape: tuple[int, int], n_z: int, repeats: int = 5) -> float:
    """Median wall time of the FFT work one 3D data-term evaluation cannot avoid.

    That is ``n_z + 1`` rfft2 and ``n_z + 1`` irfft2 at the padded ``shape``
    (float32 / complex64): a batched rfft2 of the ``n_z`` planes, one irfft2 of the
    summed spectrum, one rfft2 of the residual and a batched irfft2 back to ``n_z``
    planes. A solver's seconds per iteration divided by this is its overhead ratio.
    Timed by :func:`recon.fft.time_ffts` (real pairs, stacks ``(n_z, 1)``).

    Parameters
    ----------
    shape : (P0, P1)
        Padded lateral shape.
    n_z : int
        Number of planes.
    repeats : int
        Timed repetitions (after one warm-up); the median is returned.

    Returns
    -------
    float
        Seconds.
    """
    if n_z < 1 or len(shape) != 2:
        raise ReconInputError("fft_floor_seconds needs a 2D padded shape and n_z >= 1")
    return time_ffts(tuple(shape), stacks=(n_z, 1), repeats=repeats, warmup=1)
