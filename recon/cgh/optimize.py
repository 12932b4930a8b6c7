"""Hologram optimiser: projected gradient with Nesterov acceleration (Algorithm 1, App. A.4).

Solves Eq. 7.14 / 7.23: minimise an intensity loss (:mod:`.losses`) over the SLM
field ``s`` subject to ``|s| = 1`` (or ``|s| <= 1`` for a complex SLM).

Gradient (Wirtinger calculus, Eq. A.7-A.9). With ``x_z = m_z U s``,
``z_z = F x_z`` (unitary DFT), ``I_z = |z_z|^2`` and ``a_z = dL/dI_z`` (real), the
real gradient ``g = dL/d(Re s) + i dL/d(Im s) = 2 dL/d(conj s)`` is::

    g = 2 sum_z U^T( conj(m_z) F^H( a_z z_z ) )                        (Eq. A.9)

so that ``dL = Re <g, ds>``. Per plane, with ``R = sigma I - T`` and
``sigma = sum T / sum I``, ``a = sigma G - c`` where ``G = dL/dR`` is

* ``R`` (L2), ``P^T P R`` (frequency), ``P^T c_s^2 P R`` (spatial), and
* ``c = (sum G R + sum G T) / sum I`` comes from differentiating ``sigma``.

Since ``F^H(c z) = c x`` and ``U^T(|m|^2 U w) = mask_energy w``, the constant part is
applied at SLM resolution: ``g = 2 sigma U^T(conj(m) F^H(G z)) - 2 c mask_energy w``.

Iteration (FISTA with backtracking, Beck & Teboulle; ``t`` the momentum sequence)::

    w = s_k + beta (s_k - s_{k-1}),       beta = (t_k - 1) / t_{k+1}
    s_{k+1} = prox(w - mu grad L(w))      prox = s/|s| (Eq. A.6)

The step ``mu`` is automatic: it starts at ``step_scale / k^2`` and is halved
until the sufficient-decrease test ``L(s+) <= L(w) + Re<g, s+ - w> + |s+ - w|^2 /
(2 mu)`` holds (a local Lipschitz estimate); the momentum restarts when the loss
rises (O'Donoghue & Candes). The field is linear in ``s``, so the field at ``w`` is
``(1 + beta) z(s_k) - beta z(s_{k-1})`` and costs no FFT.

FFTs per iteration (complex-FFT equivalents, a real FFT counts 1/2; plus one
trial per backtrack, rare after the first iterations): L2 2 (fft2 + ifft2),
frequency 3.5 (+ rfft2/irfft2 for the gradient, rfft2 for the trial's loss),
spatial 5. Multiply by the number of planes.

Two engines evaluate the loss and gradient: :class:`_Engine` here (NumPy, numba kernels
of :mod:`._kernels`, scipy.fft in place) and the generic
:class:`recon.cgh.xp_optimize.XpEngine` (the array API: PyTorch or CuPy on a GPU, any
conforming array); :func:`recon.cgh.iteration.iterate` runs the loop with either.
:func:`optimize_hologram` picks by ``device`` and by the type of the target.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import scipy.fft as sfft

from ..backend import resolve_device, to_numpy
from ..errors import ReconInputError
from ..fft import WORKERS
from ..validate import as_array, as_int, finite_float, positive
from . import _kernels
from .baselines import one_step_hologram
from .hologram import HologramResult, check_slm_kind, check_targets, project
from .iteration import iterate
from .losses import IntensityLoss, butterworth_lowpass
from .scattering_display import ScatteringDisplay, field_from_phase

__all__ = ["loss_and_gradient", "no_mask_hologram", "optimize_hologram"]

log = logging.getLogger(__name__)


class _Engine:
    """Buffers and fused evaluations of the loss and its gradient (raw FFT frame).

    Works in the uncentred frame of ``fft2(x)``: ``|fft2(x)|^2 = ifftshift(I)`` for
    the centred intensity ``I`` of :meth:`ScatteringDisplay.forward`, so targets and
    weights are ``ifftshift``-ed once here and no shift is done per iteration.
    """

    def __init__(self, display: ScatteringDisplay, targets: np.ndarray, loss: IntensityLoss,
                 double: bool = False):
        self.rdt = np.dtype(np.float64 if double else np.float32)
        self.cdt = np.dtype(np.complex128 if double else np.complex64)
        self.d = display
        self.loss = loss
        self.grid = display.grid_shape
        self.n = self.grid[0] * self.grid[1]
        self.k = display.k
        self.masks = [m.astype(np.complex128 if m.dtype.kind == "c" else np.float64)
                      for m in display.plane_masks] if double else display.plane_masks
        self.energy = display.mask_energy.astype(self.rdt)
        power = float(self.energy.sum(dtype=np.float64))  # sum I of a unit-modulus field
        self.T = []
        for t in targets:
            t64 = t.astype(np.float64)
            self.T.append(np.ascontiguousarray(
                sfft.ifftshift(t64 * (power / t64.sum())), dtype=self.rdt))
        self.sumT = [float(t.sum(dtype=np.float64)) for t in self.T]
        self.ffts = 0.0
        self.fft_seconds = 0.0
        n_slm = display.slm_shape[0] * display.slm_shape[1]
        self.H = butterworth_lowpass(self.grid, n_slm, loss.order) if loss.lowpass else None
        if self.H is not None:
            self.H = self.H.astype(self.rdt)
        self.H2 = None if self.H is None else self.H * self.H
        w = loss.weight_map(self.grid)
        self.C2 = None if w is None else np.ascontiguousarray(
            sfft.ifftshift(w.astype(self.rdt) ** 2))
        self.R = np.empty(self.grid, self.rdt)
        self.that = [None] * len(self.T)  # rfft2(T) (frequency loss, cross term)
        self.pt = [None] * len(self.T)  # P T (spatial loss, cross term)
        for p, t in enumerate(self.T):
            if self.C2 is not None:
                self.pt[p] = self._lowpass(t) if self.H is not None else t
            elif self.H is not None:
                self.that[p] = self._rfft(t)
        self.slm_tmp = np.empty(display.slm_shape, self.cdt)
        self.norm0 = sum(self._plane_value(-t, p) for p, t in enumerate(self.T))

    # -- FFTs (counted and timed) --------------------------------------------------------

    def _timed(self, fn, cost, *args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, workers=WORKERS, **kwargs)
        self.fft_seconds += time.perf_counter() - t0
        self.ffts += cost
        return out

    def _rfft(self, a):
        return self._timed(sfft.rfft2, 0.5, a)

    def _irfft(self, a):
        return self._timed(sfft.irfft2, 0.5, a, s=self.grid, overwrite_x=True)

    def _fft_inplace(self, buf, inverse=False):
        fn = sfft.ifft2 if inverse else sfft.fft2
        out = self._timed(fn, 1.0, buf, norm="ortho", overwrite_x=True)
        if out.ctypes.data != buf.ctypes.data:  # pragma: no cover - scipy did not work in place
            buf[...] = out

    def _lowpass(self, a):
        spec = self._rfft(a)
        _kernels.multiply_real(spec, self.H)
        return self._irfft(spec)

    # -- model ---------------------------------------------------------------------------

    def new_fields(self) -> list[np.ndarray]:
        """One complex grid buffer per plane (complex64, or complex128 when double)."""
        return [np.empty(self.grid, self.cdt) for _ in self.masks]

    def fields(self, s: np.ndarray, out: list[np.ndarray]) -> list[np.ndarray]:
        """``out[p] = fft2(m_p U s)`` (raw frame), in place; returns ``out``."""
        for p, m in enumerate(self.masks):
            _kernels.upsample_multiply(s, m, self.k, out[p])
            self._fft_inplace(out[p])
        return out

    @staticmethod
    def copy_fields(src: list[np.ndarray], dst: list[np.ndarray]) -> list[np.ndarray]:
        """Copy the fields ``src`` into the buffers ``dst``; returns ``dst``."""
        for a, b in zip(dst, src, strict=True):
            np.copyto(a, b)
        return dst

    @staticmethod
    def new_grad(s: np.ndarray) -> np.ndarray:
        """A gradient buffer like ``s``."""
        return np.empty_like(s)

    @staticmethod
    def copy(a: np.ndarray) -> np.ndarray:
        """A copy of ``a``."""
        return a.copy()

    @staticmethod
    def extrapolate(s: np.ndarray, s_prev: np.ndarray, beta: float) -> np.ndarray:
        """Nesterov's point ``s + beta (s - s_prev)`` (complex64)."""
        return s + np.float32(beta) * (s - s_prev) if beta else s.copy()

    @staticmethod
    def descend(w: np.ndarray, mu: float, grad: np.ndarray, slm: str) -> np.ndarray:
        """The projected gradient step ``prox(w - mu grad)`` (Eq. A.6)."""
        return project(w - np.float32(mu) * grad, slm)

    @staticmethod
    def inner(a: np.ndarray, b: np.ndarray) -> float:
        """``Re <a, b>``."""
        return float(np.vdot(a, b).real)

    def power(self, s: np.ndarray) -> float:
        """``sum I`` on each plane: ``sum mask_energy |s|^2`` (Parseval)."""
        return float(np.sum(self.energy * (s.real ** 2 + s.imag ** 2), dtype=np.float64))

    def _sigma(self, p: int, total: float):
        return self.rdt.type(self.sumT[p] / total if self.loss.match_mean else 1.0)

    def _plane_value(self, r: np.ndarray, p: int) -> float:
        """Loss of one plane from its residual ``r`` (``r`` may be overwritten)."""
        if self.H is None and self.C2 is None:
            return 0.5 * float(np.vdot(r, r).real)
        if self.C2 is None:
            spec = self._rfft(r)
            e, _ = _kernels.spectrum_filter(spec, self.H2, spec, self.grid[1], False, False)
            return 0.5 * e / self.n
        rf = self._lowpass(r) if self.H is not None else r
        return 0.5 * _kernels.weighted_sum(rf, self.C2)

    def value(self, z: list[np.ndarray], total: float) -> float:
        """Loss at the fields ``z`` (unchanged) with ``sum I = total``."""
        acc = 0.0
        for p in range(len(z)):
            rr, _ = _kernels.residual(z[p], self.T[p], self._sigma(p, total), self.R)
            acc += 0.5 * rr if (self.H is None and self.C2 is None) else \
                self._plane_value(self.R, p)
        return acc

    def value_and_grad(self, a: float, za: list[np.ndarray], b: float, zb: list[np.ndarray],
                       z: list[np.ndarray], w: np.ndarray, total: float,
                       grad: np.ndarray) -> tuple[float, np.ndarray]:
        """Loss at ``w`` and its real gradient into ``grad``; returns both.

        The fields at ``w`` are ``a za + b zb`` (linearity in ``s``); they are built
        into ``z`` and destroyed there.
        """
        grad[...] = 0
        acc = 0.0
        const = 0.0
        ra, rb = self.rdt.type(a), self.rdt.type(b)
        for p in range(len(z)):
            sig = self._sigma(p, total)
            rr, ri = _kernels.combine_residual(ra, za[p], rb, zb[p], z[p], self.T[p], sig,
                                               self.R)
            if self.H is None and self.C2 is None:  # L2: G = R
                lp, cross, g = 0.5 * rr, sig * ri / total, self.R
            elif self.C2 is None:  # frequency: G = P^T P R
                spec = self._rfft(self.R)
                e, x = _kernels.spectrum_filter(spec, self.H2, self.that[p], self.grid[1],
                                                True, self.loss.match_mean)
                lp, cross = 0.5 * e / self.n, (e + x) / (self.n * total)
                g = self._irfft(spec)
            else:  # spatial: G = P^T c^2 P R
                rf = self._lowpass(self.R) if self.H is not None else self.R
                e, x = _kernels.weight_filtered(rf, self.C2, self.pt[p])
                lp, cross = 0.5 * e, (e + x) / total
                g = self._lowpass(rf) if self.H is not None else rf
            acc += lp
            if self.loss.match_mean:
                const += cross
            _kernels.multiply_real(z[p], g)
            self._fft_inplace(z[p], inverse=True)
            _kernels.bin_conj_multiply(z[p], self.masks[p], self.k, self.slm_tmp)
            grad += self.rdt.type(2.0 * sig) * self.slm_tmp
        if const:
            grad -= self.rdt.type(2.0 * const) * self.energy * w
        return acc, grad


def _initial_field(display, targets, init, slm, seed) -> np.ndarray:
    if isinstance(init, str):
        if init == "one-step":
            return one_step_hologram(display, targets, seed=seed, slm=slm).field
        if init == "random":
            rng = np.random.default_rng(seed)
            return field_from_phase(rng.uniform(-math.pi, math.pi, display.slm_shape))
        raise ReconInputError(f"init must be 'one-step', 'random' or an array, got {init!r}")
    a = as_array(init, "init")
    if a.shape != display.slm_shape:
        raise ReconInputError(f"init has shape {a.shape}, the SLM is {display.slm_shape}")
    if a.dtype.kind not in "fiuc":
        raise ReconInputError(f"init must be a real phase map or a complex field, got dtype "
                              f"{a.dtype}")
    if not np.all(np.isfinite(a)):
        raise ReconInputError("init contains NaN or inf; pass a finite phase map or field")
    if a.dtype.kind != "c":
        return field_from_phase(a)
    return project(np.ascontiguousarray(a, dtype=np.complex64), slm)


def loss_and_gradient(display: ScatteringDisplay, s, target, loss: IntensityLoss | None = None,
                      double: bool = False):
    """Loss and real gradient ``2 dL/d(conj s)`` at an SLM field (Eq. A.7-A.9).

    Parameters
    ----------
    display : ScatteringDisplay
    s : numpy.ndarray or array
        Complex SLM field, ``slm_shape`` (any modulus). A NumPy array takes the NumPy
        path; an array of another array-API library (PyTorch, CuPy) the generic path
        (``recon.cgh.xp_optimize.XpEngine``) on that array's device.
    target : numpy.ndarray
        Target intensity per plane (centred frame), normalised internally to the
        power of a unit-modulus SLM field.
    loss : IntensityLoss, optional
        Default :meth:`IntensityLoss.frequency`.
    double : bool
        Evaluate in float64/complex128 (for gradient checks; NumPy path only);
        default single.

    Returns
    -------
    (float, array)
        ``L`` and the gradient ``g`` (complex64, complex128 when ``double``) with
        ``dL = Re <g, ds>``; on ``s``'s device for the generic path.

    Raises
    ------
    ReconInputError
        Bad display, field or target; ``double`` on the generic path.
    """
    loss = IntensityLoss.frequency() if loss is None else loss
    if not isinstance(display, ScatteringDisplay):
        raise ReconInputError(f"display must be a ScatteringDisplay, got {type(display).__name__}")
    backend = _array_backend(s)
    if backend is not None:
        if double:
            raise ReconInputError("double=True is for the NumPy path; pass a numpy array")
        from .xp_optimize import XpEngine

        display.check_slm(to_numpy(s))  # shape, dtype and finiteness
        eng = XpEngine(display, check_targets(_host(target), display), loss, backend)
        s = backend.xp.astype(s, backend.xp.complex64)
        z = eng.fields(s)
        return eng.value_and_grad(1.0, z, 0.0, z, z, s, eng.power(s))
    eng = _Engine(display, check_targets(target, display), loss, double=double)
    display.check_slm(s)  # shape, dtype and finiteness
    s = np.ascontiguousarray(s, dtype=eng.cdt)
    z = eng.fields(s, eng.new_fields())
    return eng.value_and_grad(1.0, z, 0.0, z, z, s, eng.power(s),
                              np.empty(display.slm_shape, eng.cdt))


def _host(a):
    """``a`` as a host (NumPy) array when it is another library's array, else as given."""
    return a if _array_backend(a) is None else to_numpy(a)


def _array_backend(a):
    """The backend of an array of another array-API library (PyTorch, CuPy, ...), or
    None for NumPy arrays and anything else (lists, scalars)."""
    if isinstance(a, np.ndarray) or not hasattr(a, "__dlpack__"):
        return None
    from .xp_optimize import backend_of

    try:
        return backend_of(a)
    except TypeError:  # not an array-API array after all
        return None


def _choose_backend(target, device: str):
    """Where the optimisation runs: ``device`` (:func:`recon.backend.resolve_device`),
    or the target's own library and device when it is not a NumPy array and ``device``
    is the CPU (or ``auto`` without a GPU)."""
    backend = resolve_device(device)
    if backend.is_numpy:
        return _array_backend(target) or backend
    return backend


def optimize_hologram(display: ScatteringDisplay, target, loss: IntensityLoss | None = None,
                      steps: int = 200, *, init="one-step", seed: int = 0,
                      slm: str = "phase", step_scale: float = 4.0, step_growth: float = 1.0,
                      max_backtracks: int = 30, checkpoints=(), callback=None,
                      device: str = "cpu") -> HologramResult:
    """Compute an SLM pattern for a target intensity (Eq. 7.14 / 7.23, Algorithm 1).

    Parameters
    ----------
    display : ScatteringDisplay
        The display model (mask, ``k``, planes).
    target : numpy.ndarray
        Target intensity, ``display.grid_shape`` or ``(n_planes, *grid_shape)``,
        centred frame (zero order in the middle), >= 0; its scale is irrelevant.
    loss : IntensityLoss, optional
        Default :meth:`IntensityLoss.frequency` (Eq. 7.17).
    steps : int
        Most gradient steps of the optimiser, its iterations (an integer >= 1, numpy
        integers too); 200 by default. The result's ``iterations`` counts those taken
        (fewer when ``callback`` stops it).
    init : {"one-step", "random"} or numpy.ndarray
        Start: the one-step baseline (default), a random phase, a phase map (real)
        or a complex field (projected).
    seed : int
        Seed of the one-step target phase or of the random start (>= 0).
    slm : {"phase", "complex"}
        Phase-only projection ``s/|s|`` (Eq. A.6) or complex SLM (``|s| <= 1``).
    step_scale : float
        Initial step ``mu_0 = step_scale / k^2`` (> 0); backtracking lowers it.
    step_growth : float
        Factor (>= 1) applied to the step after every iteration (1: monotone).
    max_backtracks : int
        Halvings allowed per iteration (>= 0); when exhausted the loss cannot decrease at
        float32 precision and the run stops ("converged").
    checkpoints : iterable of int
        Iterations after which a copy of the field is kept (e.g. ``(25, 50, 100)``).
    callback : callable, optional
        ``callback(iteration, field, loss)`` after each iteration (``field`` on the
        device the optimisation runs on); return ``True`` to stop early (e.g. to
        cancel from a GUI).
    device : {"cpu", "cuda", "auto"}
        Where it runs (:func:`recon.backend.resolve_device`): ``cpu`` the NumPy path
        (numba kernels, scipy.fft), ``cuda`` the generic path
        (``recon.cgh.xp_optimize``) on the GPU through CuPy or PyTorch, ``auto``
        the GPU when one is usable. A ``target`` of another array library (a PyTorch
        tensor, a CuPy array) with ``cpu`` runs the generic path on that array's
        device. The result is on the host either way; ``params["device"]`` says where
        it ran.

    Returns
    -------
    HologramResult

    Raises
    ------
    ReconInputError
        Bad display, target, parameters or init; an unusable ``device`` (names what
        is missing); a problem that does not fit in the GPU's free memory (says how
        much it needs, ``recon.cgh.xp_optimize.memory_bytes``).
    DivergenceError
        The loss became NaN/inf (history and last good field attached).
    """
    t_start = time.perf_counter()
    if not isinstance(display, ScatteringDisplay):
        raise ReconInputError(f"display must be a ScatteringDisplay, got {type(display).__name__}")
    loss = IntensityLoss.frequency() if loss is None else loss
    if not isinstance(loss, IntensityLoss):
        raise ReconInputError(f"loss must be an IntensityLoss, got {type(loss).__name__}")
    check_slm_kind(slm)
    steps = as_int(steps, "steps", 1)
    seed = as_int(seed, "seed", 0)
    step_scale = positive(step_scale, "step_scale")
    step_growth = finite_float(step_growth, "step_growth", lo=1.0)
    max_backtracks = as_int(max_backtracks, "max_backtracks", 0)
    try:
        marks = {as_int(c, "checkpoints entry", 1) for c in checkpoints}
    except TypeError:
        raise ReconInputError(f"checkpoints must be a sequence of iteration numbers, got "
                              f"{checkpoints!r}") from None
    backend = _choose_backend(target, device)
    targets = check_targets(_host(target), display)
    if backend.is_numpy:
        eng = _Engine(display, targets, loss)
        s = _initial_field(display, targets, init, slm, seed)
    else:
        from .xp_optimize import XpEngine, check_device_memory, initial_field_xp

        check_device_memory(backend, display.slm_shape, display.k, display.n_planes)
        eng = XpEngine(display, targets, loss, backend)
        s = initial_field_xp(eng, targets, init if isinstance(init, str) else
                             _initial_field(display, targets, _host(init), slm, seed), slm, seed)
    result = iterate(eng, s, steps, slm=slm, mu=step_scale / (display.k ** 2),
                      step_growth=step_growth, max_backtracks=max_backtracks, marks=marks,
                      callback=callback, t_start=t_start)
    result.params = {"loss": loss.name, "iterations": steps, "init": init if isinstance(
        init, str) else "array", "seed": seed, "slm": slm, "step_scale": step_scale,
        "step_growth": step_growth, "final_step": result.params["final_step"], "k": display.k,
        "planes_mm": display.planes_mm, "device": backend.label}
    log.debug("hologram on %s: %d iterations, loss %.4g, %.2f s (%s)", backend.label,
              result.iterations, result.loss, result.seconds, result.stop_reason)
    return result


def no_mask_hologram(target, loss=None, *, slm_pitch_um: float = 16.0, **kwargs):
    """Hologram on the bare SLM (no mask, native étendue) for reference.

    The target is shown over the native field of view only, at SLM resolution; the
    optimiser and loss are the same as with a mask (``k = 1``, so the Butterworth
    passband holds every SLM frequency that fits its disc).

    Parameters
    ----------
    target : numpy.ndarray
        Target intensity, ``(N_y, N_x)`` = the SLM shape, centred frame.
    loss : IntensityLoss, optional
        Default :meth:`IntensityLoss.frequency`.
    slm_pitch_um : float
        SLM pitch (um).
    **kwargs
        Passed to :func:`optimize_hologram`.

    Returns
    -------
    (ScatteringDisplay, HologramResult)
    """
    t = np.asarray(target)
    if t.ndim != 2:
        raise ReconInputError(f"target must be 2D (rows, cols) at SLM resolution, got {t.shape}")
    display = ScatteringDisplay.no_mask(t.shape, slm_pitch_um=slm_pitch_um)
    return display, optimize_hologram(display, t, loss, **kwargs)
