"""The notebook API: ``recon.reconstruct(psf, raw, method="admm", iterations=100)``.

Preprocesses (dark level, binning, colour), scales the data so the automatic
defaults hold for any camera, builds the forward model of Eq. 3.4 (with the
erasure mask of Eq. 3.10 if asked), solves each colour channel independently
(Sec. 3.1, "Extension to Color") and crops the sensor field of view.
"""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass, field

import numpy as np

from diffuserlab.jsonio import jsonable

from .auto import AUTO, parse_weight, solve_channel
from .backend import resolve_device
from .errors import ReconInputError
from .fft import fft_pair_seconds
from .operators import ConvolutionOperator, PixelErasure
from .preprocess import (
    check_measured_fraction,
    check_raw_signal,
    prepare_pair,
    validate_measurement,
    validate_psf,
)
from .solvers import SOLVERS, SolveResult
from .solvers.device import device_solvers
from .validate import as_array, as_int, finite_float

#: Default TV weight per method, absolute in the scaled problem (unit-sum PSF,
#: measurement divided by its maximum); from :data:`recon.solvers.SOLVERS`.
DEFAULT_TV = {name: spec.default_tv for name, spec in SOLVERS.items()}


@dataclass
class Reconstruction:
    """Result of :func:`reconstruct`.

    Attributes
    ----------
    image : ndarray, float32, shape (rows, cols) or (rows, cols, C)
        The sensor field of view of the estimate, in measurement units (counts per
        unit PSF sum), non-negative for the iterative methods.
    estimate : ndarray, float32, shape (P0, P1) or (P0, P1, C)
        The whole object domain (twice the sensor, Sec. 3.1), same units.
    results : list of SolveResult
        One per channel (histories, parameters).
    operator : ConvolutionOperator
        The forward model of the first channel (with erasure weights if any).
    info : dict
        Preprocessing record, scale factors, method, timings.
    """

    image: np.ndarray
    estimate: np.ndarray
    results: list[SolveResult]
    operator: ConvolutionOperator
    info: dict = field(default_factory=dict)

    def metrics(self, fft_pair_s: float | None = None) -> dict:
        """The metrics record of the CLI's ``--metrics-json`` (see README).

        Parameters
        ----------
        fft_pair_s : float, optional
            FFT floor; measured now at the padded shape if not given.
        """
        if fft_pair_s is None:
            fft_pair_s = fft_pair_seconds(self.operator.padded_shape)
        per_iter = [s for r in self.results for s in r.history.seconds]
        med = float(np.median(per_iter))
        return {
            "method": self.info["method"],
            "device": self.info.get("device", "cpu (numpy)"),
            "iterations": self.info["iterations"],
            "iterations_used": self.info.get("iterations_used", self.info["iterations"]),
            "tv": self.info["tv"],
            "l1": self.info.get("l1", 0.0),
            "auto": self.info.get("auto", []),
            "shape": list(self.image.shape),
            "padded_shape": list(self.operator.padded_shape),
            "channels": len(self.results),
            "bin_factor": self.info["bin_factor"],
            "erased_fraction": self.info["erased_fraction"],
            "seconds_total": self.info["seconds_total"],
            "seconds_per_iteration": med,
            "fft_pair_seconds": fft_pair_s,
            "ratio_to_fft_floor": med / fft_pair_s,
            "final_relative_residual": max(r.final_relative_residual for r in self.results),
            "final_objective": [r.final_objective for r in self.results],
            "objective": [list(r.history.objective) for r in self.results],
            "data_residual": [list(r.history.data_residual) for r in self.results],
            "params": [jsonable(r.params) for r in self.results],
            # the dark level and where it came from, and the raw's own levels (a lensless
            # raw has no dark region: its floor only bounds its dark level from above)
            "dark": {"mode": self.info.get("dark_mode"), "level": self.info.get("dark_level"),
                     "region": self.info.get("dark_region"),
                     "raw_levels": self.info.get("raw_levels")},
        }


def scaled_problem(psf: np.ndarray, b: np.ndarray, weights: np.ndarray | None = None, *,
                   b_scale: float | None = None) -> tuple[ConvolutionOperator, np.ndarray]:
    """Forward model and measurement in the solvers' scaling convention.

    The PSF is normalised to unit sum (so |H| <= 1 and the Lipschitz constant is
    at most 1) and the weighted measurement divided by ``b_scale`` (default its
    largest absolute value), so step sizes, penalties and TV weights are the same
    for any camera's numbers.

    Parameters
    ----------
    psf : ndarray, (rows, cols)
        Non-negative PSF with positive sum.
    b : ndarray, (rows, cols)
        Measurement, same shape.
    weights : ndarray, (rows, cols), optional
        Sensor weights / erasure mask (Eq. 3.10); b is multiplied by them.
    b_scale : float, optional
        Common scale, e.g. shared by the colour channels of one image.

    Returns
    -------
    op : ConvolutionOperator
    b_scaled : ndarray, float32

    Raises
    ------
    ReconInputError
        PSF without positive energy, or a measurement that is zero after weighting.
    """
    h = np.asarray(psf, np.float64)
    total = float(h.sum())
    if not total > 0:
        raise ReconInputError("PSF has no positive energy; check the dark subtraction")
    op = ConvolutionOperator((h / total).astype(np.float32), sensor_weights=weights)
    bw = op.sensor_weights * np.asarray(b, np.float64)
    scale = float(np.max(np.abs(bw))) if b_scale is None else float(b_scale)
    if not scale > 0:
        raise ReconInputError(
            "measurement is zero after dark subtraction and weighting; check the exposure"
        )
    return op, (bw / scale).astype(np.float32)


def solver_options(method: str) -> tuple[str, ...]:
    """The keyword options of a method's solver beyond ``iterations`` and ``tv``.

    Parameters
    ----------
    method : str
        A key of :data:`recon.solvers.SOLVERS`.

    Returns
    -------
    tuple of str
        Option names in signature order (e.g. ``("regularization",)`` for Wiener).
    """
    params = inspect.signature(SOLVERS[method].solve).parameters
    return tuple(n for n, p in list(params.items())[2:]
                 if n not in ("iterations", "tv") and p.kind is not p.VAR_KEYWORD)


def check_options(method: str, options: dict) -> None:
    """Refuse solver options the method does not take (before any work).

    Raises
    ------
    ReconInputError
        One line naming the unknown options and those the method accepts.
    """
    known = solver_options(method)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ReconInputError(
            f"method {method!r} takes no option {', '.join(map(repr, unknown))}; its options "
            f"are {', '.join(known) or 'none'}")


def solve(
    op: ConvolutionOperator, b: np.ndarray, method: str, *, iterations: int, tv: float,
    **options
) -> SolveResult:
    """Dispatch to one solver of :data:`recon.solvers.SOLVERS` by name.

    A direct solver (Wiener) ignores ``iterations`` and ``tv``.

    Raises
    ------
    ReconInputError
        Unknown method, or an option the method does not take.
    """
    spec = SOLVERS.get(method)
    if spec is None:
        raise ReconInputError(f"unknown method {method!r}; choose one of {', '.join(SOLVERS)}")
    check_options(method, options)
    if not spec.iterative:
        return spec.solve(op, b, **options)
    return spec.solve(op, b, iterations=iterations, tv=tv, **options)


def reconstruct(
    psf: np.ndarray,
    raw: np.ndarray,
    method: str = "auto",
    *,
    iterations: int = 200,
    tv: float | str | None = "auto",
    l1: float | str = 0.0,
    seconds: float | None = None,
    auto_stop: bool = True,
    bin_factor: int = 1,
    dark=None,
    bayer=None,
    erase: float = 0.0,
    erasure_mask: np.ndarray | None = None,
    seed: int = 0,
    preprocess: bool = True,
    full_scale: float | None = None,
    allow_mixed_ranges: bool = False,
    device: str = "cpu",
    **solver_options,
) -> Reconstruction:
    """Reconstruct an image from a DiffuserCam measurement and its PSF.

    Parameters
    ----------
    psf : ndarray, (rows, cols) or (rows, cols, C), any real dtype
        Calibration PSF (image of a point source), same spatial shape as ``raw``.
        One PSF for all channels, or one per channel.
    raw : ndarray, (rows, cols) or (rows, cols, C)
        Raw measurement (sensor counts).
    method : {"auto", "wiener", "gd", "fista", "admm"}
        ``"auto"`` (default) chooses by :mod:`recon.auto.choice` and says why in
        ``info["auto"]``.
    iterations : int
        Maximum iterations of the iterative methods (ignored by Wiener): they stop
        earlier when the fit changes by less than the noise can explain
        (:class:`recon.auto.Stopping`); ``info["iterations_used"]`` says how many ran.
    tv : "auto" or float
        TV weight in the scaled problem; ``"auto"`` (default; ``None`` too) chooses it
        by hold-out cross-validation (:mod:`recon.auto.weight`), a number fixes it
        (:data:`DEFAULT_TV` holds the former fixed defaults).
    l1 : "auto" or float
        l1 weight (sparse scenes; ADMM, FISTA, GD); default 0.
    seconds : float, optional
        Time budget of each channel's solve, for ``method="auto"`` (Wiener when it
        affords too few iterations).
    auto_stop : bool
        Automatic stopping of a fixed-weight solve (default); False runs exactly
        ``iterations`` (the automatic weight always stops by itself).
    bin_factor : int
        Box binning before reconstruction (4 gives the tutorial's 300 x 400).
    dark, bayer
        Passed to :func:`recon.preprocess.prepare_pair` (dark level from the PSF
        corner by default; Bayer pattern for a raw mosaic).
    erase : float
        Fraction of sensor pixels to erase at random (compressed sensing, Eq. 3.10).
    erasure_mask : ndarray, optional
        Explicit mask at the binned sensor shape (1 measured, 0 erased); overrides
        ``erase``.
    seed : int
        Seed of the random erasure mask.
    full_scale : float, optional
        Saturation level of the input when below the dtype maximum (e.g. 65520 for
        12-bit data shifted into uint16); used for the saturation warning.
    allow_mixed_ranges : bool
        Accept a PSF and raw whose bit depths or ranges cannot belong to one camera
        (:func:`recon.preprocess.check_pair_ranges`).
    device : {"cpu", "cuda", "auto"}
        Where the iterative solvers run (:func:`recon.backend.resolve_device`): the
        CPU's NumPy path (default), a CUDA GPU through CuPy or PyTorch (the array-API
        path, :mod:`recon.solvers.device`; an automatic weight is chosen along its ADMM path on the
        CPU, then the chosen method solves on the GPU), or the GPU when one is usable.
        ``info["device"]`` says which ran.
    preprocess : bool
        False when psf and raw are already dark-subtracted float arrays of equal
        shape (binning still applies through prepare_pair when True only); they are
        still checked like :func:`recon.preprocess.validate_psf` and
        :func:`recon.preprocess.validate_measurement` do.
    **solver_options
        Passed to the solver (e.g. ``step_scale``, ``mu``, ``balance``,
        ``regularization``); :func:`solver_options` lists what a method takes.

    Returns
    -------
    Reconstruction

    Raises
    ------
    ReconInputError
        Bad input (see :mod:`recon.preprocess`) or parameters: ``iterations`` and
        ``bin_factor`` not integers >= 1, ``seed`` not an integer >= 0, ``erase`` not
        in [0, 1) or keeping fewer than 1 % of the pixels, ``tv`` not a finite number
        >= 0 (the messages the CLI shows), or a solver option the method does not take;
        a raw with nothing to reconstruct after its dark level
        (:class:`recon.preprocess.RawSignalError`); an unusable ``device`` (names what
        is missing) or a problem that does not fit in the GPU's free memory.
    DivergenceError
        The solver diverged (history and last good estimate attached).
    """
    if method != AUTO and method not in SOLVERS:
        raise ReconInputError(f"unknown method {method!r}; choose one of auto, "
                              f"{', '.join(SOLVERS)}")
    iterations = as_int(iterations, "iterations", 1)
    bin_factor = as_int(bin_factor, "bin_factor", 1)
    seed = as_int(seed, "seed", 0)
    erase = finite_float(erase, "erase")
    if not 0.0 <= erase < 1.0:  # the message of PixelErasure.random
        raise ReconInputError(f"erased fraction {erase} is outside [0, 1); use e.g. 0.8 to "
                              "erase 80 % of the pixels")
    check_measured_fraction(erase)
    tv, l1 = parse_weight(tv, "tv"), parse_weight(l1, "l1")
    if method == AUTO and solver_options:
        raise ReconInputError(f"method 'auto' takes no solver options ({', '.join(solver_options)}"
                              "); name a method to pass them")
    if method != AUTO:
        check_options(method, solver_options)
    backend = resolve_device(device)
    on_device = ({} if backend.is_numpy else
                 {"solvers": device_solvers(backend), "weight_path_solves": False})
    fft_s = None
    t_start = time.perf_counter()
    if preprocess:
        prepared = prepare_pair(
            psf, raw, bin_factor=bin_factor, dark=dark, bayer=bayer, full_scale=full_scale,
            allow_mixed_ranges=allow_mixed_ranges,
        )
        p, b, info = prepared.psf, prepared.raw, dict(prepared.info)
    else:
        p, b = as_array(psf, "PSF"), as_array(raw, "measurement")
        validate_psf(p)
        validate_measurement(b)
        if p.shape[:2] != b.shape[:2] or (p.ndim == 3 and p.shape != b.shape):
            raise ReconInputError(
                f"PSF shape {p.shape} and raw shape {b.shape} differ; pass equal (rows, cols) "
                "and, for a colour PSF, the same channels")
        levels = check_raw_signal(b, b, dark_level=None,
                                  dark_source="preprocess=False: nothing subtracted",
                                  full_scale=full_scale)
        p, b, info = p.astype(np.float32), b.astype(np.float32), {"raw_levels": levels}
    channels = 1 if b.ndim == 2 else b.shape[2]
    sensor_shape = b.shape[:2]
    if erasure_mask is not None:
        mask = PixelErasure(erasure_mask)
        check_measured_fraction(mask.mask)
        mask.check_shape(sensor_shape, "(binned) sensor")
    elif erase > 0:
        mask = PixelErasure.random(sensor_shape, erase, seed)
    else:
        mask = None
    raw_scale = float(np.max(np.abs(b)))
    if not raw_scale > 0:
        raise ReconInputError("measurement is zero after dark subtraction; check the exposure")
    results, estimates, op0, records = [], [], None, []
    for c in range(channels):
        pc = p if p.ndim == 2 else p[..., c]
        bc = b if b.ndim == 2 else b[..., c]
        op, scaled = scaled_problem(pc, bc, None if mask is None else mask.mask,
                                    b_scale=raw_scale)
        if seconds is not None and fft_s is None:
            fft_s = fft_pair_seconds(op.padded_shape)  # the budget's unit, measured now
        res, record = solve_channel(op, scaled, bc, raw_scale, method=method,
                                    iterations=iterations, tv=tv, l1=l1, seconds=seconds,
                                    fft_pair_s=fft_s, auto_stop=auto_stop,
                                    **on_device, **solver_options)
        results.append(res)
        records.append(record)
        estimates.append(res.x * raw_scale)
        op0 = op0 or op
    estimate = estimates[0] if channels == 1 else np.stack(estimates, axis=-1)
    image = np.ascontiguousarray(estimate[op0.crop])
    chosen = records[0].get("method", {}).get("method", method)
    info.update(
        method=chosen,
        iterations=iterations if SOLVERS[chosen].iterative else 1,
        iterations_used=max(r["iterations_used"] for r in records),
        tv=records[0]["tv"],
        l1=records[0]["l1"],
        auto=records,
        bin_factor=bin_factor,
        raw_scale=raw_scale,
        erased_fraction=0.0 if mask is None else float(1 - op0.sensor_weights.mean()),
        seconds_total=time.perf_counter() - t_start,
        device=backend.label,
    )
    return Reconstruction(image.astype(np.float32), estimate.astype(np.float32), results, op0, info)
