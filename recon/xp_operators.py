"""The 2D and 3D cropped-convolution forward models on any array-API backend.

:class:`XpConvolution` is :class:`recon.operators.ConvolutionOperator` (Kuo 2020,
Eq. 3.4, adjoint Eq. 3.8) and :class:`XpVolumeConvolution` is
:class:`recon.volume.VolumeConvolutionOperator` (Eq. 4.4) with their PSF spectra and
sensor weights moved to the device of a given array; the NumPy operator stays the
one source of validation and of the spectra (computed once on the host, so both
paths use the same complex64 numbers).
"""

from __future__ import annotations

import numpy as np

from .backend import array_namespace, device_of, total
from .errors import ReconInputError

__all__ = ["XpConvolution", "XpVolumeConvolution"]


class _XpCropped:
    """What the 2D and 3D generic operators share: the device copies of the crop's
    weights, padding and the shape checks."""

    def __init__(self, op, like):
        self.op = op
        self.xp = xp = array_namespace(like)
        self.device = dev = device_of(like)
        self.shape_in, self.shape_out = tuple(op.shape_in), tuple(op.shape_out)
        self.padded_shape, self.crop = tuple(op.padded_shape), op.crop
        self.sensor_weights = xp.asarray(np.ascontiguousarray(op.sensor_weights), device=dev)
        wp = np.zeros(op.padded_shape, np.float32)
        wp[op.crop] = op.sensor_weights
        self.wp = xp.asarray(wp, device=dev)

    def asarray(self, a):
        """A host array on this operator's device."""
        return self.xp.asarray(a, device=self.device)

    def pad(self, y):
        """Zero-pad a sensor-shaped array to the padded grid (the pad P = C^T)."""
        buf = self.xp.zeros(self.padded_shape, dtype=y.dtype, device=self.device)
        buf[self.crop] = y
        return buf

    def _check(self, a, shape, what):
        if tuple(a.shape) != tuple(shape):
            raise ReconInputError(f"{what} has shape {tuple(a.shape)}, operator expects "
                                  f"{tuple(shape)}")
        return a

    def lipschitz(self, power_iterations: int = 30, seed: int = 0) -> float:
        """:meth:`recon.operators.LinearOperator.lipschitz` on the device, from the
        same random start (drawn by NumPy)."""
        xp = self.xp
        rng = np.random.default_rng(seed)
        x0 = rng.standard_normal(self.shape_in).astype(np.float32)
        x = self.asarray(x0 / np.linalg.norm(x0))
        lam = 0.0
        for _ in range(power_iterations):
            y = self.normal(x)
            lam = total(xp, y * y) ** 0.5
            if lam == 0.0 or not np.isfinite(lam):
                break
            x = y / lam
        return 1.02 * lam

    def normal(self, x):
        """A^T A x."""
        return self.adjoint(self.forward(x))


class XpConvolution(_XpCropped):
    """:class:`recon.operators.ConvolutionOperator` on the backend of ``like``.

    Parameters
    ----------
    op : ConvolutionOperator
        The NumPy operator (PSF spectrum, sensor weights, grid).
    like : array
        Any array of the target backend and device.

    Attributes
    ----------
    spectrum, spectrum_conj : array, complex64, (P0, P1 // 2 + 1)
    wp : array, float32, (P0, P1)
        Sensor weights zero-padded to the object grid.
    """

    ffts_per_apply = 2

    def __init__(self, op, like):
        super().__init__(op, like)
        self.spectrum = self.asarray(op.spectrum)
        self.spectrum_conj = self.xp.conj(self.spectrum)

    def convolve_full(self, x):
        """M x: circular convolution on the padded grid (1 rfft2 + 1 irfft2)."""
        xp = self.xp
        return xp.fft.irfftn(xp.fft.rfftn(x, axes=(-2, -1)) * self.spectrum,
                             s=self.padded_shape, axes=(-2, -1))

    def correlate_full(self, y_padded):
        """M^T y on the padded grid (correlation with the PSF)."""
        xp = self.xp
        return xp.fft.irfftn(xp.fft.rfftn(y_padded, axes=(-2, -1)) * self.spectrum_conj,
                             s=self.padded_shape, axes=(-2, -1))

    def forward(self, x):
        """A x = diag(w) C M x; ``x`` (P0, P1) float32 -> (rows, cols)."""
        x = self._check(x, self.shape_in, "object")
        return self.sensor_weights * self.convolve_full(x)[self.crop]

    def adjoint(self, y):
        """A^T y = M^T C^T diag(w) y; ``y`` (rows, cols) -> (P0, P1)."""
        y = self._check(y, self.shape_out, "sensor image")
        return self.correlate_full(self.pad(self.sensor_weights * y))

    def data_term(self, x, b):
        """Loss 1/2 ||A x - b||^2 and gradient A^T (A x - b) (4 FFTs)."""
        r = self.wp * self.convolve_full(self._check(x, self.shape_in, "object")) - self.pad(b)
        return 0.5 * total(self.xp, r * r), self.correlate_full(self.wp * r)


class XpVolumeConvolution(_XpCropped):
    """:class:`recon.volume.VolumeConvolutionOperator` on the backend of ``like``.

    All planes are transformed in one batched call (no chunking: a GPU holds the
    spectra of the whole volume; :func:`recon.volume.xp_admm3d.memory_bytes` is checked
    before a solve).

    Attributes
    ----------
    spectra : array, complex64, (n_z, P0, P1 // 2 + 1)
    """

    def __init__(self, op, like):
        super().__init__(op, like)
        self.n_z = op.n_z
        self.ffts_per_apply = op.ffts_per_apply
        self.spectra = self.asarray(op.spectra)

    def sum_spectrum(self, x):
        """``sum_z H_z F x_z`` (n_z rfft2, one batched call)."""
        xp = self.xp
        return xp.sum(xp.fft.rfftn(x, axes=(-2, -1)) * self.spectra, axis=0)

    def convolve_full(self, x):
        """M x: sum over depth of the circular convolutions, padded grid."""
        return self.xp.fft.irfftn(self.sum_spectrum(x), s=self.padded_shape, axes=(-2, -1))

    def backproject_full(self, y_padded):
        """M^T y: every plane's correlation of the padded image with its PSF."""
        xp = self.xp
        spec = xp.fft.rfftn(y_padded, axes=(-2, -1))
        return xp.fft.irfftn(xp.conj(self.spectra) * spec[None, ...], s=self.padded_shape,
                             axes=(-2, -1))

    def forward(self, x):
        """A x; ``x`` (n_z, P0, P1) float32 -> (rows, cols)."""
        x = self._check(x, self.shape_in, "volume")
        return self.sensor_weights * self.convolve_full(x)[self.crop]

    def adjoint(self, y):
        """A^T y; ``y`` (rows, cols) -> (n_z, P0, P1)."""
        y = self._check(y, self.shape_out, "sensor image")
        return self.backproject_full(self.pad(self.sensor_weights * y))

    def data_term(self, x, b):
        """Loss 1/2 ||A x - b||^2 and gradient A^T (A x - b) (2 n_z + 2 FFTs)."""
        r = self.wp * self.convolve_full(self._check(x, self.shape_in, "volume")) - self.pad(b)
        return 0.5 * total(self.xp, r * r), self.backproject_full(self.wp * r)

