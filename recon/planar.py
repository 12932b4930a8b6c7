"""One PSF (2D): what :func:`recon.reconstruct` runs for a PSF array.

Preprocesses (dark level, binning, colour), scales the data so the automatic
defaults hold for any camera, builds the forward model of Eq. 3.4 (with the
erasure mask of Eq. 3.10 if asked), solves each colour channel independently
(Sec. 3.1, "Extension to Color"; an RGB image's automatic weight is chosen once, by
the green channel, :func:`shares_weight`) and crops the sensor field of view.
"""

from __future__ import annotations

import inspect
import time

import numpy as np

from diffuserlab.jsonio import jsonable

from .auto import AUTO, ChannelProblem, parse_weight, solve_channel
from .backend import resolve_device
from .early_stop import EarlyStop, named
from .errors import ReconInputError
from .fft import fft_pair_seconds
from .operators import ConvolutionOperator, PixelErasure
from .options import ReconOptions, l1_given
from .preprocess import (
    check_measured_fraction,
    check_raw_signal,
    prepare_pair,
    validate_measurement,
    validate_psf,
)
from .result import ReconInfo, Reconstruction
from .solvers import SOLVERS, SolveResult
from .solvers.device import device_metrics, device_solvers, fft_pair_seconds_on
from .validate import as_array, as_int, finite_float

#: Default TV weight per method, absolute in the scaled problem (unit-sum PSF,
#: measurement divided by its maximum); from :data:`recon.solvers.SOLVERS`.
DEFAULT_TV = {name: spec.default_tv for name, spec in SOLVERS.items()}


def image_metrics(rec: Reconstruction, fft_pair_s: float | None = None) -> dict:
    """The 2D metrics record of ``recon --metrics-json`` (:meth:`Reconstruction.metrics`).

    Parameters
    ----------
    rec : Reconstruction
        A 2D reconstruction (one PSF).
    fft_pair_s : float, optional
        FFT floor; measured now at the padded shape if not given (on the CPU; a
        reconstruction on a device measures its device's,
        ``recon.solvers.device.device_metrics``).
    """
    info, results = rec.info, rec.results
    if fft_pair_s is None:
        fft_pair_s = fft_pair_seconds(rec.operator.padded_shape)
    per_iter = [s for r in results for s in r.history.seconds]
    med = float(np.median(per_iter))
    return {
        "method": info.method,
        "device": info.device,
        "iterations": info.iterations,
        "iterations_used": info.iterations_used,
        "tv": info.tv,
        "l1": info.l1,
        "auto": list(info.auto),
        # the image prior: TV unless asked (a method without one, Wiener: None)
        "prior": info.get("prior", "tv"),
        "shape": list(rec.image.shape),
        "padded_shape": list(rec.operator.padded_shape),
        "channels": len(results),
        "bin_factor": info.bin_factor,
        "erased_fraction": info["erased_fraction"],
        "seconds_total": info.seconds_total,
        "seconds_per_iteration": med,
        "fft_pair_seconds": fft_pair_s,
        "ratio_to_fft_floor": med / fft_pair_s,
        "final_relative_residual": max(r.final_relative_residual for r in results),
        "final_objective": [r.final_objective for r in results],
        "objective": [list(r.history.objective) for r in results],
        "data_residual": [list(r.history.data_residual) for r in results],
        "params": [jsonable(r.params) for r in results],
        # the dark level and where it came from, and the raw's own levels (a lensless
        # raw has no dark region: its floor only bounds its dark level from above)
        "dark": {"mode": info.dark_mode, "level": info.dark_level,
                 "region": info.get("dark_region"), "raw_levels": info.get("raw_levels")},
        # a scene calibration's recipe (recon.early_stop), when it made the image
        "calibration": info.get("calibration"),
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
                 if n not in ("iterations", "tv", "prior") and p.kind is not p.VAR_KEYWORD)


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


#: The channel of an RGB image whose hold-out weight path chooses the automatic weight
#: of every channel (:func:`shares_weight`): green, the middle of the visible band
#: and of a Bayer sensor's samples.
LEAD_CHANNEL = 1
#: The share of ``iterations`` each channel's solve at the shared weight may run
#: (:func:`shared_final_iterations`; the lead's path is sized by all of them). On the
#: five real pairs of ``shared/data/mirflickr-real`` with file PSFs, finals capped at
#: 100, 130 and 200 of 200 gave 15.83 / 0.397, 15.95 / 0.403 and 15.94 / 0.404 mean
#: PSNR / SSIM, and the whole default at 100 took 0.95x LenslessPiCam's CPU time for its
#: 100 iterations (1.27x at 200; docs/real-data.md): the issue's budget is that time.
SHARED_FINAL_SHARE = 0.5


def shares_weight(channels: int, options: ReconOptions) -> bool:
    """Whether an image of ``channels`` channels solved with ``options`` takes one
    automatic weight for every channel, chosen by :data:`LEAD_CHANNEL`'s path.

    An RGB image (3 channels) with an automatic TV weight (``tv`` ``"auto"``, ``l1``
    not automatic, one prior named, not ``"auto"``) does: the lead channel runs the
    hold-out path (:func:`recon.auto.weight.admm_auto`) to choose the weight only, then
    solves afresh on all pixels at it (``final_solve``), and the other
    channels solve at the same weight (each solve, with method ``"auto"``, at most
    :func:`shared_final_iterations`), as one colour image is one scene (LenslessPiCam
    and Kuo 2020, Sec. 3.1, give every channel one weight too). Measured on the five
    real pairs of ``shared/data/mirflickr-real`` with file PSFs (each pair's
    leave-one-out estimate), against a path per channel keeping its fit-pixel iterate:
    15.94 / 0.404 against 15.74 / 0.398 mean PSNR / SSIM, in 61-88 % of the CPU time
    (docs/real-data.md). Any other image: each channel its own choice, as before.

    Parameters
    ----------
    channels : int
        The image's colour channels (1 for a grey image).
    options : ReconOptions
        The options as :func:`reconstruct_image` checked them (weights parsed).

    Returns
    -------
    bool
    """
    return (channels == 3 and options.tv == AUTO and options.l1 != AUTO
            and options.prior != AUTO)


def shared_final_iterations(iterations: int) -> int:
    """The most iterations of each channel's solve at the weight that
    :data:`LEAD_CHANNEL`'s path chose (:func:`shares_weight`): :data:`SHARED_FINAL_SHARE`
    of ``iterations``, which sizes the path (at least 1).

    Parameters
    ----------
    iterations : int
        The reconstruction's ``iterations`` (>= 1).

    Returns
    -------
    int
    """
    return max(1, round(SHARED_FINAL_SHARE * int(iterations)))


def shared_weight_record(chosen: dict) -> dict:
    """The ``weight`` record of a channel that took :data:`LEAD_CHANNEL`'s automatic
    weight: the lead's regulariser and weight, ``criterion`` ``"shared"``, and a
    ``reason`` that says whose path chose it and why (the lead's own reason).

    Parameters
    ----------
    chosen : dict
        The lead channel's ``weight`` record (``recon.auto.weight.AutoWeight.as_dict``).

    Returns
    -------
    dict
        JSON-ready: ``regulariser``, ``weight`` (float, scaled problem), ``criterion``,
        ``lead_channel``, ``final_iterations`` (each channel's most, or None),
        ``reason``.
    """
    return {"regulariser": chosen.get("regulariser", "tv"), "weight": chosen["weight"],
            "criterion": "shared", "lead_channel": LEAD_CHANNEL,
            "final_iterations": chosen.get("final_iterations"),
            "reason": f"chosen for every channel by channel {LEAD_CHANNEL}'s (green's) "
                      f"path: {chosen.get('reason', '')}"}


def reconstruct_image(psf: np.ndarray, raw: np.ndarray, options: ReconOptions | None = None, *,
                      auto_stop: bool = True, bayer=None,
                      erasure_mask: np.ndarray | None = None, preprocess: bool = True,
                      **solver_options) -> Reconstruction:
    """Reconstruct an image from one PSF: :func:`recon.reconstruct` for a PSF array.

    Parameters
    ----------
    psf : ndarray, (rows, cols) or (rows, cols, C), any real dtype
        Calibration PSF (image of a point source), same spatial shape as ``raw``.
        One PSF for all channels, or one per channel.
    raw : ndarray, (rows, cols) or (rows, cols, C)
        Raw measurement (sensor counts).
    options : recon.options.ReconOptions, optional
        The reconstruction's options, as :func:`recon.reconstruct` passes them
        (checked there; ``dark`` then ``"auto"``, ``"none"``, a number or an array);
        default the declared ones (:meth:`~diffuserlab.options.Options.from_defaults`).
        This path reads ``method``, ``iterations``, ``tv``, ``l1``, ``bin_factor``,
        ``dark``, ``allow_mixed_ranges``, ``device``, ``prior``, ``seconds`` (the time
        budget of each channel's solve, for ``method="auto"``: Wiener when it affords
        too few iterations), ``erase`` (the fraction of sensor pixels erased at
        random, compressed sensing, Eq. 3.10), ``seed`` (of that mask) and
        ``full_scale``.
    auto_stop : bool
        Automatic stopping of a fixed-weight solve (default); False runs exactly
        ``iterations`` (the automatic weight always stops by itself).
    bayer : str, optional
        Bayer pattern of a raw mosaic (:func:`recon.preprocess.prepare_pair`).
    erasure_mask : ndarray, optional
        Explicit mask at the binned sensor shape (1 measured, 0 erased); overrides
        ``erase``.
    preprocess : bool
        False when psf and raw are already dark-subtracted float arrays of equal
        shape (``dark`` and ``bin_factor`` then unused); they are still checked like
        :func:`recon.preprocess.validate_psf` and
        :func:`recon.preprocess.validate_measurement` do.
    **solver_options
        Passed to the solver (e.g. ``step_scale``, ``penalty``, ``regularization``);
        :func:`solver_options` lists what a method takes.

    Returns
    -------
    Reconstruction
        ``info.kind == "image"``; one result per colour channel.

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
    o = ReconOptions.from_defaults() if options is None else options
    if named(o.early_stop):  # the recipe fixes the solve
        fit = EarlyStop.load(o.early_stop)
        # a numeric dark (level, per channel or frame) is on the recipe's PSF as well
        recipe_psf = fit.clean_psf(psf, o.dark if preprocess else None)
        rec = reconstruct_image(recipe_psf, raw, early_stopped_options(o, fit),
                                auto_stop=False, bayer=bayer, erasure_mask=erasure_mask,
                                preprocess=preprocess, **solver_options)
        return fit.finish(rec)
    method, tv, bin_factor, dark = o.method, o.tv, o.bin_factor, o.dark
    full_scale = o.full_scale
    l1 = l1_given(o.l1)
    if method != AUTO and method not in SOLVERS:
        raise ReconInputError(f"unknown method {method!r}; choose one of auto, "
                              f"{', '.join(SOLVERS)}")
    iterations = as_int(o.iterations, "iterations", 1)
    bin_factor = as_int(bin_factor, "bin_factor", 1)
    seed = as_int(o.seed, "seed", 0)
    erase = finite_float(o.erase, "erase")
    if not 0.0 <= erase < 1.0:  # the message of PixelErasure.random
        raise ReconInputError(f"erased fraction {erase} is outside [0, 1); use e.g. 0.8 to "
                              "erase 80 % of the pixels")
    check_measured_fraction(erase)
    tv, l1 = parse_weight(tv, "tv"), parse_weight(0.0 if l1 is None else l1, "l1")
    if method == AUTO and solver_options:
        raise ReconInputError(f"method 'auto' takes no solver options ({', '.join(solver_options)}"
                              "); name a method to pass them")
    if method != AUTO:
        check_options(method, solver_options)
    backend = resolve_device(o.device)
    on_device = ({} if backend.is_numpy else
                 {"solvers": device_solvers(backend), "backend": backend})
    fft_s = None
    t_start = time.perf_counter()
    if preprocess:
        prepared = prepare_pair(  # its dark=None is the estimate from the PSF's corner
            psf, raw, bin_factor=bin_factor, dark=None if _is(dark, "auto") else dark,
            bayer=bayer, full_scale=full_scale,
            allow_mixed_ranges=o.allow_mixed_ranges,
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
    # the options as checked here (the weights parsed), what each channel's solve reads
    solved = o.replace(method=method, iterations=iterations, tv=tv, l1=l1)
    solves: dict[int, tuple] = {}

    def solve_one(c: int, opts: ReconOptions, **keywords) -> tuple:
        nonlocal fft_s
        pc = p if p.ndim == 2 else p[..., c]
        bc = b if b.ndim == 2 else b[..., c]
        op, scaled = scaled_problem(pc, bc, None if mask is None else mask.mask,
                                    b_scale=raw_scale)
        if o.seconds is not None and fft_s is None:  # the budget's unit, measured now
            fft_s = fft_pair_seconds_on(backend, op.padded_shape)
        res, record = solve_channel(ChannelProblem(op, scaled, bc, raw_scale), opts,
                                    fft_pair_s=fft_s, auto_stop=auto_stop, **on_device,
                                    **solver_options, **keywords)
        return op, res, record

    others, shared_record = solved, None
    if shares_weight(channels, solved):  # the lead channel's path chooses for all
        # the default (method auto) takes the share; a method named keeps its count
        final = shared_final_iterations(iterations) if method == AUTO else iterations
        solves[LEAD_CHANNEL] = solve_one(LEAD_CHANNEL, solved, final_solve=final)
        lead = solves[LEAD_CHANNEL][2]
        if lead.get("weight") is not None:  # its method had a weight to choose (not Wiener)
            others = solved.replace(tv=lead["tv"], iterations=final)
            lead["weight"]["final_iterations"] = final
            shared_record = shared_weight_record(lead["weight"])
    for c in range(channels):
        if c not in solves:
            solves[c] = solve_one(c, others)
            if shared_record is not None:
                solves[c][2]["weight"] = dict(shared_record)
    results, estimates, op0, records = [], [], None, []
    for c in range(channels):
        op, res, record = solves[c]
        results.append(res)
        records.append(record)
        estimates.append(res.x * raw_scale)
        op0 = op0 or op
    estimate = estimates[0] if channels == 1 else np.stack(estimates, axis=-1)
    image = np.ascontiguousarray(estimate[op0.crop])
    chosen = records[0].get("method", {}).get("method", method)
    reason = ("given" if method != AUTO
              else "; ".join(records[0].get("method", {}).get("reasons", [])) or "auto")
    if not preprocess:
        info.update(dark_mode="none", dark_level=None)
    dark_mode = info.pop("dark_mode", None)
    info_ = ReconInfo(
        kind="image", method=chosen, method_reason=reason,
        iterations=iterations if SOLVERS[chosen].iterative else 1,
        iterations_used=max(r["iterations_used"] for r in records),
        tv=records[0]["tv"], l1=records[0]["l1"], auto=records,
        dark_mode=dark_mode, dark_level=info.pop("dark_level", None),
        dark_source=_DARK_SOURCES.get(dark_mode, "the dark value given"),
        bin_factor=bin_factor, raw_scale=raw_scale,
        seconds_total=time.perf_counter() - t_start, device=backend.label,
        histories=[r.history for r in results],
        extra={**info, "erased_fraction": 0.0 if mask is None
               else float(1 - op0.sensor_weights.mean()),
               "prior": records[0].get("prior", {}).get("prior", "tv")
               if SOLVERS[chosen].iterative else None})
    return Reconstruction(image.astype(np.float32), estimate.astype(np.float32), results, op0,
                          info_, record=image_metrics if backend.is_numpy
                          else device_metrics(image_metrics, backend))


#: :func:`recon.preprocess.prepare_pair`'s dark modes in words (``ReconInfo.dark_source``).
_DARK_SOURCES = {"psf_region": "the PSF's dark corner (recon.preprocess.DEFAULT_DARK_REGION)",
                 "none": "none: the inputs are dark-subtracted",
                 "scalar": "the dark value given", "vector": "the per-channel values given",
                 "frame": "the dark frame given, pixel by pixel"}


def early_stopped_options(options: ReconOptions, fit) -> ReconOptions:
    """``options`` for the solve of a scene calibration's recipe (:mod:`recon.early_stop`):
    non-negative FISTA, no TV or l1, the fitted iteration count, no recipe named.

    Parameters
    ----------
    options : ReconOptions
    fit : recon.early_stop.EarlyStop

    Returns
    -------
    ReconOptions
    """
    return options.replace(method="fista", iterations=fit.iterations, tv=0.0, l1=0.0,
                           early_stop=None)


def _is(value, word: str) -> bool:
    return isinstance(value, str) and value == word
