"""A calibrated PSF grid: what :func:`recon.reconstruct` runs for a :class:`PsfGrid`.

:func:`reconstruct_psf_grid` is what ``diffuserlab recon --psf-grid`` and ``recon3d
--psf-grid`` run (through ``instrument.processing.reconstruct_grid``): bin the grid and the
raw frame alike, pick the forward model (``auto``: :func:`recon.spatial.choose_model`),
scale as the other solvers expect (central PSF of unit sum, measurement divided by
its maximum) and solve Eq. 6.2 with :func:`recon.spatial.fista_background`
(``background="estimate"``) or the same l1 FISTA without a background
(``"none"``); or (``method="admm"``, 2D, no background) TV ADMM
(:func:`recon.spatial.spatial_admm`) with the weight chosen as :func:`recon.reconstruct`
chooses it (hold-out cross-validation, :mod:`recon.auto`). ``two_part=True`` models
a far scene by Eq. 5.1's two parts: the grid's caustics (:func:`recon.spatial.caustic_grid`)
in the model, the brightness divided out of the image afterwards. ``device="cuda"``
runs the solve on a GPU through the array-API path (``recon.spatial.device``); the
model choice and ADMM's automatic weight stay on the CPU.
"""

from __future__ import annotations

import time

import numpy as np

from ..auto import AUTO, ChannelProblem, parse_weight, solve_channel
from ..backend import resolve_device
from ..errors import ReconInputError
from ..options import (  # ``--background``, ``method`` choices
    BACKGROUNDS,
    GRID_METHODS,
    ReconOptions,
    l1_given,
)
from ..preprocess import box_bin, check_raw_signal, dark_argument
from ..result import ReconInfo, Reconstruction
from ..solvers import SOLVERS, SolverSpec
from ..validate import as_int, nonneg_weight
from .admm import SpatialAdmmPlan, spatial_admm
from .background import fista_background
from .brightness import brightness_map, caustic_grid
from .choice import MODELS, ModelChoice, build_operator, choose_model, predicted_errors
from .device import BACKGROUND_PLANES, device_grid_solvers, solve_grid_on
from .grid import PsfGrid

__all__ = ["BACKGROUNDS", "GRID_METHODS", "GRID_SOLVERS", "bin_grid", "grid_dark",
           "grid_metrics", "grid_model", "reconstruct_psf_grid"]

#: The solvers that serve a spatially varying model, for :func:`recon.auto.solve_channel`.
GRID_SOLVERS = {
    "admm": SolverSpec(spatial_admm, SOLVERS["admm"].default_tv, True,
                       "ADMM, x-update linearized and preconditioned by a convolution"),
    "fista": SOLVERS["fista"],
}


def grid_metrics(rec: Reconstruction, floor_seconds: float | None = None) -> dict:
    """JSON-ready record of a grid reconstruction (:meth:`Reconstruction.metrics`): model,
    cost, timings against the FFT floor of the model's ``K`` convolutions
    (:func:`recon.volume.fft_floor_seconds`)."""
    from ..volume import fft_floor_seconds

    op, result, inf = rec.operator, rec.result, rec.info
    if floor_seconds is None:
        floor_seconds = fft_floor_seconds(op.padded_shape, op.n_kernels)
    per_it = float(np.median(result.history.seconds))
    info = {"method": inf.method, "device": inf.device, "iterations": inf.iterations,
            "iterations_used": inf.iterations_used, "bin_factor": inf.bin_factor,
            "raw_scale": inf.raw_scale, "tv": inf.tv, "l1": inf.l1,
            "dark_mode": inf.dark_mode, **inf.extra, "seconds_total": inf.seconds_total,
            "depths_mm": rec.depths_mm}
    if inf.auto:
        info["auto"] = inf.auto[0]
    return {"model": rec.choice.as_dict(), "n_kernels": int(op.n_kernels),
            "ffts_per_apply": int(op.ffts_per_apply), "shape": list(rec.image.shape),
            "padded_shape": list(op.padded_shape), **info,
            "seconds_per_iteration": per_it, "fft_floor_seconds": floor_seconds,
            "ratio_to_fft_floor": per_it / floor_seconds,
            "final_relative_residual": result.final_relative_residual,
            "objective": list(result.history.objective)}


#: Where a grid reconstruction's dark level came from, per mode (:func:`grid_dark`).
GRID_DARK_SOURCES = {
    "auto": "auto: nothing subtracted, the grid's PSFs are dark-subtracted (background "
            "'estimate' fits the frame's offset)",
    "none": "none: the frame is dark-subtracted",
    "value": "the dark value given", "frame": "the dark frame given, pixel by pixel"}


def grid_dark(dark, shape: tuple[int, int]) -> tuple[str, float | np.ndarray]:
    """``(mode, level)`` of a grid reconstruction's dark argument.

    The grid's PSFs are dark-subtracted, so the level is subtracted from the frame only;
    ``"auto"`` subtracts nothing (Eq. 6.2's background, ``background="estimate"``,
    fits the frame's offset), as ``"none"``.

    Parameters
    ----------
    dark : "auto", "none", None, float or ndarray (rows, cols)
        As :func:`recon.reconstruct`.
    shape : (rows, cols)
        The frame's shape.

    Returns
    -------
    mode : {"auto", "none", "value", "frame"}
    level : float or ndarray float32 (rows, cols)
        What to subtract (0.0 for ``"auto"`` and ``"none"``).

    Raises
    ------
    ReconInputError
        A dark argument of none of these forms.
    """
    mode, level = dark_argument(dark, shape)
    return mode, 0.0 if level is None else level


def bin_grid(grid: PsfGrid, factor: int) -> PsfGrid:
    """A grid box-binned laterally by ``factor`` (PSFs summed over blocks, shifts scaled).

    Bin the raw frame with :func:`recon.preprocess.box_bin` by the same factor.
    """
    factor = as_int(factor, "bin factor", 1)
    if factor == 1:
        return grid
    psfs = box_bin(np.moveaxis(grid.psfs, 0, -1), factor)
    return PsfGrid(np.moveaxis(psfs, -1, 0), grid.shifts_px / factor, grid.grid_shape,
                   grid.z_mm, grid.d_mm)


def grid_model(grids, *, model: str = "auto", k: int | None = None, depths_mm=None,
               bin_factor: int, support=None, tolerance: float | None = None,
               two_part: bool = False) -> tuple[ModelChoice, object]:
    """Choose the forward model of a calibrated grid and build it, once for many frames.

    The grids are binned by ``bin_factor`` (:func:`bin_grid`); ``auto`` takes
    :func:`recon.spatial.choose_model`'s choice, any other model is used as given
    (its predicted errors still reported).

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
        One grid (2D) or one per depth (3D).
    model, k, depths_mm, bin_factor, support, tolerance, two_part
        As :func:`reconstruct_psf_grid`.

    Returns
    -------
    (ModelChoice, SpatialConvolutionOperator)
        Pass them to :func:`reconstruct_psf_grid` as ``prepared`` for every frame. With
        ``two_part`` the operator's ``brightness`` holds the map the images are divided
        by (:func:`recon.spatial.brightness_map`, float32, sensor shape).

    Raises
    ------
    ReconInputError
        Unknown model, bad bin factor, ``two_part`` with several grids (a volume).
    """
    if model not in MODELS:
        raise ReconInputError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    single = isinstance(grids, PsfGrid)
    glist = [bin_grid(g, bin_factor) for g in ([grids] if single else list(grids))]
    brightness = None
    if two_part:
        if not single:
            raise ReconInputError("the two-part model (caustics in the model, brightness "
                                  "divided out) is for one far plane; reconstruct a volume "
                                  "without two_part")
        brightness = brightness_map(glist[0])
        glist = [caustic_grid(glist[0])]
    arg = glist[0] if single else glist
    if model == "auto":
        opts = {} if tolerance is None else {"tolerance": tolerance}
        support_2d = None if support is None or np.ndim(support) == 2 else np.any(support, 0)
        choice = choose_model(arg, support=support_2d, **opts)
    else:
        errors = predicted_errors(arg)
        choice = ModelChoice(model, k, 0, errors, reason="given")
    op = build_operator(arg, choice.model, k=choice.k, depths_mm=depths_mm, support=support)
    op.brightness = brightness
    choice.convolutions = op.n_kernels // (op.n_z if op.volume else 1)
    if choice.model == "pca":
        choice.k = op.components[0]
    return choice, op


def reconstruct_psf_grid(grids, raw: np.ndarray, options: ReconOptions | None = None, *,
                         depths_mm=None, support=None, tolerance: float | None = None,
                         prepared: tuple | None = None) -> Reconstruction:
    """Reconstruct an image (one grid) or a volume (several grids) from one frame.

    Parameters
    ----------
    grids : PsfGrid or list of PsfGrid
        Registered calibration grids (one: 2D; a list, one per depth: 3D).
    raw : ndarray, (rows, cols)
        The frame, same shape as the PSFs.
    options : recon.options.ReconOptions, optional
        The reconstruction's options, as :func:`recon.reconstruct` passes them; default
        the declared ones (:meth:`~diffuserlab.options.Options.from_defaults`). This
        path reads ``model`` (``"auto"``, ``"convolution"``, ``"local"``, ``"pca"``),
        ``k`` (PCA components; None: from the explained energy), ``background``
        (``"estimate"``: Eq. 6.2's joint background, or ``"none"``, which
        ``method="admm"`` needs), ``l1`` (l1 weight in the scaled problem; not given,
        the declared default :data:`recon.options.L1_DEFAULT`, or None: 1e-3 with FISTA,
        Eq. 6.2's sparse object, 0 with ADMM; ``"auto"``, ``method="admm"`` only,
        chooses it by hold-out cross-validation), ``iterations`` (FISTA's iterations;
        ADMM's maximum: it stops when the fit settles, and the automatic weight takes at
        most twice as many, :mod:`recon.auto.weight`), ``method`` (``"auto"`` is FISTA:
        the grid solver that estimates Eq. 6.2's background and serves a volume;
        ``"fista"``: FISTA on Eq. 6.2, l1, non-negativity, the optional background;
        ``"admm"``: ADMM with TV, l1 and non-negativity,
        :func:`recon.spatial.spatial_admm`, 2D, without a background, converged in a few
        hundred iterations where FISTA takes thousands), ``tv`` (TV weight of
        ``method="admm"``, scaled problem; ``"auto"`` by hold-out cross-validation, the
        record in ``info.auto``), ``two_part`` (a far scene, Eq. 5.1: model the
        caustics, each PSF over its brightness, :func:`recon.spatial.caustic_grid`, and
        divide the image by the brightness map, :func:`recon.spatial.brightness_map`;
        2D only; the kernels then carry equal light, which is also what lets ADMM's
        preconditioner fit), ``bin_factor``, ``dark`` (subtracted from the raw frame
        only, :func:`grid_dark`: the grid's PSFs are dark-subtracted; ``"auto"`` and
        ``"none"`` subtract nothing; a level or a (rows, cols) frame) and ``device``
        (:func:`recon.backend.resolve_device`: the CPU's NumPy path, or a CUDA GPU
        through the array-API path, FISTA of Eq. 6.2, ``recon.spatial.xp_background``,
        ADMM, ``recon.spatial.xp_admm``, after a check of its free memory,
        ``recon.spatial.device``; the model choice and ADMM's automatic weight run on
        the CPU; ``info.device`` says which ran).
    depths_mm : array_like, optional
        3D reconstruction depths (grids synthesised, Sec. 5.2); default the grids'.
    support : ndarray of bool, optional
        Object support on the model's object grid (after binning).
    tolerance : float, optional
        For ``auto`` (default :data:`recon.spatial.choice.DEFAULT_TOLERANCE`).
    prepared : (ModelChoice, SpatialConvolutionOperator), optional
        :func:`grid_model`'s result for these grids and ``bin_factor``, made once for
        a batch of frames (then ``model``, ``k``, ``depths_mm``, ``support`` and
        ``tolerance`` are not used).

    Returns
    -------
    Reconstruction
        ``info.kind == "grid"``; ``background`` and ``choice`` set; ``depths_mm`` for
        a volume.

    Raises
    ------
    ReconInputError
        Unknown model, background or method, a frame whose shape differs from the PSFs
        (or from the ``prepared`` model's), ``method="admm"`` with a background
        estimate or a volume, weights that are neither numbers >= 0 nor "auto"; an
        unusable ``device`` (names what is missing) or a solve that does not fit in
        its free memory (says how much it needs).
    recon.auto.NoSignalError
        ``method="admm"`` on a frame that holds only noise.
    """
    o = ReconOptions.from_defaults() if options is None else options
    model, k, background, iterations, method = (o.model, o.k, o.background, o.iterations,
                                                o.method)
    tv, bin_factor, dark, two_part = o.tv, o.bin_factor, o.dark, o.two_part
    backend = resolve_device(o.device)
    if model not in MODELS:
        raise ReconInputError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    if background not in BACKGROUNDS:
        raise ReconInputError(f"unknown background {background!r}; choose estimate or none")
    reason = "given"
    if method == AUTO:
        method, reason = "fista", ("FISTA: the grid solver that estimates Eq. 6.2's "
                                   "background and serves a volume")
    if method not in GRID_METHODS:
        raise ReconInputError(f"unknown method {method!r} for a PSF grid; choose "
                              f"{' or '.join(GRID_METHODS)}")
    iterations = as_int(iterations, "iterations", 1)
    l1 = l1_given(o.l1)  # None: not given, the method's own default
    if method == "admm":
        if background != "none":
            raise ReconInputError("the joint background of Eq. 6.2 is estimated by FISTA; with "
                                  "method 'admm' give background 'none' (subtract the dark "
                                  "frame first), or use method 'fista'")
        tv, l1 = parse_weight(tv, "tv"), parse_weight(0.0 if l1 is None else l1, "l1")
    else:
        l1 = nonneg_weight(1e-3 if l1 is None else l1, "l1")
    t0 = time.perf_counter()
    single = isinstance(grids, PsfGrid)
    glist = [grids] if single else list(grids)
    b = np.asarray(raw, np.float64)
    if b.shape != glist[0].sensor_shape:
        raise ReconInputError(f"raw frame shape {b.shape} differs from the PSF grid's "
                              f"{glist[0].sensor_shape}; pass the frame of the calibrated camera")
    dark_mode, level = grid_dark(dark, b.shape)
    b = b - level
    levels = check_raw_signal(raw, b, dark_level=level,
                              dark_source=GRID_DARK_SOURCES[dark_mode])
    b = box_bin(b, bin_factor) if bin_factor > 1 else b
    if prepared is None:
        prepared = grid_model(grids, model=model, k=k, depths_mm=depths_mm,
                              bin_factor=bin_factor, support=support, tolerance=tolerance,
                              two_part=two_part)
    choice, op = prepared
    if tuple(op.shape_out) != b.shape:
        raise ReconInputError(f"the prepared model's frames are {tuple(op.shape_out)} but the "
                              f"binned frame is {b.shape}; prepare it with the same bin factor")
    scale = float(np.max(np.abs(b)))
    if not scale > 0:
        raise ReconInputError("raw frame is zero after the dark level; check the exposure")
    info = {"background": background, "dark": float(np.mean(level)), "raw_levels": levels,
            "psf_scale": float(op.scale), "two_part": getattr(op, "brightness", None)
            is not None}
    if method == "admm":
        if op.volume:
            raise ReconInputError("ADMM serves one plane of a spatially varying model; "
                                  "reconstruct a volume with method 'fista'")
        # on a GPU the automatic weight's path runs on the CPU, the chosen weight's
        # ADMM on the GPU (as for one PSF, recon.planar)
        problem = ChannelProblem(op, (b / scale).astype(np.float32), b, scale)
        chosen = ReconOptions.from_defaults(method=AUTO, iterations=iterations, tv=tv, l1=l1,
                                            prior="tv")  # the grid's plans are TV's
        res, record = solve_channel(problem, chosen,
                                    solvers=device_grid_solvers(backend, GRID_SOLVERS),
                                    plan_of=SpatialAdmmPlan.of,
                                    final_solve=None if backend.is_numpy else iterations)
        tv, l1, auto, used = record["tv"], record["l1"], [record], record["iterations_used"]
        g = None
    else:
        options = {"iterations": iterations, "l1": l1,
                   "estimate_background": background == "estimate"}
        b_scaled = (b / scale).astype(np.float32)
        res = (fista_background(op, b_scaled, **options) if backend.is_numpy else
               solve_grid_on(backend, fista_background, op, b_scaled,
                             planes=BACKGROUND_PLANES, method="FISTA", **options))
        g = res.params["background"] * scale if background == "estimate" else None
        tv, auto, used = None, [], int(res.params.get("iterations_used", iterations))
    crop = (slice(None), *op.crop) if op.volume else op.crop
    estimate = (res.x * scale).astype(np.float32)
    image = np.ascontiguousarray(estimate[crop])
    if getattr(op, "brightness", None) is not None:
        image /= op.brightness
    info_ = ReconInfo(
        kind="grid", method=method, method_reason=reason, iterations=iterations,
        iterations_used=used, tv=tv, l1=l1, auto=auto, dark_mode=dark_mode,
        dark_level=None if dark_mode in ("auto", "none") else float(np.mean(level)),
        dark_source=GRID_DARK_SOURCES[dark_mode], bin_factor=int(bin_factor),
        raw_scale=scale, seconds_total=time.perf_counter() - t0, device=backend.label,
        histories=[res.history], extra=info)
    return Reconstruction(image, estimate, [res], op, info_,
                          depths_mm=[float(z) for z in op.depths] if op.volume else None,
                          background=g, choice=choice, record=grid_metrics)
