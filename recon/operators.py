"""Linear forward models with adjoints (Kuo 2020, Eq. 3.4, 3.8, 3.10).

The same objects serve the simulator, the solvers and the analysis. Each operator
declares ``shape_in``, ``shape_out``, ``dtype`` and ``ffts_per_apply`` and offers
``forward``, ``adjoint``, ``normal`` (A^T A) and ``data_term`` (loss and gradient of
1/2 ||A x - b||^2 in one pass, reusing A x for both).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from . import _kernels
from .errors import ReconInputError
from .fft import fast_padded_shape, irfftn, rfftn
from .validate import as_array, as_int, as_shape2, finite_float


def real32(a, name: str, *, contiguous: bool = False) -> np.ndarray:
    """``a`` as a float32 array, refusing what has no real value (complex, object,
    strings, ragged sequences) instead of dropping an imaginary part or failing in numpy.

    Parameters
    ----------
    a : array_like
        Real data (bool, integer or float).
    name : str
        What it is, for the message.
    contiguous : bool
        Return a C-contiguous array.

    Returns
    -------
    ndarray, float32
        A view when ``a`` is already such an array.

    Raises
    ------
    ReconInputError
        Not convertible, or a non-real dtype.
    """
    arr = a if isinstance(a, np.ndarray) else as_array(a, name)
    if arr.dtype.kind not in "biuf":
        raise ReconInputError(f"{name} must be real numbers, got dtype {arr.dtype}; pass a "
                              "real (float or integer) array")
    if contiguous:
        return np.ascontiguousarray(arr, dtype=np.float32)
    return np.asarray(arr, dtype=np.float32)


class LinearOperator(ABC):
    """A real linear operator ``A: R^shape_in -> R^shape_out`` (float32).

    Subclasses implement :meth:`forward` and :meth:`adjoint`; the generic
    :meth:`data_term` and :meth:`normal` are built from them and may be overridden
    with fused versions.

    Attributes
    ----------
    shape_in, shape_out : tuple of int
    dtype : numpy.dtype
        float32.
    ffts_per_apply : int
        Cost estimate: FFTs (forward or inverse) per ``forward`` or ``adjoint``.
    """

    shape_in: tuple[int, ...]
    shape_out: tuple[int, ...]
    dtype = np.dtype(np.float32)
    ffts_per_apply: int = 0

    @abstractmethod
    def forward(self, x: np.ndarray) -> np.ndarray:
        """Apply A to ``x`` of shape ``shape_in``; returns ``shape_out`` float32."""

    @abstractmethod
    def adjoint(self, y: np.ndarray) -> np.ndarray:
        """Apply A^T to ``y`` of shape ``shape_out``; returns ``shape_in`` float32."""

    def normal(self, x: np.ndarray) -> np.ndarray:
        """Apply A^T A to ``x`` (shape ``shape_in``)."""
        return self.adjoint(self.forward(x))

    def data_term(self, x: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        """Loss 1/2 ||A x - b||^2 and its gradient A^T (A x - b) (Eq. 2.9).

        Parameters
        ----------
        x : ndarray, shape ``shape_in``, float32
        b : ndarray, shape ``shape_out``, float32

        Returns
        -------
        loss : float
        grad : ndarray, shape ``shape_in``, float32
        """
        r = self.forward(x) - b
        return 0.5 * float(np.vdot(r, r)), self.adjoint(r)

    def lipschitz(self, power_iterations: int = 30, seed: int = 0) -> float:
        """Largest eigenvalue of A^T A by power iteration (Lipschitz constant of the
        data-term gradient), with a 2 % safety margin.

        Parameters
        ----------
        power_iterations : int
            Power iterations (>= 1; not a solve's iterations).
        seed : int
            Seed of the random start (>= 0).

        Returns
        -------
        float
            ``1.02`` times the power-iteration estimate of the largest eigenvalue
            (0 where A^T A maps the iterate to 0).

        Raises
        ------
        ReconInputError
            ``power_iterations`` or ``seed`` not an integer in range.
        """
        power_iterations = as_int(power_iterations, "power_iterations", 1)
        rng = np.random.default_rng(as_int(seed, "seed", 0))
        x = rng.standard_normal(self.shape_in).astype(np.float32)
        x /= np.linalg.norm(x)
        lam = 0.0
        for _ in range(power_iterations):
            y = self.normal(x)
            lam = float(np.linalg.norm(y))
            if lam == 0.0 or not np.isfinite(lam):
                break
            x = (y / lam).astype(np.float32, copy=False)
        return 1.02 * lam

    def __matmul__(self, other: LinearOperator) -> LinearOperator:
        return other._rcompose(self)

    def _rcompose(self, outer: LinearOperator) -> LinearOperator:
        """Return ``outer @ self``; subclasses may fold diagonal operators in."""
        return Composition(outer, self)


class Composition(LinearOperator):
    """``outer @ inner`` for any two operators with matching shapes."""

    def __init__(self, outer: LinearOperator, inner: LinearOperator):
        if tuple(outer.shape_in) != tuple(inner.shape_out):
            raise ReconInputError(
                f"cannot compose operators: {inner.shape_out} output into {outer.shape_in} "
                "input; build the outer operator for the inner one's output shape"
            )
        self.outer, self.inner = outer, inner
        self.shape_in, self.shape_out = inner.shape_in, outer.shape_out
        self.ffts_per_apply = outer.ffts_per_apply + inner.ffts_per_apply

    def forward(self, x):
        return self.outer.forward(self.inner.forward(x))

    def adjoint(self, y):
        return self.inner.adjoint(self.outer.adjoint(y))


class PixelErasure(LinearOperator):
    """Diagonal sensor mask diag(m) of Eq. 3.10: ones at measured pixels, zeros at
    erased ones (non-binary weights are allowed, e.g. to down-weight hot pixels).

    Composing ``PixelErasure(m) @ ConvolutionOperator(h)`` folds the mask into the
    convolution's crop, so the solvers keep their fused fast paths.

    Parameters
    ----------
    mask : ndarray, shape (rows, cols)
        Sensor weights, finite and non-negative; converted to float32.

    Raises
    ------
    ReconInputError
        If the mask is not 2D, not real numbers, not finite, negative, or all zero.
    """

    def __init__(self, mask: np.ndarray):
        m = real32(mask, "erasure mask")
        if m.ndim != 2 or not np.all(np.isfinite(m)) or np.any(m < 0) or not np.any(m):
            raise ReconInputError(
                "erasure mask must be a 2D finite non-negative array with some measured "
                "pixels; pass ones for measured pixels and zeros for erased ones"
            )
        self.mask = m
        self.shape_in = self.shape_out = m.shape

    def forward(self, x):
        return (self.mask * x).astype(np.float32, copy=False)

    def adjoint(self, y):
        return self.forward(y)

    def check_shape(self, sensor_shape: tuple[int, int], what: str = "sensor") -> None:
        """Refuse a mask whose shape is not ``sensor_shape``.

        Raises
        ------
        ReconInputError
            "erasure mask shape ... differs from the <what> shape ...".
        """
        if tuple(self.shape_in) != tuple(sensor_shape):
            raise ReconInputError(
                f"erasure mask shape {self.shape_in} differs from the {what} "
                f"shape {tuple(sensor_shape)}"
            )

    @staticmethod
    def random(shape: tuple[int, int], erased_fraction: float, seed: int = 0) -> PixelErasure:
        """A mask erasing ``erased_fraction`` of the pixels uniformly at random.

        Parameters
        ----------
        shape : (rows, cols)
        erased_fraction : float in [0, 1)
        seed : int
            Seed of :func:`numpy.random.default_rng`, for reproducible masks (>= 0).

        Raises
        ------
        ReconInputError
            A shape that is not two integers >= 1, a fraction outside [0, 1) or a
            seed that is not an integer >= 0.
        """
        shape = as_shape2(shape, "shape")
        erased_fraction = finite_float(erased_fraction, "erased fraction")
        seed = as_int(seed, "seed", 0)
        if not 0.0 <= erased_fraction < 1.0:
            raise ReconInputError(
                f"erased fraction {erased_fraction} is outside [0, 1); use e.g. 0.8 to "
                "erase 80 % of the pixels"
            )
        rng = np.random.default_rng(seed)
        return PixelErasure((rng.random(shape) >= erased_fraction).astype(np.float32))


class SensorWeighted:
    """Erasure composition of the cropped-convolution operators (2D and 3D).

    Mixin for operators ending in ``D = diag(w) C`` (crop, then sensor weights
    ``w``, Eq. 3.10) that define ``sensor_shape``, ``sensor_weights`` and
    ``with_weights(w)``: ``PixelErasure(m) @ op`` is ``op.with_weights(w * m)``
    (diag(m) diag(w) = diag(m w)), so the solvers keep their fused fast paths.
    Anything else composes as a plain :class:`Composition`.
    """

    def _rcompose(self, outer):
        if isinstance(outer, PixelErasure):
            outer.check_shape(self.sensor_shape)
            return self.with_weights(self.sensor_weights * outer.mask)
        return super()._rcompose(outer)


def padded_grid(sensor_shape: tuple[int, int], padded_shape=None) -> tuple[
        tuple[int, int], tuple[int, int], tuple[slice, slice]]:
    """The object-domain grid of the cropped convolution model (Eq. 3.4, 4.4).

    Parameters
    ----------
    sensor_shape : (rows, cols)
    padded_shape : (P0, P1), optional
        Default :func:`recon.fft.fast_padded_shape` (at least twice the sensor).

    Returns
    -------
    padded_shape : (P0, P1)
    offset : (top, left)
        Position of the sensor window in the padded grid (centred).
    crop : (slice, slice)
        The sensor window (the crop C).

    Raises
    ------
    ReconInputError
        A padded shape that is not two integers, or smaller than ``2 * sensor - 1``
        (circular wrap-around).
    """
    padded = (fast_padded_shape(sensor_shape) if padded_shape is None
              else as_shape2(padded_shape, "padded_shape"))
    if any(p < 2 * s - 1 for p, s in zip(padded, sensor_shape,
                                                              strict=True)):
        raise ReconInputError(
            f"padded shape {padded} is smaller than twice the sensor {tuple(sensor_shape)}: "
            "circular wrap-around would corrupt the model"
        )
    top = (padded[0] - sensor_shape[0]) // 2
    left = (padded[1] - sensor_shape[1]) // 2
    crop = (slice(top, top + sensor_shape[0]), slice(left, left + sensor_shape[1]))
    return padded, (top, left), crop


def checked_sensor_weights(weights, sensor_shape: tuple[int, int]) -> np.ndarray:
    """Sensor weights (Eq. 3.10: 1 measured, 0 erased) as C-contiguous float32.

    ``None`` gives all ones.

    Raises
    ------
    ReconInputError
        Shape other than ``sensor_shape``, non-real, non-finite or negative weights.
    """
    if weights is None:
        return np.ones(sensor_shape, np.float32)
    w = real32(weights, "sensor weights", contiguous=True)
    if w.shape != tuple(sensor_shape):
        raise ReconInputError(
            f"sensor weights shape {w.shape} differs from the PSF shape {tuple(sensor_shape)}"
        )
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ReconInputError("sensor weights must be finite and non-negative")
    return w


class ConvolutionOperator(SensorWeighted, LinearOperator):
    """Cropped 2D convolution with a shift-invariant PSF (Kuo 2020, Eq. 3.4).

    ``A y = diag(w) C F^-1 diag(F P h) F y``: the object ``y`` lives on the padded
    grid (at least twice the sensor in each axis, rounded up to a fast real-FFT
    length), the PSF is zero-padded and centred, the circular convolution is done
    with real FFTs and the result is cropped to the sensor; ``w`` are optional
    sensor weights (the erasure mask of Eq. 3.10, ones by default). The adjoint is
    Eq. 3.8. A point at the centre of the padded grid images to the PSF as measured.

    Parameters
    ----------
    psf : ndarray, shape (rows, cols)
        The on-axis PSF at sensor size, float32 (converted), finite.
    sensor_weights : ndarray, shape (rows, cols), optional
        Diagonal sensor weights (erasure mask).
    padded_shape : tuple of int, optional
        Object-domain shape; default :func:`recon.fft.fast_padded_shape`.

    Attributes
    ----------
    spectrum : ndarray, complex64, shape (P0, P1 // 2 + 1)
        ``F P h`` (real FFT of the padded, centred PSF).
    crop : tuple of slice
        Where the sensor sits inside the padded grid.

    Examples
    --------
    The adjoint test: ``<A x, y> = <x, A^T y>`` to float32 rounding.

    >>> import numpy as np
    >>> from recon.operators import ConvolutionOperator
    >>> rng = np.random.default_rng(0)
    >>> op = ConvolutionOperator(rng.random((32, 48), dtype=np.float32))
    >>> op.sensor_shape, op.padded_shape
    ((32, 48), (64, 96))
    >>> x = rng.random(op.padded_shape, dtype=np.float32)
    >>> y = rng.random(op.sensor_shape, dtype=np.float32)
    >>> lhs = float(np.vdot(op.forward(x), y)); rhs = float(np.vdot(x, op.adjoint(y)))
    >>> abs(lhs - rhs) / abs(lhs) < 1e-5
    True
    """

    ffts_per_apply = 2

    def __init__(self, psf: np.ndarray, sensor_weights: np.ndarray | None = None,
                 padded_shape: tuple[int, int] | None = None, *, _spectrum=None):
        h = real32(psf, "PSF")
        if h.ndim != 2 or min(h.shape) < 2:
            raise ReconInputError(
                f"PSF must be 2D (rows, cols) with at least 2 pixels per axis, got shape "
                f"{h.shape}"
            )
        if not np.all(np.isfinite(h)):
            raise ReconInputError("PSF contains NaN or inf; fix the calibration frame")
        if not np.any(h):
            raise ReconInputError("PSF is all zero; recapture it with the point source on")
        self.sensor_shape = h.shape
        self.padded_shape, self.offset, self.crop = padded_grid(h.shape, padded_shape)
        self.shape_in, self.shape_out = self.padded_shape, self.sensor_shape
        self.psf = h
        if _spectrum is None:
            padded = np.zeros(self.padded_shape, np.float32)
            padded[self.crop] = h
            _spectrum = rfftn(np.fft.ifftshift(padded)).astype(np.complex64)
        self.spectrum = _spectrum
        self.spectrum_conj = np.conj(_spectrum)
        self.sensor_weights = checked_sensor_weights(sensor_weights, h.shape)
        self._pad_buf = np.zeros(self.padded_shape, np.float32)

    # -- composition (PixelErasure @ op: see SensorWeighted) ------------------------
    def with_weights(self, sensor_weights: np.ndarray) -> ConvolutionOperator:
        """A copy with other sensor weights, sharing the PSF spectrum."""
        return ConvolutionOperator(self.psf, sensor_weights, self.padded_shape,
                                   _spectrum=self.spectrum)

    # -- application -----------------------------------------------------------------
    def convolve_full(self, x: np.ndarray) -> np.ndarray:
        """Circular convolution on the padded grid, before the crop (float32)."""
        return irfftn(rfftn(np.asarray(x, np.float32)) * self.spectrum, self.padded_shape)

    def forward(self, x):
        x = self._check(x, self.shape_in, "object")
        return (self.sensor_weights * self.convolve_full(x)[self.crop]).astype(np.float32)

    def adjoint(self, y):
        y = self._check(y, self.shape_out, "sensor image")
        buf = self.pad_buffer()
        np.multiply(self.sensor_weights, y, out=buf[self.crop])
        return irfftn(rfftn(buf) * self.spectrum_conj, self.padded_shape)

    def data_term(self, x, b):
        """Fused loss and gradient: 4 FFTs, the crop, weights and residual in one
        pass, no large temporaries beyond the FFT outputs (see base class)."""
        x = self._check(x, self.shape_in, "object")
        b = self._check(b, self.shape_out, "measurement")
        spec = rfftn(x)
        _kernels.multiply_spectrum(spec, self.spectrum, False)
        full = irfftn(spec, self.padded_shape)
        loss = _kernels.crop_residual(full, b, self.sensor_weights, *self.offset)
        spec = rfftn(full)
        _kernels.multiply_spectrum(spec, self.spectrum, True)
        return 0.5 * loss, irfftn(spec, self.padded_shape)

    def pad_buffer(self) -> np.ndarray:
        """The operator's reusable padded buffer, zero outside the sensor crop.

        Callers write only ``buf[self.crop]`` and consume the buffer before the next
        call (it saves a page-faulting allocation per apply).
        """
        return self._pad_buf

    @staticmethod
    def _check(a, shape, what):
        a = real32(a, what)
        if a.shape != tuple(shape):
            raise ReconInputError(f"{what} has shape {a.shape}, operator expects {shape}")
        return a
