"""The hologram optimiser's loss and gradient through the array API (CuPy, PyTorch, ...).

:class:`XpEngine` is the generic twin of :class:`recon.cgh.optimize._Engine`: the same
loss (Eq. 7.16, 7.17, 7.19 with the mean matching ``sigma``), the same Wirtinger
gradient (Eq. A.7-A.9) and the same FFT count per evaluation, written with whole-array
operations of the Python array API standard so one implementation runs on PyTorch or
CuPy arrays on a CUDA GPU (or PyTorch's CPU, ``array-api-strict`` in the tests). The
iteration itself (Algorithm 1: Nesterov momentum, backtracking, restarts) is shared with
the NumPy path (:func:`recon.cgh.optimize.optimize_hologram` runs either engine).

The constant arrays (normalised targets, the Butterworth response ``H`` of
:func:`recon.cgh.losses.butterworth_lowpass`, the spatial weights of
:meth:`recon.cgh.losses.IntensityLoss.weight_map`) are built on the host once, exactly as
the NumPy path builds them, and copied to the device. The numba kernels' fused passes
become whole-array expressions; their float64 accumulators become the backend's float32
sums, so the two paths agree to float32 rounding. The Hermitian column weights of a real
FFT (1 for column 0 and, for an even width, the last; 2 elsewhere) are folded into
``H^2`` once, so a Parseval sum is a single weighted sum.

FFTs are counted as on the NumPy path; they are not timed one by one (a GPU runs them
asynchronously), so ``fft_seconds`` is NaN.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from ..backend import Backend, array_namespace, check_memory, device_of, free_device_bytes
from .losses import IntensityLoss, butterworth_lowpass
from .xp_display import XpDisplay

__all__ = ["XpEngine", "backend_of", "check_device_memory", "initial_field_xp", "memory_bytes",
           "project_xp"]

#: Bytes per mask-grid sample per plane: the mask (complex64 at most), the normalised
#: target, its half spectrum or low-passed copy, and three planes' fields at once (the
#: accepted, the previous being replaced, the trial).
PLANE_BYTES = 8 + 4 + 4 + 4 + 3 * 8
#: Bytes per mask-grid sample shared by the planes: the filters (``H``, ``H^2`` with the
#: column weights, half-size; the spatial weights) and the temporaries of one plane's
#: evaluation (field, intensity, residual, spectrum, gradient field, its inverse FFT, the
#: masked product) and the FFT plans' work areas (CuPy keeps one with each cached plan:
#: forward, inverse, real forward and inverse).
SHARED_BYTES = 2 + 2 + 4 + 8 + 4 + 4 + 4 + 4 + 8 + 8 + 8 + 3 * 8


def memory_bytes(slm_shape, k: int, n_planes: int = 1) -> int:
    """Estimated peak device memory of the generic optimiser, bytes.

    Parameters
    ----------
    slm_shape : (int, int)
        SLM pixels ``(N_y, N_x)``.
    k : int
        Mask pixels per SLM pixel (expansion ``k^2``): the grid is ``N_y k x N_x k``.
    n_planes : int
        Image planes.

    Returns
    -------
    int
        ``G (n_planes PLANE_BYTES + SHARED_BYTES)`` for ``G`` grid samples, plus the
        SLM-resolution fields (a few complex64 ``slm_shape`` arrays).
    """
    n_slm = int(slm_shape[0]) * int(slm_shape[1])
    grid = n_slm * int(k) ** 2
    return grid * (int(n_planes) * PLANE_BYTES + SHARED_BYTES) + 12 * 8 * n_slm


def check_device_memory(backend: Backend, slm_shape, k: int, n_planes: int = 1) -> None:
    """Refuse, before anything is allocated there, a hologram that does not fit in the
    device's free memory (:func:`memory_bytes`, :func:`recon.backend.check_memory`).

    Parameters
    ----------
    backend : recon.backend.Backend
        The device (no check on the CPU: its free memory is not queried).
    slm_shape : (int, int)
        SLM pixels ``(N_y, N_x)``.
    k : int
        Mask pixels per SLM pixel (expansion ``k^2``).
    n_planes : int
        Image planes.

    Raises
    ------
    ReconInputError
        "the hologram of a N_x x N_y SLM at q x with P plane(s) needs X GiB on
        <device>, Y GiB are free; ...".
    """
    ny, nx = (int(v) for v in slm_shape)
    check_memory(memory_bytes(slm_shape, k, n_planes), free_device_bytes(backend),
                 where=backend.label, fix="use a smaller SLM, factor or fewer planes",
                 what=f"the hologram of a {nx} x {ny} SLM at {int(k) ** 2}x with "
                 f"{int(n_planes)} plane(s)")


def backend_of(a) -> Backend:
    """The :class:`~recon.backend.Backend` of a non-NumPy array (its namespace, device)."""
    xp = array_namespace(a)
    dev = device_of(a)
    name = xp.__name__.split(".")[-1].replace("_", "-")
    where = f"cuda:{dev.id}" if name == "cupy" else "cpu" if name == "array-api-strict" else dev
    return Backend(name, xp, dev, f"{where} ({name})")


def project_xp(xp, v, slm: str):
    """:func:`recon.cgh.hologram.project` on any backend: ``v / |v|`` (1 where ``v = 0``)
    for a phase-only SLM (Eq. A.6), ``v / max(1, |v|)`` for a complex one."""
    a = xp.abs(v)
    if slm == "phase":
        zero = a == 0
        out = v / xp.where(zero, xp.ones_like(a), a)
        return xp.where(zero, xp.ones_like(v), out)
    return v / xp.clip(a, min=1.0)


def _column_weights(n_rows: int, n_cols: int) -> np.ndarray:
    """Hermitian weights of an rfft2 spectrum of ``n_cols`` real columns, float32
    ``(n_rows, n_cols // 2 + 1)`` (:func:`recon.cgh._kernels.spectrum_filter`)."""
    w = np.full((n_rows, n_cols // 2 + 1), 2.0, np.float32)
    w[:, 0] = 1.0
    if n_cols % 2 == 0:
        w[:, -1] = 1.0
    return w


class XpEngine:
    """Loss and gradient of the hologram optimiser on a backend (raw FFT frame).

    The interface is :class:`recon.cgh.optimize._Engine`'s, with arrays of
    ``backend``: fields and gradients are returned (new arrays) rather than written
    into buffers.

    Parameters
    ----------
    display : ScatteringDisplay
    targets : numpy.ndarray
        float32 ``(n_planes, G_y, G_x)``, centred frame (checked by
        :func:`recon.cgh.hologram.check_targets`).
    loss : IntensityLoss
    backend : recon.backend.Backend
        Not NumPy.
    """

    def __init__(self, display, targets: np.ndarray, loss: IntensityLoss, backend: Backend):
        self.backend = backend
        self.xp = backend.xp
        self.d = XpDisplay(display, backend)
        self.loss = loss
        self.grid = display.grid_shape
        self.n = self.grid[0] * self.grid[1]
        self.ffts = 0.0
        self.fft_seconds = math.nan
        power = float(display.mask_energy.sum(dtype=np.float64))
        host_t = []
        for t in targets:
            t64 = t.astype(np.float64)
            host_t.append(np.ascontiguousarray(sfft.ifftshift(t64 * (power / t64.sum())),
                                               dtype=np.float32))
        self.sumT = [float(t.sum(dtype=np.float64)) for t in host_t]
        self.T = [self.d.asarray(t) for t in host_t]
        n_slm = display.slm_shape[0] * display.slm_shape[1]
        h = butterworth_lowpass(self.grid, n_slm, loss.order) if loss.lowpass else None
        self.H = None if h is None else self.d.asarray(h)
        self.H2 = None if h is None else self.d.asarray(h * h)
        self.Hw = None if h is None else self.d.asarray(h * h * _column_weights(*self.grid))
        w = loss.weight_map(self.grid)
        self.C2 = None if w is None else self.d.asarray(
            np.ascontiguousarray(sfft.ifftshift(w.astype(np.float32) ** 2)))
        self.that = [self._rfft(t) if self.H is not None and self.C2 is None else None
                     for t in self.T]
        self.pt = [(self._lowpass(t) if self.H is not None else t) if self.C2 is not None
                   else None for t in self.T]
        self.norm0 = sum(self._plane_value(-t) for t in self.T)

    # -- FFTs (counted) ------------------------------------------------------------------

    def _rfft(self, a):
        self.ffts += 0.5
        return self.xp.fft.rfftn(a, axes=(-2, -1))

    def _irfft(self, a):
        self.ffts += 0.5
        return self.xp.fft.irfftn(a, s=self.grid, axes=(-2, -1))

    def _lowpass(self, a):
        return self._irfft(self._rfft(a) * self.H)

    def _sum(self, a) -> float:
        return float(self.xp.sum(a))

    # -- the loop's array operations ------------------------------------------------------

    def new_fields(self) -> list:
        """Placeholders for a list of plane fields (the generic path allocates anew)."""
        return [None] * len(self.T)

    def new_grad(self, s):
        """Placeholder for the gradient (returned by :meth:`value_and_grad`)."""
        return None

    def fields(self, s, out=None) -> list:
        """``fft2(m_p U s)`` per plane (raw frame), new arrays (``out`` is ignored)."""
        self.ffts += len(self.T)
        return self.d.fields(s)

    @staticmethod
    def copy_fields(src: list, dst=None) -> list:
        """The fields of ``src`` (arrays are not written in place here)."""
        return list(src)

    def copy(self, a):
        """A copy of ``a`` on the device."""
        return self.xp.asarray(a, copy=True)

    def power(self, s) -> float:
        """``sum I`` on each plane: ``sum mask_energy |s|^2`` (Parseval)."""
        return self.d.power(s)

    def extrapolate(self, s, s_prev, beta: float):
        """Nesterov's point ``s + beta (s - s_prev)``."""
        return s + beta * (s - s_prev) if beta else self.copy(s)

    def descend(self, w, mu: float, grad, slm: str):
        """The projected gradient step ``prox(w - mu grad)``."""
        return project_xp(self.xp, w - mu * grad, slm)

    def inner(self, a, b) -> float:
        """``Re <a, b>`` as a float."""
        xp = self.xp
        return self._sum(xp.real(a) * xp.real(b) + xp.imag(a) * xp.imag(b))

    # -- loss and gradient ------------------------------------------------------------------

    def _sigma(self, p: int, total: float) -> float:
        return self.sumT[p] / total if self.loss.match_mean else 1.0

    def _residual(self, v, p: int, sigma: float):
        xp = self.xp
        inten = xp.real(v) ** 2 + xp.imag(v) ** 2
        return sigma * inten - self.T[p], inten

    def _plane_value(self, r) -> float:
        """Loss of one plane from its residual ``r``."""
        if self.H is None and self.C2 is None:
            return 0.5 * self._sum(r * r)
        if self.C2 is None:
            spec = self._rfft(r)
            xp = self.xp
            return 0.5 * self._sum(self.Hw * (xp.real(spec) ** 2 + xp.imag(spec) ** 2)) / self.n
        rf = self._lowpass(r) if self.H is not None else r
        return 0.5 * self._sum(self.C2 * rf * rf)

    def value(self, z: list, total: float) -> float:
        """Loss at the fields ``z`` with ``sum I = total``."""
        return sum(self._plane_value(self._residual(z[p], p, self._sigma(p, total))[0])
                   for p in range(len(z)))

    def _plane_gradient(self, r, inten, p: int, sig: float, total: float):
        """(loss, cross term, ``G = dL/dR``) of one plane (module docstring of
        :mod:`recon.cgh.optimize`)."""
        xp = self.xp
        if self.H is None and self.C2 is None:  # L2: G = R
            return 0.5 * self._sum(r * r), sig * self._sum(r * inten) / total, r
        if self.C2 is None:  # frequency: G = P^T P R
            spec = self._rfft(r)
            re, im = xp.real(spec), xp.imag(spec)
            e = self._sum(self.Hw * (re * re + im * im))
            x = 0.0
            if self.loss.match_mean:
                t = self.that[p]
                x = self._sum(self.Hw * (re * xp.real(t) + im * xp.imag(t)))
            return 0.5 * e / self.n, (e + x) / (self.n * total), self._irfft(spec * self.H2)
        rf = self._lowpass(r) if self.H is not None else r  # spatial: G = P^T c^2 P R
        wv = self.C2 * rf
        e, x = self._sum(wv * rf), self._sum(wv * self.pt[p])
        return 0.5 * e, (e + x) / total, (self._lowpass(wv) if self.H is not None else wv)

    def value_and_grad(self, a: float, za: list, b: float, zb: list, z, w, total: float,
                       grad=None):
        """Loss at ``w`` and its real gradient ``2 dL/d(conj s)`` (Eq. A.9).

        The fields at ``w`` are ``a za + b zb`` (linearity in ``s``).

        Returns
        -------
        (float, array)
            The loss and the complex64 ``slm_shape`` gradient on the device.
        """
        acc = 0.0
        const = 0.0
        for p in range(len(za)):
            sig = self._sigma(p, total)
            v = a * za[p] + b * zb[p]
            r, inten = self._residual(v, p, sig)
            lp, cross, g = self._plane_gradient(r, inten, p, sig, total)
            acc += lp
            if self.loss.match_mean:
                const += cross
            self.ffts += 1.0
            part = (2.0 * sig) * self.d.back(v * g, p)
            grad = part if p == 0 else grad + part
        if const:
            grad = grad - (2.0 * const) * self.d.energy * w
        return acc, grad


def initial_field_xp(eng: XpEngine, targets: np.ndarray, init, slm: str, seed: int):
    """The optimiser's start on the device.

    Parameters
    ----------
    eng : XpEngine
    targets : numpy.ndarray
        float32 ``(n_planes, G_y, G_x)``, centred frame.
    init : {"one-step", "random"} or numpy.ndarray
        ``"one-step"``: :func:`recon.cgh.baselines.one_step_hologram` with the adjoint
        on the device (the random target phase drawn on the host, as the NumPy path
        draws it); ``"random"``: a random phase from the host's generator; an array:
        the complex64 start already checked and projected on the host.
    slm : {"phase", "complex"}
    seed : int

    Returns
    -------
    array
        complex64 ``slm_shape`` on the device.
    """
    from .baselines import random_phase_field
    from .scattering_display import field_from_phase

    xp, d = eng.xp, eng.d
    if not isinstance(init, str):
        return d.asarray(init)
    if init == "random":
        rng = np.random.default_rng(seed)
        return d.asarray(field_from_phase(rng.uniform(-math.pi, math.pi, d.slm_shape)))
    if init != "one-step":
        from ..errors import ReconInputError

        raise ReconInputError(f"init must be 'one-step', 'random' or an array, got {init!r}")
    z = d.adjoint(d.asarray(random_phase_field(targets, seed)))
    eng.ffts += len(d.masks)
    if slm == "phase":
        return project_xp(xp, z, "phase")
    peak = float(xp.max(xp.abs(z)))
    return z / peak if peak > 0 else xp.ones_like(z)
