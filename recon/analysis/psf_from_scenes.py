"""A PSF calibrated from known scenes: non-negative least squares in the PSF.

With the scene known, the lensless forward model ``b = C (h * P x)`` (Kuo 2020,
Eq. 3.4: pad the object, convolve with the PSF, crop the sensor) is linear in the
PSF ``h`` as well: the convolution is symmetric, so the scene plays the PSF's role in
the same :class:`recon.operators.ConvolutionOperator` (``ConvolutionOperator(x)``
applied to the padded PSF is ``ConvolutionOperator(h)`` applied to the padded scene,
exactly: the centring shift commutes with the circular convolution). Given pairs of
scenes on the sensor grid and their measurements, each colour channel's PSF is

    h = argmin_{h >= 0}  1/2 sum_i ||C (x_i * P h) - b_i||^2

solved by ADMM with the split ``h = z, z >= 0`` (Boyd et al. 2011, Sec. 5.2): the
h-update ``(A^T A + rho I) h = A^T b + rho (z - u)`` by a few iterations of
preconditioned conjugate gradients, warm-started; the preconditioner is the
update's operator without the crop, diagonal in Fourier,
``1 / (sum_i |X_i(f)|^2 + rho)``. Natural scenes have a ~1/f^2 power spectrum, so
the normal operator's eigenvalues span many decades; the preconditioner whitens
them, without which gradient methods stall (FISTA on gradient-whitened data reached
a held-out residual of 0.18 in 100 iterations on the shared real pairs where this
reaches 0.08). The unconstrained least-squares PSF fits as well but carries ~40 %
negative mass, which the reconstruction's clipping turns into a poor PSF.

ADMM runs until an iteration changes the PSF by less than ``tol`` of its norm (1 %,
26 to 30 iterations on the shared real pairs) rather than a fixed count. By default
the colour channels are tied: a diffuser's caustics are nearly the same pattern in
every channel, so one pattern ``h`` is fitted to every (pair, channel), each channel
``c`` as ``g_c h`` with its gain ``g_c`` (the channel's measured light over its
scenes' light): three times the equations for the same unknowns. Measured by what
the PSF buys (a fixed prior-free FISTA on each left-out real pair, docs/real-data.md),
tying beat the channels alone; weighting the data term by image gradients (whitening
the scenes' ~1/f^2 spectrum) lost 0.55 to 3.7 dB there (most at full size), so it is not used.

:func:`leave_one_out` scores the calibration honestly: each pair's relative residual
``||C (x_k * P h_{-k}) - b_k|| / ||b_k||`` under the PSF estimated without it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ReconInputError
from ..fft import irfftn, map_jobs, rfftn
from ..operators import ConvolutionOperator, real32
from ..validate import as_int, as_shape2, finite_float

__all__ = ["ESTIMATE_ITERATIONS", "LeaveOneOut", "PsfEstimate", "binned_psf_options", "check_pairs",
           "estimate_psf_from_scenes", "held_out_estimate", "leave_one_out",
           "predict_measurements", "relative_residuals"]

#: The estimate's cap on ADMM iterations (it stops earlier once converged): its own
#: quantity, not a reconstruction's ``iterations``; ``calibrate psf-from-scenes
#: --iterations`` defaults to it.
ESTIMATE_ITERATIONS = 100


@dataclass(frozen=True)
class PsfEstimate:
    """A PSF estimated from known scenes (:func:`estimate_psf_from_scenes`).

    Attributes
    ----------
    psf : ndarray, float32, (rows, cols) or (rows, cols, channels)
        Non-negative, centred as :class:`recon.operators.ConvolutionOperator` takes
        it (a point at the centre of the object grid images to it); the channels of
        the measurements, if any. In the measurements' unit per unit of scene.
    residuals : ndarray, float64, (n_pairs, channels)
        Each training pair's relative residual ``||C (x_i * P h) - b_i|| / ||b_i||``
        (in-sample: :func:`leave_one_out` gives held-out ones).
    iterations, cg_iterations : int
        The cap on ADMM iterations and conjugate-gradient iterations per h-update.
    rho_rel : float
        ADMM penalty relative to the largest eigenvalue of the uncropped normal
        operator.
    tied : bool
        The channels share one pattern, each scaled by its gain (``tie_channels``).
    iterations_run : int
        The ADMM iterations run (at most ``iterations``; fewer once converged).
    tol : float
        The convergence criterion: an iteration's relative change of the PSF.
    """

    psf: np.ndarray
    residuals: np.ndarray
    iterations: int
    cg_iterations: int
    rho_rel: float
    tied: bool = False
    iterations_run: int = 0
    tol: float = 0.0

    @property
    def method(self) -> str:
        """The method in words, for records."""
        tied = ("; the colour channels tied: one pattern, a gain per channel"
                if self.tied else "")
        return (f"non-negative least squares by ADMM ({self.iterations_run} iterations, "
                f"at most {self.iterations}, until a relative change below {self.tol:g}; "
                f"{self.cg_iterations} Fourier-preconditioned CG steps per update, rho "
                f"{self.rho_rel:g} x the largest eigenvalue{tied})")


@dataclass(frozen=True)
class LeaveOneOut:
    """Held-out residuals of :func:`leave_one_out`.

    Attributes
    ----------
    residuals : ndarray, float64, (n_pairs, channels)
        Pair ``k``'s relative residual under the PSF estimated from the other pairs.
    psfs : list of ndarray
        The PSF estimated without pair ``k``, per ``k`` (as ``PsfEstimate.psf``).
    """

    residuals: np.ndarray
    psfs: list

    @property
    def per_pair(self) -> np.ndarray:
        """Each pair's residual averaged over the channels, (n_pairs,)."""
        return self.residuals.mean(axis=1)

    @property
    def mean(self) -> float:
        """The residual averaged over pairs and channels."""
        return float(self.residuals.mean())


def _channels(a: np.ndarray) -> np.ndarray:
    """``a`` as (rows, cols, channels)."""
    return a[..., None] if a.ndim == 2 else a


def check_pairs(scenes, measurements) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Validate scene/measurement pairs; each as float32 (rows, cols, channels).

    Parameters
    ----------
    scenes, measurements : sequence of array_like, or ndarray (n, rows, cols[, C])
        The known scenes on the sensor grid (Eq. 3.3's object grid cropped to the
        sensor: the object as the camera's convolution model sees it, inverted and
        scaled) and their measurements (dark-subtracted), pairwise the same shape.

    Returns
    -------
    scenes, measurements : list of ndarray, float32, (rows, cols, channels)

    Raises
    ------
    ReconInputError
        Different numbers of scenes and measurements, none, shapes that differ or are
        not (rows, cols) or (rows, cols, channels), non-real or non-finite values, or
        a scene channel that is all zero.
    """
    scenes = [real32(s, f"scene {i}") for i, s in enumerate(scenes)]
    measurements = [real32(b, f"measurement {i}") for i, b in enumerate(measurements)]
    if len(scenes) != len(measurements) or not scenes:
        raise ReconInputError(
            f"{len(scenes)} scenes and {len(measurements)} measurements: give one "
            "measurement per known scene, at least one pair")
    shape = measurements[0].shape
    if len(shape) not in (2, 3) or min(shape[:2]) < 2:
        raise ReconInputError(f"measurement 0 has shape {shape}; give images (rows, cols) or "
                              "(rows, cols, channels) with at least 2 pixels a side")
    for i, (x, b) in enumerate(zip(scenes, measurements, strict=True)):
        if x.shape != b.shape or b.shape != shape:
            raise ReconInputError(
                f"pair {i}: scene {x.shape} and measurement {b.shape} (pair 0's measurement "
                f"{shape}): give every scene on the sensor grid, the shape of its "
                "measurement, and every pair the same shape (resample the scenes onto the "
                "sensor grid first)")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(b))):
            raise ReconInputError(f"pair {i} holds NaN or inf; fix or leave out that pair")
        empty = [c for c in range(_channels(x).shape[2]) if not np.any(_channels(x)[..., c])]
        if empty:
            raise ReconInputError(f"scene {i} is all zero in channel(s) {empty}: a dark "
                                  "scene says nothing about the PSF; leave it out")
    return ([np.ascontiguousarray(_channels(x)) for x in scenes],
            [np.ascontiguousarray(_channels(b)) for b in measurements])


class _Problem:
    """The least-squares problem of one channel: the scenes' spectra, the crop and
    the PSF's support in the padded grid, with the normal operator, the right-hand
    side and the Fourier preconditioner.

    The normal operator fuses the pairs: ``F`` of the support-embedded PSF once,
    per pair an inverse FFT, the crop, an FFT, accumulated in Fourier, one inverse
    FFT (``2 n + 2`` FFTs for ``n`` pairs rather than ``4 n``).
    """

    def __init__(self, scenes: Sequence[np.ndarray], psf_shape: tuple[int, int]):
        ops = [ConvolutionOperator(x) for x in scenes]  # the scene in the PSF's role
        self.padded = ops[0].padded_shape
        self.crop = ops[0].crop
        self.spectra = [op.spectrum for op in ops]
        rows, cols = ops[0].sensor_shape
        top = self.crop[0].start + rows // 2 - psf_shape[0] // 2
        left = self.crop[1].start + cols // 2 - psf_shape[1] // 2
        self.support = (slice(top, top + psf_shape[0]), slice(left, left + psf_shape[1]))
        self.power = sum(np.abs(s.astype(np.complex128)) ** 2 for s in self.spectra)
        self._buf = np.zeros(self.padded, np.float32)

    def _embed(self, a: np.ndarray, where) -> np.ndarray:
        self._buf[...] = 0.0
        self._buf[where] = a
        return rfftn(self._buf)

    def forward(self, h: np.ndarray, k: int) -> np.ndarray:
        """Pair ``k``'s predicted measurement ``C (x_k * P h)``."""
        return irfftn(self._embed(h, self.support) * self.spectra[k], self.padded)[self.crop]

    def adjoint_sum(self, measurements: Sequence[np.ndarray]) -> np.ndarray:
        """``sum_k A_k^T b_k`` on the support."""
        acc = sum(self._embed(b, self.crop) * np.conj(s)
                  for b, s in zip(measurements, self.spectra, strict=True))
        return irfftn(acc, self.padded)[self.support]

    def normal(self, h: np.ndarray) -> np.ndarray:
        """``sum_k A_k^T A_k h`` on the support."""
        spec = self._embed(h, self.support)
        acc = None
        for s in self.spectra:
            y = irfftn(spec * s, self.padded)[self.crop]
            term = self._embed(y, self.crop) * np.conj(s)
            acc = term if acc is None else acc + term
        return irfftn(acc, self.padded)[self.support]

    def precondition(self, g: np.ndarray, inverse: np.ndarray) -> np.ndarray:
        """``g`` filtered by ``inverse`` (diagonal in Fourier), back on the support."""
        return irfftn(self._embed(g, self.support) * inverse, self.padded)[self.support]


def _admm(problem: _Problem, measurements, iterations: int, cg_iterations: int,
          rho_rel: float, tol: float = 0.0, on_iteration=None,
          initial=None) -> tuple[np.ndarray, int]:
    """The non-negative least-squares PSF of one problem (module docstring): at most
    ``iterations`` ADMM iterations, fewer once an iteration changes ``z`` by less than
    ``tol`` of its norm; returns ``z`` and the iterations run."""
    rho = rho_rel * float(problem.power.max())
    inverse = (1.0 / (problem.power + rho)).astype(np.float32)
    atb = problem.adjoint_sum(measurements).astype(np.float64)
    shape = atb.shape
    h, u = np.zeros(shape), np.zeros(shape)
    if initial is not None:
        h[...] = initial
    z = h.copy()

    def system(v):
        return problem.normal(v.astype(np.float32)).astype(np.float64) + rho * v

    def precondition(g):
        return problem.precondition(g.astype(np.float32), inverse).astype(np.float64)

    done = 0
    for done in range(1, iterations + 1):
        r = atb + rho * (z - u) - system(h)
        q = precondition(r)
        p, rq = q.copy(), float(np.vdot(r, q))
        for _ in range(cg_iterations):
            if rq <= 0.0:  # converged to rounding
                break
            ap = system(p)
            alpha = rq / float(np.vdot(p, ap))
            h += alpha * p
            r -= alpha * ap
            q = precondition(r)
            rq_next = float(np.vdot(r, q))
            p = q + (rq_next / rq) * p
            rq = rq_next
        z_next = np.maximum(h + u, 0.0)
        change = float(np.linalg.norm(z_next - z)) / max(float(np.linalg.norm(z_next)), 1e-300)
        z = z_next
        u += h - z
        if on_iteration is not None:
            on_iteration(done, change)
        if change < tol:
            break
    return z.astype(np.float32), done


def _options(psf_shape, sensor_shape, iterations, cg_iterations, rho_rel):
    iterations = as_int(iterations, "iterations", 1)
    cg_iterations = as_int(cg_iterations, "cg_iterations", 1)
    rho_rel = finite_float(rho_rel, "rho_rel", lo=0.0, lo_open=True)
    psf_shape = sensor_shape if psf_shape is None else as_shape2(psf_shape, "psf_shape")
    if (psf_shape[0] > sensor_shape[0] or psf_shape[1] > sensor_shape[1]
            or min(psf_shape) < 2):
        raise ReconInputError(
            f"psf_shape {psf_shape} must lie within the sensor {sensor_shape} with at "
            "least 2 pixels a side; leave it out for a PSF of the sensor's size")
    return psf_shape, iterations, cg_iterations, rho_rel


def estimate_psf_from_scenes(scenes, measurements, *, psf_shape=None,
                             iterations: int = ESTIMATE_ITERATIONS, cg_iterations: int = 5,
                             rho_rel: float = 1e-4, tie_channels: bool = True,
                             tol: float = 1e-2, initial=None,
                             on_iteration=None) -> PsfEstimate:
    """The PSF per colour channel from known scenes and their measurements.

    Non-negative least squares by ADMM with Fourier-preconditioned conjugate gradients
    until converged (module docstring); the channels tied by default.

    Parameters
    ----------
    scenes : sequence of array_like, (rows, cols) or (rows, cols, channels)
        The known scenes on the sensor grid: the object the convolution model
        (:class:`recon.operators.ConvolutionOperator`) sees, i.e. registered to the
        measurement (inverted and scaled by the magnification d/z for a displayed
        image), linear in radiance (no display gamma).
    measurements : sequence of array_like, the scenes' shapes
        Dark-subtracted measurements, linear in light.
    psf_shape : (rows, cols), optional
        Support of the PSF, centred on the sensor's centre; default the sensor's
        shape.
    iterations : int
        The most ADMM iterations (>= 1; :data:`ESTIMATE_ITERATIONS` by default).
    cg_iterations : int
        Conjugate-gradient iterations per h-update (>= 1).
    rho_rel : float
        ADMM penalty relative to ``max_f sum_i |X_i(f)|^2`` (> 0).
    tie_channels : bool
        One pattern for every colour channel, scaled by a gain per channel (each
        channel's light over its scenes' light, ``_channel_gains``): every
        (pair, channel) is one equation of the same pattern, three times the data of
        a channel alone (module docstring). False: each channel on its own.
    tol : float
        Stop once an iteration changes the PSF by less than this fraction of its norm
        (>= 0; 0 runs every iteration).
    initial : array_like, optional
        A start for the PSF, ``psf_shape`` with the measurements' channels (default
        zero). Never start a held-out estimate from a PSF that saw the held-out pair.
    on_iteration : callable, optional
        ``on_iteration(channels, iteration, change)`` after each ADMM iteration
        (progress): the channels solved (all of them when tied), the iteration from 1,
        the relative change.

    Returns
    -------
    PsfEstimate
        ``psf`` of shape ``psf_shape`` (2D for 2D measurements, else with their
        channels last), float32, >= 0.

    Raises
    ------
    ReconInputError
        Pairs refused by :func:`check_pairs`, an option out of range, an initial PSF
        of another shape, or tied channels of which one holds no light.

    Examples
    --------
    >>> import numpy as np
    >>> from recon.analysis.psf_from_scenes import estimate_psf_from_scenes
    >>> from recon.operators import ConvolutionOperator
    >>> rng = np.random.default_rng(1)
    >>> h = np.zeros((16, 20), np.float32); h[5, 7] = h[9, 12] = 1.0
    >>> scenes = [rng.random((16, 20), dtype=np.float32) for _ in range(3)]
    >>> measurements = [ConvolutionOperator(x).forward(np.pad(h, ((8, 8), (10, 10))))
    ...                 for x in scenes]
    >>> est = estimate_psf_from_scenes(scenes, measurements, iterations=30)
    >>> bool(np.corrcoef(est.psf.ravel(), h.ravel())[0, 1] > 0.99)
    True
    """
    xs, bs = check_pairs(scenes, measurements)
    sensor = xs[0].shape[:2]
    psf_shape, iterations, cg_iterations, rho_rel = _options(
        psf_shape, sensor, iterations, cg_iterations, rho_rel)
    tol = finite_float(tol, "tol", lo=0.0)
    channels = xs[0].shape[2]
    start = None if initial is None else _channels(real32(initial, "initial PSF"))
    if start is not None and start.shape != (*psf_shape, channels):
        raise ReconInputError(f"initial PSF of shape {start.shape}: give one of shape "
                              f"{(*psf_shape, channels)}")
    tied = bool(tie_channels) and channels > 1
    groups = [list(range(channels))] if tied else [[c] for c in range(channels)]
    psf = np.zeros((*psf_shape, channels), np.float32)
    residuals = np.zeros((len(xs), channels))
    used = 0
    for group in groups:
        # one problem per group: a tied group's pairs are every (pair, channel), each
        # channel's measurement divided by its gain (the PSF's channels in ratio)
        gains = _channel_gains(xs, bs) if tied else np.ones(channels)
        problem = _Problem([x[..., c] for c in group for x in xs], psf_shape)
        b = [m[..., c] / gains[c] for c in group for m in bs]
        h0 = None if start is None else start[..., group].mean(axis=-1) / gains[group].mean()

        def step(i, change, group=group):
            if on_iteration is not None:
                on_iteration(group, i, change)
        h, done = _admm(problem, b, iterations, cg_iterations, rho_rel, tol, step, h0)
        used = max(used, done)
        for j, c in enumerate(group):
            psf[..., c] = gains[c] * h
            residuals[:, c] = [_relative(gains[c] * problem.forward(h, j * len(xs) + k),
                                         bs[k][..., c]) for k in range(len(xs))]
    psf = psf[..., 0] if np.ndim(measurements[0]) == 2 else psf
    return PsfEstimate(psf, residuals, iterations, cg_iterations, rho_rel, tied, used, tol)


def _channel_gains(xs, bs) -> np.ndarray:
    """Each channel's PSF total relative to their mean: a convolution's total is the
    product of its factors' totals, so ``sum_i sum b_ic / sum_i sum x_ic``."""
    light = np.array([sum(float(b[..., c].sum()) for b in bs) for c in range(bs[0].shape[2])])
    scene = np.array([sum(float(x[..., c].sum()) for x in xs) for c in range(xs[0].shape[2])])
    ratio = np.maximum(light, 0.0) / scene
    if not np.all(ratio > 0):
        raise ReconInputError("a channel's measurements hold no light in total: its PSF "
                              "cannot be tied to the others; give tie_channels=False")
    return ratio / ratio.mean()


def _relative(prediction: np.ndarray, b: np.ndarray) -> float:
    norm = float(np.linalg.norm(b))
    if norm == 0.0:
        raise ReconInputError("a measurement is all zero: nothing to compare a prediction "
                              "with; leave that pair out")
    return float(np.linalg.norm(prediction.astype(np.float64) - b)) / norm


def predict_measurements(psf, scenes) -> list[np.ndarray]:
    """Each scene's predicted measurement ``C (x_i * P h)`` under ``psf``.

    Parameters
    ----------
    psf : array_like, (rows, cols) or (rows, cols, channels)
        Centred PSF (as ``PsfEstimate.psf``), of at most the sensor's shape.
    scenes : sequence of array_like, (rows, cols) or (rows, cols, channels)
        As for :func:`estimate_psf_from_scenes`.

    Returns
    -------
    list of ndarray, float32, (rows, cols, channels)
        One per scene (a channel axis also for 2D scenes).

    Raises
    ------
    ReconInputError
        Scenes refused by :func:`check_pairs`, or a PSF with other channels or larger
        than the sensor.
    """
    xs, _ = check_pairs(scenes, scenes)
    h = _channels(real32(psf, "PSF"))
    if h.ndim != 3 or h.shape[2] != xs[0].shape[2]:
        raise ReconInputError(f"PSF of shape {np.shape(psf)} for scenes of shape "
                              f"{np.shape(scenes[0])}: give one PSF channel per "
                              "measurement channel")
    _options(h.shape[:2], xs[0].shape[:2], 1, 1, 1.0)
    out = [np.zeros(x.shape, np.float32) for x in xs]
    for c in range(h.shape[2]):
        problem = _Problem([x[..., c] for x in xs], h.shape[:2])
        for k, o in enumerate(out):
            o[..., c] = problem.forward(h[..., c], k)
    return out


def relative_residuals(psf, scenes, measurements) -> np.ndarray:
    """Each pair's relative residual ``||C (x_i * P h) - b_i|| / ||b_i||`` under ``psf``.

    Parameters
    ----------
    psf : array_like, (rows, cols) or (rows, cols, channels)
        Centred PSF (as ``PsfEstimate.psf``), of at most the sensor's shape.
    scenes, measurements
        As for :func:`estimate_psf_from_scenes`.

    Returns
    -------
    ndarray, float64, (n_pairs, channels)

    Raises
    ------
    ReconInputError
        Pairs refused by :func:`check_pairs`, a PSF with other channels or larger than
        the sensor, or an all-zero measurement.
    """
    xs, bs = check_pairs(scenes, measurements)
    predictions = predict_measurements(psf, xs)
    return np.array([[_relative(p[..., c], b[..., c]) for c in range(b.shape[2])]
                     for p, b in zip(predictions, bs, strict=True)])


def leave_one_out(scenes, measurements, *, on_estimate=None, **options) -> LeaveOneOut:
    """Each pair's held-out relative residual: the PSF estimated from the other pairs
    (:func:`estimate_psf_from_scenes` with ``options``) predicts its measurement.

    Parameters
    ----------
    scenes, measurements
        As for :func:`estimate_psf_from_scenes`, at least two pairs.
    on_estimate : callable, optional
        ``on_estimate(k)`` after pair ``k``'s held-out PSF is estimated (progress; the
        estimates run as :func:`recon.fft.map_jobs`, so ``k`` comes in the order they
        end).
    **options
        Of :func:`estimate_psf_from_scenes` (``psf_shape``, ``iterations``,
        ``tie_channels``, ...).

    Returns
    -------
    LeaveOneOut

    Raises
    ------
    ReconInputError
        Fewer than two pairs, or what :func:`estimate_psf_from_scenes` refuses.
    """
    scenes, measurements = list(scenes), list(measurements)
    check_pairs(scenes, measurements)
    if len(scenes) < 2:
        raise ReconInputError("leave-one-out needs at least two pairs (one to estimate "
                              "the PSF from, one to score it on); give more pairs")
    done = None if on_estimate is None else (lambda k, _: on_estimate(k))
    out = map_jobs(lambda k: held_out_estimate(scenes, measurements, k, **options),
                   range(len(scenes)), on_done=done)
    return LeaveOneOut(np.array([r for _, r in out]), [h for h, _ in out])


def binned_psf_options(options: dict, factor: int) -> dict:
    """``options`` of :func:`estimate_psf_from_scenes` for the pairs binned by
    ``factor``: a ``psf_shape`` divided by it (at least 2 pixels a side).

    Parameters
    ----------
    options : dict
    factor : int
        The binning (>= 1).

    Returns
    -------
    dict
        ``options`` itself when it names no ``psf_shape``, else a copy.
    """
    if options.get("psf_shape") is None:
        return options
    return {**options, "psf_shape": tuple(max(2, int(n) // factor)
                                          for n in options["psf_shape"])}


def held_out_estimate(scenes, measurements, k: int, *, estimate=None, **options
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Pair ``k``'s entry of :func:`leave_one_out`: the PSF estimated from the other
    pairs and pair ``k``'s relative residual under it.

    Parameters
    ----------
    scenes, measurements
        As for :func:`leave_one_out` (checked there).
    k : int
        The pair held out.
    estimate : callable, optional
        ``estimate(scenes, measurements, **options) -> PsfEstimate`` in place of
        :func:`estimate_psf_from_scenes` (e.g. with a sensor response,
        :func:`recon.analysis.sensor_response.estimate_with_sensor_response`).
    **options
        Of :func:`estimate_psf_from_scenes`.

    Returns
    -------
    psf : ndarray, float32
        As ``PsfEstimate.psf``.
    residual : ndarray, float64, (channels,)

    Raises
    ------
    ReconInputError
        What :func:`estimate_psf_from_scenes` refuses.
    """
    train = [i for i in range(len(scenes)) if i != k]
    est = (estimate or estimate_psf_from_scenes)([scenes[i] for i in train],
                                                 [measurements[i] for i in train], **options)
    return est.psf, relative_residuals(est.psf, [scenes[k]], [measurements[k]])[0]
