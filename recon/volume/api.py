"""A PSF stack (3D): what :func:`recon.reconstruct` runs for a :class:`recon.PsfStack`.

The volume counterpart of the 2D path (Kuo 2020, Ch. 4): sorts the
PSF stack by depth, subtracts the dark level, bins laterally, scales the problem
like the 2D API (:func:`recon.api.scaled_problem`: stack normalised by
:func:`recon.volume.normalize_psf_stack`, measurement divided by its largest
magnitude), builds the forward model of Eq. 4.4
(:class:`recon.volume.VolumeConvolutionOperator`) and solves it with 3D FISTA or 3D
ADMM (Eq. 4.5). ``diffuserlab recon3d`` is this plus reading and writing files.
The result is the one :class:`recon.result.Reconstruction` (``info.kind ==
"volume"``).
"""

from __future__ import annotations

import logging
import math
import numbers
import time

import numpy as np

from ..auto import AUTO, parse_weight
from ..auto.noise import NoiseModel, estimate_noise
from ..auto.volume import EMPTY_PLANES, auto_volume
from ..backend import resolve_device
from ..errors import ReconInputError
from ..options import ReconOptions, l1_given
from ..preprocess import (
    box_bin,
    check_pair_ranges,
    check_raw_signal,
    dark_argument,
    dark_level,
    saturation_fraction,
    subtract_dark,
    validate_measurement,
    validate_psf,
)
from ..priors import prior_of
from ..result import ReconInfo, Reconstruction
from ..solvers.device import check_device_memory, device_metrics, solve_on
from ..validate import as_array, float_array
from .admm import VolumeAdmmPlan, admm3d
from .fista import fista3d
from .memory_plan import memory_plan, process_baseline_bytes, solve_streamed
from .operator import (
    VolumeConvolutionOperator,
    bin_stack,
    fft_floor_seconds,
    normalize_psf_stack,
)
from .streamed import streamed_fft_floor_seconds
from .xp_admm3d import XpVolumeAdmmPlan, auto3d_extra_bytes
from .xp_admm3d import memory_bytes as admm3d_memory
from .xp_fista3d import memory_bytes as fista3d_memory

__all__ = ["DEFAULT_TV", "METHODS", "SATURATION_WARN", "SOLVERS", "check_volume_parameters",
           "depth_profile", "prepare_volume_problem", "reconstruct_stack", "volume_metrics"]

log = logging.getLogger(__name__)

#: Default 3D TV weight per method (as :data:`recon.api.DEFAULT_TV` in 2D) of
#: a fixed-weight 3D solve (``recon3d --tv`` a number), absolute in the scaled
#: problem (stack normalised by :func:`normalize_psf_stack`, measurement divided by
#: its maximum).
#: Chosen with the 3D accuracy benchmark (``benchmarks.volume_accuracy``:
#: tilted target on the virtual bench, 16 planes of 128 x 160, 200 iterations, SNR
#: 35 dB): with ADMM, TV 1e-4 came out 1.4 dB below the best weight (1e-6; none
#: equal), keeping 1.1 of the best's 2.5 dB over the zero volume; 1e-5 came out
#: 0.4 dB below the best; FISTA changes by
#: < 0.1 dB up to 1e-4, and beads are localised as well at 1e-5. A one-off check on
#: the same render with 500 and 100 peak photons (SNR 25 and 17 dB) kept 1e-5
#: within 0.3 and 0.1 dB of the best weight there, 1e-4 0.6-1.5 dB below.
DEFAULT_TV = {"admm": 1e-5, "fista": 1e-5}

#: The 3D solvers by method name (as :data:`recon.solvers.SOLVERS` in 2D); a new
#: one is added here (``solve(op, b, *, iterations, tv, l1, nonneg)``) and in
#: :data:`DEFAULT_TV`.
SOLVERS = {"admm": admm3d, "fista": fista3d}

#: Solvers of ``method``.
METHODS = tuple(SOLVERS)

#: Saturated fraction of the raw image above which a warning is logged.
SATURATION_WARN = 0.001


def volume_metrics(rec: Reconstruction, fft_floor_s: float | None = None) -> dict:
    """The solver part of ``recon3d``'s metrics record (:meth:`Reconstruction.metrics`).

    Parameters
    ----------
    rec : Reconstruction
        A volume reconstruction (a PSF stack).
    fft_floor_s : float, optional
        Seconds of the FFTs one iteration needs at least
        (:func:`recon.volume.fft_floor_seconds`); measured now if not given (on the
        CPU; a reconstruction on a device measures its device's,
        ``recon.solvers.device.device_metrics``).

    Returns
    -------
    dict
        method, iterations, tv, l1, shapes, depths, preprocessing, scales,
        times (total, median per iteration), the FFT floor and the ratio to it,
        where the volume puts its light (:func:`depth_profile`: ``plane_energy``,
        ``plane_peak``, ``depth_profile``), final relative residual and
        objective, the objective and data residual histories and the solver
        parameters; ``auto`` (the automatic weight's record) when the weight was
        chosen.
    """
    op, result, inf = rec.operator, rec.result, rec.info
    if fft_floor_s is None:
        fft_floor_s = (streamed_fft_floor_seconds(op.padded_shape, op.n_z)
                       if getattr(op, "streamed", False)
                       else fft_floor_seconds(op.padded_shape, op.n_z))
    per_iter = float(np.median(result.history.seconds))
    info = {"dark_mode": inf.dark_mode, "dark_level": inf.dark_level,
            "bin_factor": inf.bin_factor, **inf.extra}
    if inf.auto:
        info["auto"] = inf.auto[0]
    scales = {"psf_scale": info.pop("psf_scale"), "raw_scale": inf.raw_scale}
    return {
        "method": inf.method, "device": inf.device, "iterations": inf.iterations,
        "iterations_used": inf.iterations_used, "tv": inf.tv, "l1": inf.l1,
        "prior": inf.get("prior"),
        "shape": list(rec.image.shape),
        "sensor_shape": list(op.sensor_shape),
        "padded_shape": list(op.padded_shape),
        "n_planes": op.n_z,
        "depths_mm": list(rec.depths_mm),
        **info,
        **scales,
        "seconds_total": inf.seconds_total,
        "seconds_per_iteration": per_iter,
        "fft_floor_seconds": fft_floor_s,
        "fft_floor_transforms": f"{op.n_z + 1} rfft2 + {op.n_z + 1} irfft2 at "
                                f"{op.padded_shape[0]}x{op.padded_shape[1]}",
        "ratio_to_fft_floor": per_iter / fft_floor_s,
        **depth_profile(rec.image, rec.depths_mm),
        "final_relative_residual": result.final_relative_residual,
        "final_objective": result.final_objective,
        "objective": list(result.history.objective),
        "data_residual": list(result.history.data_residual),
        "params": dict(result.params),
    }


def depth_profile(volume: np.ndarray, depths_mm) -> dict:
    """Where a volume puts its light: per-plane energy and the depth profile.

    Parameters
    ----------
    volume : ndarray, (n_z, rows, cols)
        Non-negative volume (measurement units), planes in depth order.
    depths_mm : sequence of float, (n_z,)

    Returns
    -------
    dict
        ``plane_energy`` (sum of each plane), ``plane_peak`` (each plane's largest
        voxel) and ``depth_profile``: ``depths_mm``, ``energy_fraction`` (each plane's
        share of the total), ``mean_depth_mm`` (energy-weighted), ``peak_plane``
        (the plane of most energy); JSON-ready.
    """
    v = np.asarray(volume)
    energy = v.reshape(v.shape[0], -1).sum(axis=1, dtype=np.float64)
    peak = v.reshape(v.shape[0], -1).max(axis=1)
    total = float(energy.sum())
    z = [float(d) for d in depths_mm]
    frac = energy / total if total > 0 else np.zeros_like(energy)
    return {"plane_energy": [float(e) for e in energy],
            "plane_peak": [float(p) for p in peak],
            "depth_profile": {"depths_mm": z, "energy_fraction": [float(f) for f in frac],
                              "mean_depth_mm": (float(np.dot(frac, z)) if total > 0
                                                else None),
                              "peak_plane": int(np.argmax(energy))}}


def prepare_volume_problem(stack: np.ndarray, raw: np.ndarray, dark, bin_factor: int,
                           allow_mixed_ranges: bool = False
                           ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Dark subtraction, binning and clipping with the :mod:`recon.preprocess` steps.

    Parameters
    ----------
    stack : ndarray, shape (n_z, rows, cols), real
        PSF stack, one plane per depth.
    raw : ndarray, shape (rows, cols), real
        One grayscale measurement, the size of a plane.
    dark : "auto", "none", None, float or ndarray (rows, cols)
        ``"auto"``: the median over the planes of their dark-corner level
        (:func:`recon.preprocess.dark_level`), subtracted from the stack and the raw
        image; ``"none"`` or None: no subtraction; a number: that level, input units
        (DN); a dark frame (the raw's shape): subtracted pixel by pixel from every
        plane and the raw image.
    bin_factor : int
        Lateral box binning of every plane and of the raw image.
    allow_mixed_ranges : bool
        Accept a stack and raw whose bit depths cannot be one camera's
        (:func:`recon.preprocess.check_pair_ranges`).

    Returns
    -------
    stack : ndarray, float32, shape (n_z, rows / bin, cols / bin)
        Non-negative (negative values after dark subtraction clipped to 0).
    raw : ndarray, float32, shape (rows / bin, cols / bin)
    info : dict
        ``dark_mode``, ``dark_level``, ``bin_factor``, ``saturated_fraction_raw``,
        ``psf_clipped_fraction``.

    Raises
    ------
    ReconInputError
        Invalid images, shapes that differ, or a plane without signal; a raw with
        nothing to reconstruct after its dark level
        (:class:`recon.preprocess.RawSignalError`, :func:`recon.preprocess.check_raw_signal`).
    """
    if raw.ndim != 2:
        raise ReconInputError(f"the raw image has shape {raw.shape}; recon3d needs one "
                              "grayscale image (rows, cols)")
    if raw.shape != stack.shape[1:]:
        raise ReconInputError(f"raw image {raw.shape[0]}x{raw.shape[1]} and PSF planes "
                              f"{stack.shape[1]}x{stack.shape[2]} differ in size; capture or "
                              "crop both to the same sensor region")
    for k in range(stack.shape[0]):
        validate_psf(stack[k])
    validate_measurement(raw)
    check_pair_ranges(stack, raw, allow_mixed_ranges=allow_mixed_ranges)
    raw_in = raw
    saturated = saturation_fraction(raw)
    if saturated > SATURATION_WARN:
        log.warning("%.2g%% of the raw image is saturated: the linear model does not hold "
                    "there", 100 * saturated)
    mode, level = dark_argument(dark, raw.shape)
    if mode == "auto":
        level = float(np.median([dark_level(stack[k]) for k in range(stack.shape[0])]))
    if level is not None:  # a scalar or a frame of the raw's shape: any plane count
        stack = np.asarray(stack, np.float32) - np.asarray(level, np.float32)
        raw = subtract_dark(raw, level)
    source = VOLUME_DARK_SOURCES[mode]
    raw_levels = check_raw_signal(raw_in, raw, dark_level=level, dark_source=source)
    stack = bin_stack(stack, bin_factor)
    raw = box_bin(raw, bin_factor)
    clipped = float(np.count_nonzero(stack < 0)) / stack.size
    np.clip(stack, 0.0, None, out=stack)
    empty = [k for k in range(stack.shape[0]) if not stack[k].sum(dtype=np.float64) > 0]
    if empty:
        raise ReconInputError(f"PSF planes {empty} have no signal above the dark level "
                              f"{level}; try the dark level none or a smaller value")
    info = {"dark_mode": mode, "dark_source": source,
            "dark_level": float(np.mean(level)) if mode == "frame" else level,
            "bin_factor": int(bin_factor), "saturated_fraction_raw": saturated,
            "psf_clipped_fraction": clipped, "raw_levels": raw_levels}
    return stack, raw, info


#: Where the dark level of a volume (or grid) reconstruction came from, per mode.
VOLUME_DARK_SOURCES = {"auto": "the median of the planes' dark corners, rows 5:15, cols 5:15",
                       "none": "none: the inputs are dark-subtracted",
                       "value": "the dark value given",
                       "frame": "the dark frame given, pixel by pixel"}


def check_volume_parameters(method: str, iterations: int, tv: float, l1: float,
                            bin_factor: int = 1) -> None:
    """Refuse parameters :func:`recon.reconstruct_volume` cannot use (before any file is read).

    Raises
    ------
    ReconInputError
        ``method`` not in :data:`METHODS`, ``iterations`` or ``bin_factor`` not an
        integer >= 1, or a weight that is not a finite number >= 0.
    """
    if method not in METHODS:
        raise ReconInputError(f"unknown method {method!r}; choose admm or fista")
    if isinstance(iterations, bool) or not isinstance(iterations, numbers.Integral) \
            or iterations < 1:
        raise ReconInputError(f"iterations must be an integer >= 1, got {iterations!r}")
    if isinstance(bin_factor, bool) or not isinstance(bin_factor, numbers.Integral) \
            or bin_factor < 1:
        raise ReconInputError(f"bin_factor must be an integer >= 1, got {bin_factor!r}")
    for name, w in (("tv", tv), ("l1", l1)):
        try:
            ok = not isinstance(w, bool) and math.isfinite(w) and w >= 0
        except TypeError:
            ok = False
        if not ok:
            raise ReconInputError(f"{name} must be a finite number >= 0, got {w!r}")


def reconstruct_stack(psf_stack: np.ndarray, depths_mm, raw: np.ndarray,
                      options: ReconOptions | None = None, *,
                      memory_limit_bytes: int | None = None, slab_group=None,
                      announce=None) -> Reconstruction:
    """Reconstruct a volume from one DiffuserCam measurement and a PSF stack (Eq. 4.4-4.5).

    Parameters
    ----------
    psf_stack : ndarray, shape (n_z, rows, cols), real
        One calibration PSF per depth (any order; sorted by depth here).
    depths_mm : sequence of float, length n_z
        Depth of every plane, mm.
    raw : ndarray, shape (rows, cols), real
        The measurement (sensor counts), the size of one plane.
    options : recon.options.ReconOptions, optional
        The reconstruction's options, as :func:`recon.reconstruct` passes them; default
        the declared ones (:meth:`~diffuserlab.options.Options.from_defaults`). This
        path reads ``method`` (``"admm"``: 3D ADMM, :func:`recon.volume.admm3d`;
        ``"fista"``: 3D FISTA, :func:`recon.volume.fista3d`; ``"auto"`` is ADMM, the
        3D accuracy benchmark's best), ``iterations`` (>= 1; with an automatic weight,
        those of the fixed-weight run it replaces: the path and the final solve take at
        most 2.5x as many, :data:`recon.auto.volume.VOLUME_RULES`; with few iterations
        the path's steps are coarse and the record says so), ``tv`` (3D TV weight in
        the scaled problem, >= 0, 0 disables; ``"auto"`` or None chooses it by hold-out
        cross-validation along a warm-started 3D ADMM path and tests every plane for
        signal against the held-out pixels and the frame's noise model,
        :func:`recon.auto.volume.auto_volume`, ``info["auto"]`` says what and why),
        ``l1`` (native sparsity weight, >= 0; ``"auto"``: the weight chosen, TV then
        fixed, 0 if ``tv`` is ``"auto"``; not given: 0), ``bin_factor`` (lateral box
        binning of the stack and the raw image), ``dark`` and ``allow_mixed_ranges``
        (:func:`prepare_volume_problem`), ``empty_planes`` (with an automatic weight:
        ``"keep"`` every plane, or ``"drop"``: those that show no signal in the
        held-out pixels, alone or together, :func:`recon.auto.planes.plane_tests`, set
        to zero; ``info["auto"]`` says which, why, and what the held-out error and the
        residual did), ``device`` (:func:`recon.backend.resolve_device`: the CPU's
        NumPy path, a CUDA GPU, the array-API paths: 3D ADMM's generic kernel set,
        ``recon.volume.xp_admm3d.XpVolumeAdmmPlan``, and
        ``recon.volume.xp_fista3d.fista3d_xp``, an automatic weight's held-out path
        and final solve there too, its plane tests on the host, or the GPU when one is
        usable; ``info["device"]`` says which ran) and ``prior`` (the prior of 3D ADMM,
        :mod:`recon.priors`: 3D TV (``"tv"``, and ``"tv-iso"``, the declared default of
        the 2D image), or ``"wavelet"`` or ``"dncnn"`` on each plane,
        ``tv`` its fixed weight; in memory, on the CPU or a device).
    memory_limit_bytes : int, optional
        The most this process's resident set may reach during a CPU solve (default:
        what it holds plus what the machine has available now). The first plan whose
        estimate fits runs (:func:`recon.volume.memory_plan.memory_plan`): the
        in-memory solver, else streamed 3D FISTA
        (:func:`recon.volume.memory_plan.solve_streamed`: planes transformed on the
        fly, a chunk or one plane at a time, iterates on the sensor's field of view;
        an automatic weight by the same held-out path over the slabs,
        :func:`recon.volume.streamed_auto.auto_streamed`, every plane kept); a limit
        below every plan is refused before any solver work. ``info.method_reason``
        and ``info.extra["memory_plan"]`` say which plan and why, and, streamed,
        ``info.extra["memory"]`` holds the estimate and the measured peak.
    slab_group : callable, optional
        ``slab_group(h, psf_scale) -> group``: run streamed 3D FISTA with the plane
        slabs elsewhere (dask workers, :class:`instrument.processing.volume_shards.ShardedSlabs`),
        whatever the memory plan says.
    announce : callable, optional
        ``announce(line)``: the memory plan and the streamed solve's estimate,
        before the solve (``recon3d`` prints them).

    Returns
    -------
    Reconstruction
        ``image`` (float32, (n_z, rows / bin, cols / bin), measurement units; also
        ``volume``), ``depths_mm`` ascending, the solver result, the operator and the
        record (``info.kind == "volume"``).

    Raises
    ------
    ReconInputError
        Bad images, shapes or parameters; an unusable ``device``, or a volume that
        does not fit in its free memory; a ``memory_limit_bytes`` below every plan's
        estimate (the message names the smallest limit that would do and what lowers
        it); a prior other than TV with FISTA, an
        automatic weight, ``"auto"`` or a streamed or sharded solve.
    recon.errors.DivergenceError
        The solver diverged.
    """
    o = ReconOptions.from_defaults() if options is None else options
    method, iterations, tv, bin_factor, dark = (o.method, o.iterations, o.tv, o.bin_factor,
                                                o.dark)
    allow_mixed_ranges, empty_planes, prior = o.allow_mixed_ranges, o.empty_planes, o.prior
    l1 = l1_given(o.l1)
    l1 = 0.0 if l1 is None else l1
    backend = resolve_device(o.device)
    reason = "given"
    if method == AUTO:  # 3D ADMM: the best localisation and PSNR of the 3D benchmark
        method, reason = "admm", ("3D ADMM: the best localisation and PSNR of the 3D "
                                  "accuracy benchmark (benchmarks.volume_accuracy)")
    tv, l1 = parse_weight(tv, "tv"), parse_weight(l1, "l1")
    auto_reg = "l1" if l1 == AUTO else "tv" if tv == AUTO else None
    if auto_reg == "l1" and tv == AUTO:
        tv = 0.0
    check_volume_parameters(method, iterations, 0.0 if tv == AUTO else tv,
                            0.0 if l1 == AUTO else l1, bin_factor)
    prior = _volume_prior(prior, method, tv, l1, slab_group)
    if empty_planes not in EMPTY_PLANES:
        raise ReconInputError(f"empty_planes {empty_planes!r}: use keep (every plane) or "
                              "drop (planes that show no signal set to zero, reported)")
    iterations, bin_factor = int(iterations), int(bin_factor)  # numpy integers too
    raw = as_array(raw, "raw image")
    dark_argument(dark, raw.shape[:2])  # refused before the work
    stack = as_array(psf_stack, "PSF stack")
    z = float_array(depths_mm, "depths_mm", ndims=(1,))
    if stack.ndim != 3 or len(z) != stack.shape[0]:
        raise ReconInputError(f"the PSF stack has shape {stack.shape} and {len(z)} "
                              "depths; give one depth per plane of an (n_z, rows, cols) stack")
    t_start = time.perf_counter()
    order = np.argsort(z, kind="stable")
    stack, depths = stack[order], [float(z[i]) for i in order]
    if len(set(depths)) < len(depths):  # arguments before the data's own checks
        raise ReconInputError(f"depths_mm {depths} repeat a depth; give one distinct depth "
                              "per plane of the PSF stack")
    stack, raw, info = prepare_volume_problem(stack, raw, dark,
                                              bin_factor, allow_mixed_ranges)

    h, psf_scale = normalize_psf_stack(stack)
    del stack
    raw_scale = float(np.max(np.abs(raw)))
    if not raw_scale > 0:
        raise ReconInputError("the measurement is zero after dark subtraction; check the "
                              "exposure and --dark")
    b = (raw / raw_scale).astype(np.float32)
    plan = None
    if backend.is_numpy:
        plan = memory_plan(method, auto_reg, h.shape[1:], h.shape[0], memory_limit_bytes,
                           baseline_bytes=process_baseline_bytes(), stack_bytes=h.nbytes,
                           bin_factor=bin_factor, sharded=slab_group is not None,
                           streamable=prior is None)
        if not plan["fits"] and prior is not None:
            raise ReconInputError(f"the {prior} prior runs in the in-memory 3D ADMM, which "
                                  f"does not fit here ({plan['reason']}); use --prior tv "
                                  "(streamed 3D FISTA) or more memory (--memory-limit)")
        if announce is not None and (plan["streamed"] or memory_limit_bytes is not None):
            announce(plan["reason"])
        if plan["streamed"]:
            held = [h]  # emptied once the slabs hold the spectra: the stack is freed
            del h
            auto = None
            if auto_reg is not None:
                noise = _frame_noise(raw)
                auto = {"noise": noise, "regulariser": auto_reg,
                        "other": l1 if auto_reg == "tv" else tv}
            return _reconstruct_streamed(
                held, b, depths, iterations=iterations, tv=tv, l1=l1, plan=plan,
                info={**info, "psf_scale": psf_scale}, raw_scale=raw_scale, t_start=t_start,
                slab_group=slab_group, announce=announce, auto=auto,
                empty_planes=empty_planes)
    op = VolumeConvolutionOperator(h, depths=depths)
    log.info("recon3d: %s, %d planes of %dx%d (padded %s), %d iterations", method, op.n_z,
             *op.sensor_shape, op.padded_shape, iterations)
    auto = []
    if not backend.is_numpy and auto_reg is None:
        needed = (admm3d_memory(op.n_z, op.padded_shape, tv > 0) if method == "admm"
                  else fista3d_memory(op.n_z, op.padded_shape))
        result = solve_on(backend, SOLVERS[method], op, b, iterations=iterations, tv=tv,
                          l1=l1, nonneg=True, needed_bytes=needed,
                          **({"prior": prior} if prior is not None else {}),
                          what=f"3D {'ADMM' if method == 'admm' else 'FISTA'} on {op.n_z} "
                               f"planes of {op.sensor_shape[0]} x {op.sensor_shape[1]}")
    elif auto_reg is None:
        result = SOLVERS[method](op, b, iterations=iterations, tv=tv, l1=l1, nonneg=True,
                                 **({"prior": prior} if prior is not None else {}))
    else:
        noise = _frame_noise(raw)
        on_device = {}
        if not backend.is_numpy:
            # the path's 3D ADMM, its kept estimates and the fit plan's second spectra
            check_device_memory(backend, admm3d_memory(op.n_z, op.padded_shape, True)
                                + auto3d_extra_bytes(op.n_z, op.padded_shape),
                                f"automatic 3D ADMM on {op.n_z} planes of "
                                f"{op.sensor_shape[0]} x {op.sensor_shape[1]}")
            on_device = {"backend": backend, "device_plan": XpVolumeAdmmPlan}
        result, record = auto_volume(method, op, b, noise=noise.scaled(raw_scale),
                                     iterations=iterations, plan_of=VolumeAdmmPlan.of,
                                     fista=fista3d, regulariser=auto_reg,
                                     other=l1 if auto_reg == "tv" else tv,
                                     empty_planes=empty_planes, **on_device)
        auto = [dict(record, noise=noise.as_dict())]
        tv, l1 = ((record["weight"], l1) if auto_reg == "tv" else (tv, record["weight"]))
    estimate = (result.x * raw_scale).astype(np.float32)
    volume = np.ascontiguousarray(estimate[(slice(None), *op.crop)])
    info_ = ReconInfo(
        kind="volume", method=method, method_reason=reason, iterations=iterations,
        iterations_used=int(result.params.get("iterations_used", iterations)), tv=tv, l1=l1,
        auto=auto, dark_mode=info.pop("dark_mode"), dark_level=info.pop("dark_level"),
        dark_source=info.pop("dark_source"), bin_factor=info.pop("bin_factor"),
        raw_scale=raw_scale, seconds_total=time.perf_counter() - t_start,
        device=backend.label, histories=[result.history],
        extra={**info, "psf_scale": psf_scale,
               "prior": prior or ("tv" if method == "admm" else None),
               **({} if plan is None else {"memory_plan": plan})})
    return Reconstruction(volume, estimate, [result], op, info_, depths_mm=depths,
                          record=volume_metrics if backend.is_numpy
                          else device_metrics(volume_metrics, backend, op.n_z))


def _volume_prior(prior, method: str, tv, l1, slab_group) -> str | None:
    """The prior other than 3D TV asked of a volume (None for TV), or why it cannot run.

    Raises
    ------
    ReconInputError
        An unknown prior, ``"auto"``, FISTA, an automatic weight or a sharded solve.
    """
    if prior in ("tv", "tv-iso") or prior is None:  # tv-iso, the 2D default: 3D TV here
        return None
    if prior == AUTO:
        raise ReconInputError("prior auto chooses among priors for a 2D image; a volume takes "
                              "one named prior (--prior tv|wavelet|dncnn)")
    name = prior_of(prior).name
    if name in ("tv", "tv-iso"):
        return None
    if method != "admm":
        raise ReconInputError(f"the {name} prior runs in 3D ADMM; use --method admm or "
                              "--prior tv")
    if AUTO in (tv, l1):
        raise ReconInputError(f"a volume's automatic weight is chosen with 3D TV; give the "
                              f"{name} prior a fixed weight (--tv W) or use --prior tv")
    if slab_group is not None:
        raise ReconInputError(f"the {name} prior runs in one process; a sharded solve is "
                              "3D FISTA with TV (--prior tv)")
    return name


def _frame_noise(raw: np.ndarray) -> NoiseModel:
    """The frame's Poisson-Gaussian noise (:func:`recon.auto.noise.estimate_noise`; too
    small a frame: none known), for an automatic weight."""
    return estimate_noise(raw) if min(raw.shape) >= 8 else NoiseModel(0.0, 0.0, [])


def _reconstruct_streamed(held, b, depths, *, iterations, tv, l1, plan, info, raw_scale, t_start,
                          slab_group, announce, auto=None, empty_planes="keep"
                          ) -> Reconstruction:
    """:func:`reconstruct_stack`'s streamed 3D FISTA (the in-memory plan did not fit);
    ``auto`` (the frame's ``noise``, ``regulariser``, ``other``): its weight chosen by
    the held-out path over the slabs (:mod:`recon.volume.streamed_auto`)."""
    notes, run_auto = [], None
    if auto is not None:
        reg = auto["regulariser"]
        notes.append(f"automatic {reg} weight: the held-out path of recon.auto over the "
                     "slabs (streamed 3D FISTA, the held-out pixels masked from the data "
                     "term on the sensor; recon.volume.streamed_auto)")
        if empty_planes != "keep":
            notes.append(f"empty_planes {empty_planes!r} not applied: the planes' held-out "
                         "test runs on the in-memory path only; every plane kept")
        run_auto = dict(auto, noise=auto["noise"].scaled(raw_scale))
    for note in notes if announce is not None else ():
        announce(note)
    result, model, memory, record = solve_streamed(
        held, b, iterations=iterations, tv=tv, l1=l1, depths=depths,
        slab_group=slab_group, announce=announce, auto=run_auto,
        **({} if slab_group is not None else
           {"chunk_bytes": plan["chunk_bytes"], "baseline_bytes": plan["baseline_bytes"]}))
    records = []
    if record is not None:
        records = [dict(record, noise=auto["noise"].as_dict())]
        if auto["regulariser"] == "tv":
            tv = record["weight"]
        else:
            l1 = record["weight"]
    result.x *= np.float32(raw_scale)  # in place: no second volume
    volume = np.ascontiguousarray(result.x[(slice(None), *model.estimate_crop)])
    info_ = ReconInfo(
        kind="volume", method="fista", method_reason="; ".join([plan["reason"], *notes]),
        iterations=iterations, iterations_used=int(result.params["iterations_used"]),
        tv=tv, l1=l1, auto=records, dark_mode=info.pop("dark_mode"),
        dark_level=info.pop("dark_level"), dark_source=info.pop("dark_source"),
        bin_factor=info.pop("bin_factor"), raw_scale=raw_scale,
        seconds_total=time.perf_counter() - t_start, device="cpu",
        histories=[result.history],
        extra={**info, "memory_plan": plan, "memory": memory, "support": "sensor"})
    return Reconstruction(volume, result.x, [result], model, info_, depths_mm=depths,
                          record=volume_metrics)
