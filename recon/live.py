"""Per-PSF reconstructor for video: precompute once, then only the solve per frame.

:class:`LiveReconstructor` prepares the PSF (dark level, binning, clip, unit sum), builds
the forward model of Eq. 3.4 (:class:`~recon.operators.ConvolutionOperator`) and the ADMM
precomputations (:class:`~recon.solvers.admm.AdmmPlan`) once. Per frame it does the raw
conversion of :func:`recon.preprocess.prepare_pair` (same functions, same order), the
scaling of :func:`recon.api.scaled_problem` and one solve:

- :meth:`LiveReconstructor.wiener`: the Wiener preview (:func:`recon.solvers.wiener`).
- :meth:`LiveReconstructor.admm`: a few ADMM iterations (Kuo 2020, Eq. 4.5 / App. A.3;
  Boyd et al. 2011) through :func:`recon.solvers.admm_loop.run_admm`, warm-started from the
  previous frame's ADMM state (consecutive video frames are similar).

A cold single frame equals :func:`recon.reconstruct` with the same method, iterations
and weights exactly (tests/recon/test_live.py).

The options' ``device="cuda"`` (or ``"auto"`` with a usable GPU) keeps the PSF
spectrum, the Wiener filter and the warm-start ADMM state on the GPU
(``recon.xp_live.DeviceLive``, the array-API path); frames still come in and images go
out as NumPy arrays.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .backend import Backend, resolve_device, to_numpy
from .errors import ReconInputError
from .options import ReconOptions
from .planar import DEFAULT_TV, scaled_problem
from .preprocess import box_bin, subtract_dark, validate_measurement, validate_psf
from .preprocess.dark import DEFAULT_DARK_REGION, front_door_dark, resolve_dark
from .preprocess.validation import as_array, check_bin_factor
from .priors import Prior, prior_of
from .solvers import SolveResult, wiener
from .solvers.admm import AdmmPlan, AdmmState, plan_for_prior, record_prior, run_admm
from .solvers.penalty import AdmmPenalty, check_penalty_settings
from .solvers.wiener import auto_regularization
from .validate import as_int, nonneg_weight, positive

__all__ = ["LiveReconstructor", "LiveResult"]


@dataclass
class LiveResult:
    """One reconstructed frame.

    Attributes
    ----------
    image : ndarray, float32, shape (rows, cols)
        Sensor field of view of the estimate (binned sensor shape), measurement units
        (counts per unit PSF sum), as ``recon.Reconstruction.image``.
    estimate : ndarray, float32, shape (P0, P1)
        The whole padded object domain, same units (on a device: copied to the host
        when first read).
    solve : SolveResult
        The solver's record (estimate in the scaled problem, history, parameters; on
        a device its ``x`` stays there and ``params["device"]`` names it).
    method : str
        ``"wiener"`` or ``"admm"``.
    iterations : int
        ADMM iterations run on this frame (1 for Wiener).
    warm : bool
        Whether ADMM started from the previous frame's state.
    raw_scale : float
        The frame's scale max|b| (the scaled problem is b / raw_scale).
    seconds : float
        Wall time of the whole call (conversion + solve), s.
    """

    image: np.ndarray
    estimate: np.ndarray
    solve: SolveResult
    method: str
    iterations: int
    warm: bool
    raw_scale: float
    seconds: float


class _DeviceResult(LiveResult):
    """A :class:`LiveResult` whose ``estimate`` stays on the device until it is read
    (a live view shows only ``image``: the padded grid is 4x the sensor's)."""

    @property
    def estimate(self) -> np.ndarray:
        """The padded estimate on the host (copied on first access)."""
        if not isinstance(self._estimate, np.ndarray):
            self._estimate = to_numpy(self._estimate)
        return self._estimate

    @estimate.setter
    def estimate(self, value) -> None:
        self._estimate = value


class LiveReconstructor:
    """Reconstruct video frames of one PSF with the per-PSF work done once.

    Parameters
    ----------
    psf : ndarray, (rows, cols), any real dtype
        Calibration PSF in sensor counts, same shape as the frames (grayscale only).
    options : recon.options.ReconOptions, optional
        The reconstruction's options (default: the declared ones); the live
        reconstructor reads four of them:

        - ``bin_factor``: box binning of PSF and frames (4 turns 1200 x 1600 into
          300 x 400).
        - ``dark``: as :func:`recon.reconstruct`'s: ``"auto"`` estimates the dark level
          from the PSF's corner and subtracts it from the PSF and every frame; ``"none"``
          or None subtracts nothing (both are dark-subtracted already); a level in DN or
          a dark frame (rows, cols) is subtracted from both.
        - ``prior``: ADMM's image prior, as :func:`recon.reconstruct`'s (default
          isotropic TV, ``"tv-iso"``); ``"auto"``, which chooses per image by
          hold-out cross-validation, is refused (a live stream keeps one prior).
        - ``device``: where the solves run (:func:`recon.backend.resolve_device`):
          ``cpu`` the NumPy path (numba); ``cuda`` a GPU through the array-API path
          (``recon.xp_live.DeviceLive``), with the PSF spectrum and the ADMM state kept
          there between frames. A :class:`~recon.backend.Backend` is used as given
          (PyTorch's CPU backend in benchmarks and tests). ``backend`` says which.

        Values a caller resolved (a dark level, a backend) go in with
        ``ReconOptions.from_defaults(dark=..., device=...)``.
    tv : float, optional
        ADMM TV weight in the scaled problem; default ``recon.api.DEFAULT_TV["admm"]``.
    penalty : AdmmPenalty, optional
        Initial ADMM penalties and residual balancing (default ``AdmmPenalty()``, see
        :func:`recon.solvers.admm.admm`; with the default schedule balancing first
        changes a penalty at iteration 6 of 10 or more; none with a few iterations
        per frame).
    regularization : float, optional
        Wiener lambda in units of |H|^2. Default: estimated from the first frame
        :meth:`wiener` sees (:func:`recon.solvers.wiener.auto_regularization`, a
        wavelet noise estimate too slow for every frame) and kept afterwards
        (``regularization``).

    Raises
    ------
    ReconInputError
        A PSF that is not 2D, not finite, without signal above the dark level, or
        invalid weights / binning / dark; an unusable ``device`` (names what is
        missing), or a problem that does not fit in the GPU's free memory (says how
        much it needs; checked before anything is put on the device); an options prior of
        ``"auto"`` (a live stream keeps one prior; name one).

    Notes
    -----
    Warm start (:meth:`admm` with ``warm_start=True``) carries the whole scaled-dual
    ADMM state of the previous frame (:class:`~recon.solvers.admm.AdmmState`): the primal
    x, M x, and per split q = z - a (split variable minus scaled dual) for the crop,
    the two TV and the non-negativity splits, plus the penalties. Only the data b
    changes, which enters the crop split's v-update (Boyd et al. 2011, Sec. 3.1.1: the
    iteration is a fixed-point map, so any state is a valid start). Since each frame is
    scaled by its own max|b|, the state is first multiplied by previous scale / new
    scale so it is in the new frame's units.

    Examples
    --------
    >>> import numpy as np
    >>> from recon.live import LiveReconstructor
    >>> from recon.operators import ConvolutionOperator
    >>> rng = np.random.default_rng(1)
    >>> psf = 100.0 * (rng.random((48, 64)) > 0.97)  # a sparse caustic-like PSF
    >>> scene = np.zeros((96, 128), np.float32); scene[40:56, 50:70] = 1.0
    >>> frame = ConvolutionOperator(psf).forward(scene)  # one video frame
    >>> from recon.options import ReconOptions
    >>> live = LiveReconstructor(psf, ReconOptions.from_defaults(dark=0.0))
    >>> live.wiener(frame).image.shape
    (48, 64)
    >>> first = live.admm(frame, iterations=5)        # cold start
    >>> second = live.admm(frame, iterations=5)       # warm: continues the first
    >>> second.image.dtype
    dtype('float32')
    """

    def __init__(self, psf: np.ndarray, options: ReconOptions | None = None, *,
                 tv: float | None = None, penalty: AdmmPenalty | None = None,
                 regularization: float | None = None):
        o = ReconOptions.from_defaults() if options is None else options
        psf = as_array(psf, "PSF")
        validate_psf(psf)
        if psf.ndim != 2:
            raise ReconInputError(f"live reconstruction takes a 2D (grayscale) PSF, got shape "
                                  f"{psf.shape}; pass one channel")
        self.bin_factor = check_bin_factor(o.bin_factor)
        self.raw_shape = psf.shape
        self._dark_mode, self._dark = resolve_dark(front_door_dark(o.dark), psf,
                                                   DEFAULT_DARK_REGION, None)
        p = np.maximum(self._convert(psf), 0.0)  # the PSF clip of prepare_pair
        self.tv = DEFAULT_TV["admm"] if tv is None else nonneg_weight(tv, "tv")
        self.penalty = check_penalty_settings(penalty)
        self.regularization = (None if regularization is None
                               else positive(regularization, "regularization"))
        # scaled_problem normalises the PSF to unit sum; its measurement half is unused
        self.operator, _ = scaled_problem(p, p)
        self.prior = _live_prior(o.prior)
        self.plan = AdmmPlan.of(self.operator)
        self._state: AdmmState | None = None
        self._state_scale = 1.0
        self.backend = _backend(o.device)
        self._device = None
        if not self.backend.is_numpy:
            from .xp_live import DeviceLive

            self._device = DeviceLive(self.backend, self.plan, self.prior)
        else:  # as recon.admm's: TV, the fused isotropic passes or the generic set
            self.plan = plan_for_prior(self.plan, np.zeros(1, np.float32), self.prior)

    @property
    def state(self):
        """The ADMM state the next warm frame starts from (:class:`AdmmState
        <recon.solvers.admm.AdmmState>`, on a device an ``XpAdmmState`` of
        ``recon.solvers.xp_admm`` with its arrays there), or None."""
        return self._state

    @property
    def sensor_shape(self) -> tuple[int, int]:
        """(rows, cols) of the binned frames and of ``LiveResult.image``."""
        return self.operator.sensor_shape

    def _convert(self, raw: np.ndarray) -> np.ndarray:
        """Dark subtraction and binning of :func:`recon.preprocess.prepare_pair`, float32."""
        if self._dark_mode == "none":
            return box_bin(raw.astype(np.float32), self.bin_factor)
        return box_bin(subtract_dark(raw, self._dark), self.bin_factor)

    def prepare(self, raw: np.ndarray) -> tuple[np.ndarray, float]:
        """A raw frame as the scaled measurement of the solvers.

        Parameters
        ----------
        raw : ndarray, ``raw_shape`` (the PSF's), any real dtype
            Sensor counts.

        Returns
        -------
        b : ndarray, float32, :attr:`sensor_shape`
            Dark-subtracted, binned, divided by its max|b|.
        raw_scale : float
            That max|b|.

        Raises
        ------
        ReconInputError
            Wrong shape, non-finite values, or a frame that is zero after the dark
            subtraction.
        """
        raw = as_array(raw, "measurement")
        if raw.shape != self.raw_shape:
            raise ReconInputError(f"frame has shape {raw.shape}, the PSF {self.raw_shape}; "
                                  "stream frames of the PSF's size and binning")
        validate_measurement(raw)
        b = self._convert(raw)
        scale = float(np.max(np.abs(b)))
        if not scale > 0:
            raise ReconInputError("frame is zero after dark subtraction; check the exposure")
        # the scaling of recon.api.scaled_problem (no erasure weights here)
        return (np.asarray(b, np.float64) / scale).astype(np.float32), scale

    def _result(self, res: SolveResult, method: str, iterations: int, warm: bool,
                scale: float, t0: float) -> LiveResult:
        if method == "admm":  # recorded as recon.admm does
            record_prior(res, self.prior)
        if self._device is not None:
            image, estimate = self._device.images(res.x, scale, self.operator.crop)
            return _DeviceResult(image, estimate, res, method, iterations, warm, scale,
                                 time.perf_counter() - t0)
        estimate = (res.x * scale).astype(np.float32)
        image = np.ascontiguousarray(estimate[self.operator.crop])
        return LiveResult(image, estimate, res, method, iterations, warm, scale,
                          time.perf_counter() - t0)

    def wiener(self, raw: np.ndarray) -> LiveResult:
        """Wiener preview of one frame (:func:`recon.solvers.wiener`).

        Parameters
        ----------
        raw : ndarray, ``raw_shape``, any real dtype

        Returns
        -------
        LiveResult
            Equal to ``recon.reconstruct(psf, raw, "wiener", bin_factor=..., dark=...,
            regularization=...)`` (on the first frame also with the automatic lambda).

        Raises
        ------
        ReconInputError
            See :meth:`prepare`.
        """
        t0 = time.perf_counter()
        b, scale = self.prepare(raw)
        if self.regularization is None:
            self.regularization = auto_regularization(b)
        res = (wiener(self.operator, b, regularization=self.regularization)
               if self._device is None else self._device.wiener(b, self.regularization))
        return self._result(res, "wiener", 1, False, scale, t0)

    def admm(self, raw: np.ndarray, iterations: int, warm_start: bool = True) -> LiveResult:
        """``iterations`` ADMM iterations on one frame, warm-started by default.

        Parameters
        ----------
        raw : ndarray, ``raw_shape``, any real dtype
        iterations : int
            >= 1 (a live worker passes its :class:`recon.options.LiveOptions`'
            ``iterations``).
        warm_start : bool
            Start from the state left by the previous :meth:`admm` call (see the class
            notes); False, or no previous call, starts cold (x_0 = 0, the initial
            penalties of ``penalty``). The state is kept either way for the next frame.

        Returns
        -------
        LiveResult
            Cold: equal to ``recon.reconstruct(psf, raw, "admm", iterations=iterations,
            tv=tv, auto_stop=False, penalty=penalty)``.

        Raises
        ------
        ReconInputError
            See :meth:`prepare`, or invalid iterations.
        DivergenceError
            The solve diverged; the state is dropped (the next frame starts cold).
        """
        t0 = time.perf_counter()
        iterations = as_int(iterations, "iterations", 1)
        b, scale = self.prepare(raw)
        warm = warm_start and self._state is not None
        if warm:
            self._state.scale(self._state_scale / scale)
        elif self._device is None:
            self._state = self.plan.zeros(self.penalty.initial(), self.tv > 0)
        else:
            self._state = self._device.zeros(self.penalty.initial(), self.tv > 0)
        self._state_scale = scale
        try:
            if self._device is None:
                res = run_admm(self.plan, b, self._state, iterations=iterations,
                               tv=self.tv, penalty=self.penalty)
            else:
                res = self._device.admm(b, self._state, iterations=iterations, tv=self.tv,
                                        penalty=self.penalty)
        except Exception:
            self._state = None
            raise
        return self._result(res, "admm", iterations, warm, scale, t0)

    def reset(self) -> None:
        """Forget the ADMM state: the next :meth:`admm` call starts cold."""
        self._state = None


def _live_prior(name) -> Prior:
    """The fixed prior of a live stream: ``ReconOptions.prior`` but ``"auto"``.

    Raises
    ------
    ReconInputError
        ``"auto"`` (a choice per image by hold-out cross-validation, too slow for
        every frame and not one prior across frames), or an unknown name.
    """
    if name == "auto":
        raise ReconInputError("live reconstruction keeps one prior for the whole stream; "
                              "prior 'auto' chooses one per image: name one (tv-iso, the "
                              "default, tv, tgv, wavelet or dncnn)")
    return prior_of(name)


def _backend(device) -> Backend:
    """The backend of a ``device=`` argument: a name (:func:`resolve_device`) or a
    :class:`~recon.backend.Backend` as given."""
    if isinstance(device, Backend):
        return device
    return resolve_device(device)
