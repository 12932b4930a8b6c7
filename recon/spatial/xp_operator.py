"""The spatially varying forward models (Eq. 5.5) on any array-API backend.

:class:`XpSpatialConvolution` is :class:`recon.spatial.SpatialConvolutionOperator`
(the local convolution model, Eq. 5.3-5.5, and the low-rank PCA model, Eq. 5.6-5.7;
2D and 3D) with its kernel spectra and weight maps moved to the device of a given
array:

    A y = diag(w) C sum_j F^-1 diag(F P k_j) F diag(W_j) y_{z_j},

``forward`` ``K`` rfft2 + 1 irfft2, ``adjoint`` 1 rfft2 + ``K`` irfft2, the kernels
transformed in batches (one batched call per batch of kernels of one plane). The
NumPy operator stays the one source of validation, of the spectra and of the weight
maps (computed once on the host, so both paths use the same float32 / complex64
numbers). :func:`device_operator` makes the generic operator of any model the grid
solvers take; :func:`device_memory_bytes` is what a solve needs
on the device, checked before it starts (:func:`recon.backend.check_memory`).
"""

from __future__ import annotations

import numpy as np

from ..backend import total
from ..errors import ReconInputError
from ..operators import ConvolutionOperator
from ..volume.operator import VolumeConvolutionOperator
from ..xp_operators import XpConvolution, XpVolumeConvolution, _XpCropped
from .operator import SpatialConvolutionOperator

__all__ = ["DEVICE_BATCH_BYTES", "DEVICE_WEIGHT_CACHE_BYTES", "XpSpatialConvolution",
           "device_memory_bytes", "device_operator"]

#: Temporaries of one batch of kernels on the device (the batched FFT's input, output
#: and product) are kept under this many bytes.
DEVICE_BATCH_BYTES = 512 * 2**20
#: The weight maps ``W_j`` are kept on the device when they take at most this many
#: bytes; else each batch's maps are made from their separable factors when used.
DEVICE_WEIGHT_CACHE_BYTES = 1024 * 2**20


def _per_kernel_batch_bytes(padded_shape) -> int:
    """Bytes of one kernel in a batch: the weighted plane and its irfft2 output
    (float32), the rfft2 output, the conjugate spectrum and a product (complex64)."""
    p0, p1 = padded_shape
    return 2 * 4 * p0 * p1 + 3 * 8 * p0 * (p1 // 2 + 1)


class XpSpatialConvolution(_XpCropped):
    """:class:`~recon.spatial.SpatialConvolutionOperator` on the backend of ``like``.

    Parameters
    ----------
    op : SpatialConvolutionOperator
        The NumPy operator (kernels' spectra, weight maps, support, sensor weights).
    like : array
        Any array of the target backend and device.
    batch_bytes : int
        Temporaries of one batched FFT stay under this (at least one kernel a batch).
    cache_bytes : int
        Weight maps above this are made per batch from their factors
        (``W_j = wy^T (c_j wx)``, :meth:`SpatialConvolutionOperator.tents`) instead
        of kept.

    Attributes
    ----------
    spectra : array, complex64, (K, P0, P1 // 2 + 1)
    weights : array, float32, (K, P0, P1), or None
        The kept weight maps (support folded in), or None (made per batch).
    batches : list of (plane, start, stop)
        Kernels ``start:stop`` all act on ``plane``.
    n_kernels, ffts_per_apply : int
        As the NumPy operator's.
    """

    def __init__(self, op: SpatialConvolutionOperator, like, *,
                 batch_bytes: int = DEVICE_BATCH_BYTES,
                 cache_bytes: int = DEVICE_WEIGHT_CACHE_BYTES):
        if not isinstance(op, SpatialConvolutionOperator):
            raise ReconInputError(f"XpSpatialConvolution needs a SpatialConvolutionOperator, "
                                  f"got {type(op).__name__}")
        super().__init__(op, like)
        self.volume, self.n_z = op.volume, op.n_z
        self.n_kernels, self.ffts_per_apply = op.n_kernels, op.ffts_per_apply
        self.spectra = self.asarray(op.spectra)
        plane_bytes = 4 * op.padded_shape[0] * op.padded_shape[1]
        self.weights = None
        if op.n_kernels * plane_bytes <= cache_bytes:
            self.weights = self.asarray(np.stack([op._weight_map(j)
                                                  for j in range(op.n_kernels)]))
        else:  # factors: W_j = wy_z^T (c_j wx_z), (P0, ny) times (ny, P1)
            self._wy_t = [self.asarray(np.ascontiguousarray(wy.T)) for wy, _ in op.tents]
            self._v = [self.asarray(c @ op.tents[z][1])
                       for c, z in zip(op.coefficients, op.planes, strict=True)]
            self._support = (None if op.support is None else
                             [self.asarray(s.astype(np.float32)) for s in op.support])
        per = max(1, int(batch_bytes) // _per_kernel_batch_bytes(op.padded_shape))
        self.batches = _batches(op.planes, per)

    def _weights_of(self, plane: int, start: int, stop: int):
        """``W_j`` for kernels ``start:stop`` (of ``plane``), (k, P0, P1)."""
        if self.weights is not None:
            return self.weights[start:stop, ...]
        xp = self.xp
        w = xp.matmul(self._wy_t[plane], xp.stack(self._v[start:stop]))
        return w if self._support is None else w * self._support[plane]

    def _planes(self, x):
        return x if self.volume else x[None, ...]

    def sum_spectrum(self, x):
        """``sum_j F P k_j F W_j x_{z_j}``, (P0, P1 // 2 + 1) complex64 (``K`` rfft2)."""
        xp = self.xp
        xv = self._planes(x)
        acc = None
        for plane, start, stop in self.batches:
            spec = xp.fft.rfftn(xv[plane, ...] * self._weights_of(plane, start, stop),
                                axes=(-2, -1))
            part = xp.sum(spec * self.spectra[start:stop, ...], axis=0)
            acc = part if acc is None else acc + part
        return acc

    def backproject(self, spec):
        """``sum_j W_j F^-1 conj(F P k_j) spec`` per plane: the adjoint of
        :meth:`sum_spectrum` followed by the inverse transform (``K`` irfft2)."""
        xp = self.xp
        planes = [None] * self.n_z
        for plane, start, stop in self.batches:
            g = xp.fft.irfftn(xp.conj(self.spectra[start:stop, ...]) * spec[None, ...],
                              s=self.padded_shape, axes=(-2, -1))
            part = xp.sum(g * self._weights_of(plane, start, stop), axis=0)
            planes[plane] = part if planes[plane] is None else planes[plane] + part
        zero = xp.zeros(self.padded_shape, dtype=xp.float32, device=self.device)
        planes = [zero if p is None else p for p in planes]
        return xp.stack(planes) if self.volume else planes[0]

    def convolve_full(self, x):
        """``M x`` on the padded grid (before crop and sensor weights); ``x``
        ``shape_in`` float32 -> (P0, P1)."""
        x = self._check(x, self.shape_in, "object")
        return self.xp.fft.irfftn(self.sum_spectrum(x), s=self.padded_shape, axes=(-2, -1))

    def correlate_full(self, v):
        """``M^T v``, the adjoint of :meth:`convolve_full`; ``v`` (P0, P1) ->
        ``shape_in``."""
        v = self._check(v, self.padded_shape, "padded sensor image")
        return self.backproject(self.xp.fft.rfftn(v, axes=(-2, -1)))

    def forward(self, x):
        """A x = diag(w) C M x; ``x`` ``shape_in`` float32 -> (rows, cols)."""
        return self.sensor_weights * self.convolve_full(x)[self.crop]

    def adjoint(self, y):
        """A^T y = M^T C^T diag(w) y; ``y`` (rows, cols) -> ``shape_in``."""
        y = self._check(y, self.shape_out, "sensor image")
        return self.correlate_full(self.pad(self.sensor_weights * y))

    def data_term(self, x, b):
        """Loss 1/2 ||A x - b||^2 and gradient A^T (A x - b) (``K + 1`` FFT pairs)."""
        r = self.wp * self.convolve_full(x) - self.pad(b)
        return 0.5 * total(self.xp, r * r), self.correlate_full(self.wp * r)


def _batches(planes, per: int) -> list[tuple[int, int, int]]:
    """Runs of consecutive kernels of one plane, cut into pieces of at most ``per``."""
    out, start = [], 0
    planes = [int(p) for p in planes]
    for j in range(1, len(planes) + 1):
        if j == len(planes) or planes[j] != planes[start] or j - start == per:
            out.append((planes[start], start, j))
            start = j
    return out


def device_operator(op, like):
    """The generic operator of ``op`` on ``like``'s backend and device.

    Made per solve, not kept on ``op`` (a :class:`recon.Reconstruction` holds its
    operator: a kept copy would hold GPU memory as long as the result lives); moving
    the spectra costs one host-to-device copy, small beside a solve's ``2K + 2``
    transforms per iteration.

    Parameters
    ----------
    op : SpatialConvolutionOperator, ConvolutionOperator or VolumeConvolutionOperator
    like : array (array API)

    Returns
    -------
    XpSpatialConvolution, XpConvolution or XpVolumeConvolution

    Raises
    ------
    ReconInputError
        Another kind of operator (pass NumPy arrays: the NumPy path takes any).
    """
    kinds = ((SpatialConvolutionOperator, XpSpatialConvolution),
             (VolumeConvolutionOperator, XpVolumeConvolution),
             (ConvolutionOperator, XpConvolution))
    make = next((xop for kind, xop in kinds if isinstance(op, kind)), None)
    if make is None:
        raise ReconInputError(f"{type(op).__name__} has no array-API form; pass NumPy arrays "
                              "(the CPU path) or use a convolution or PSF-grid model")
    return make(op, like)


def device_memory_bytes(op: SpatialConvolutionOperator, *, planes: int,
                        batch_bytes: int = DEVICE_BATCH_BYTES,
                        cache_bytes: int = DEVICE_WEIGHT_CACHE_BYTES) -> int:
    """Peak device memory of a solve with :class:`XpSpatialConvolution` (bytes).

    Parameters
    ----------
    op : SpatialConvolutionOperator
    planes : int
        Object-sized float32 arrays the solver holds at once (its iterates, duals and
        temporaries; a 3D object counts ``n_z`` planes each).
    batch_bytes, cache_bytes : int
        As :class:`XpSpatialConvolution`.

    Returns
    -------
    int
        Kernel spectra, weight maps when kept, one batch's FFT temporaries and
        ``planes`` padded planes.
    """
    p0, p1 = op.padded_shape
    plane = 4 * p0 * p1
    spectra = op.spectra.nbytes
    maps = op.n_kernels * plane
    weights = maps if maps <= cache_bytes else 0
    per = _per_kernel_batch_bytes(op.padded_shape)
    batch = per * min(op.n_kernels, max(1, int(batch_bytes) // per))
    return int(spectra + weights + batch + planes * plane)
