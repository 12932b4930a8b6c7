"""Reconstruction from files: load -> reconstruct -> write PNG/TIFF/Zarr and metrics JSON.

:func:`run_recon` is ``diffuserlab recon`` (one image from a PSF and a raw
measurement; the PSF may be one depth of a run store's PSF stack or of a TIFF
stack); :func:`run_recon3d` is ``diffuserlab recon3d`` (a volume from one image and
a PSF stack, Kuo 2020, Ch. 4). The numerics are :func:`recon.reconstruct` (a PSF
or a :class:`recon.PsfStack`); this module reads run stores and stacks
(:mod:`instrument.runs.stacks`) and has the outputs written by the one writer
(:mod:`instrument.writer.products`). It logs, it never prints.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path

import numpy as np

from diffuserlab.errors import InputError
from diffuserlab.jsonio import jsonable

__all__ = ["RECIPE_FIXES", "check_dark_frame", "dark_level", "load_psf", "read_recipe_once",
           "resolve_dark", "run_recon", "run_recon3d", "scene_recipe_default"]

log = logging.getLogger(__name__)

def load_psf(psf_path: str, depth_mm: float | None,
             product: str = "psf_stack") -> tuple[np.ndarray, float | None]:
    """A 2D PSF from an image, or one depth of a stack (run store, TIFF or .npy stack).

    Parameters
    ----------
    psf_path : str
        An image (TIFF, PNG/JPEG, ``.npy``), a run store directory or a stack file.
    depth_mm : float, optional
        Depth of the stack's plane to use (nearest within 5 %); required for a stack
        file, optional for a run store with one plane.
    product : str
        Which stack of a run store (``psf_stack`` or ``psf_stack_raw``).

    Returns
    -------
    psf : ndarray, (rows, cols)
    depth : float or None
        The depth of the plane used (None for a plain image).

    Raises
    ------
    recon.errors.ReconInputError
        Unreadable input, or a stack without a matching depth.
    """
    from recon.errors import ReconInputError
    from recon.io import load_image

    from ..runs.runstore import RunStoreError
    from ..runs.stacks import load_psf_stack, pick_depth

    path = Path(psf_path)
    if not path.is_dir() and depth_mm is None:
        return load_image(psf_path), None
    try:
        stack, depths, _ = load_psf_stack(path, product=product)
        psf, depth = pick_depth(stack, depths, depth_mm)
    except RunStoreError as exc:
        raise ReconInputError(str(exc)) from exc
    return psf, depth


def resolve_dark(dark, psf: np.ndarray, *, calibrated: bool, recorded: float | None = None,
                 what: str = "the PSF", stack: bool = False):
    """``--dark`` with one meaning for every reconstruction command (docs/cli.md).

    ``auto``: a plain PSF (an image, a TIFF or ``.npy`` stack) carries its dark level in
    its dark corner ``psf[5:15, 5:15]`` (a stack: the median of its planes' corners),
    which :func:`recon.reconstruct` estimates and subtracts from PSF and raw; a PSF
    from a calibration run (``calibrated``) is dark-subtracted, so the frames' level
    recorded with them (``recorded``: a simulated run's or bench's camera offset) is
    used, and without one the level must be given. A level or a frame (given, or
    recorded) is subtracted from the raw and from a plain PSF; a calibrated PSF gets it
    added first, so that it stays as calibrated.

    Parameters
    ----------
    dark : str, float, ndarray or None
        ``--dark`` as given (``auto`` or None, ``none``, a level in DN, a ``calibrate
        dark`` run or a dark image) or a value read already (DN, a frame).
    psf : ndarray
        The PSF (rows, cols) or stack (n_z, rows, cols).
    calibrated : bool
        ``psf`` comes from a calibration run store (dark-subtracted).
    recorded : float, optional
        The frames' dark level, DN, recorded with them.
    what : str
        The PSF as the message names it (``"--psf RUN.zarr"``).
    stack : bool
        ``psf`` is a stack (n_z, rows, cols); else (rows, cols) or (rows, cols, C).

    Returns
    -------
    psf : ndarray
        ``psf``, or ``psf + level`` for a calibrated one.
    dark : "auto", "none", float or ndarray
        The ``dark`` of :func:`recon.reconstruct`.

    Raises
    ------
    recon.errors.ReconInputError
        ``auto`` with a calibrated PSF and no recorded level (names the fix), a bad
        ``dark`` (:func:`dark_level`), or a dark frame of another shape than the PSF's
        frames (:func:`check_dark_frame`, before it is added to a calibrated PSF).
    """
    from recon.errors import ReconInputError

    if isinstance(dark, np.ndarray) or isinstance(dark, int | float) and not isinstance(
            dark, bool):
        level = dark
    else:
        key = "auto" if dark is None else str(dark).strip().lower()
        if key == "none":
            return psf, "none"
        if key != "auto":
            level = dark_level(str(dark))
        elif recorded is not None and calibrated:
            level = float(recorded)
        elif calibrated:
            raise ReconInputError(
                f"{what} is a calibrated (dark-subtracted) PSF: give the frames' dark level "
                "with --dark DN or --dark DARK_RUN.zarr (diffuserlab calibrate dark), or "
                "--dark none if the raw is dark-subtracted too")
        else:
            return psf, "auto"
    frame = np.shape(psf)[1:3] if stack else np.shape(psf)[:2]
    check_dark_frame(level, frame, f"the frames of {what}")  # before any arithmetic
    if calibrated:  # subtracted from both below: the calibrated PSF stays as it was
        psf = psf + level
    return psf, level


def dark_level(text: str, option: str = "--dark"):
    """The dark level of a ``--dark`` option: a number (DN), a ``calibrate dark`` run or
    a dark image (TIFF, PNG, ``.npy``: a frame taken with the light blocked).

    Returns
    -------
    float or ndarray
        The level in DN, or the run's ``dark_mean`` frame or the image, (rows, cols)
        float32.

    Raises
    ------
    recon.errors.ReconInputError
        A negative or non-finite number, a run without a dark frame, or an unreadable
        image.
    """
    from recon.errors import ReconInputError

    from ..runs.runstore import RunStore, RunStoreError

    try:
        level = float(text)
    except ValueError:
        if Path(text).is_file():  # a dark image
            from recon.io import load_image

            return np.asarray(load_image(text), np.float32)
        try:
            dark, _ = RunStore.open(text).product("dark_mean")
        except RunStoreError as exc:
            raise ReconInputError(f"{option} {text}: {exc}") from None
        return np.asarray(dark, np.float32)
    if not 0 <= level < float("inf"):
        raise ReconInputError(f"{option} {text}: give a level >= 0 DN or a dark run")
    return level


def check_dark_frame(dark, shape, frames: str) -> None:
    """Refuse a dark frame whose shape is not the frames' before any work.

    Parameters
    ----------
    dark : float, ndarray or None
        A frames' dark level (:func:`dark_level`); only a frame (an array) is checked.
    shape : (rows, cols)
        The frames' shape (one camera's monochrome frames).
    frames : str
        What delivers the frames, for the message (``"the run's frames"``).

    Raises
    ------
    recon.errors.ReconInputError
        A dark frame of another shape, a colour image (rows, cols, C) included (named
        with both shapes and the fix).
    """
    from recon.errors import ReconInputError

    if np.ndim(dark) >= 1 and tuple(np.shape(dark)) != tuple(shape):
        raise ReconInputError(
            f"the dark frame is {'x'.join(map(str, np.shape(dark)))} but {frames} are "
            f"{'x'.join(map(str, shape))}; give a dark frame of the same camera region "
            "(ROI and binning), or a level in DN with --dark DN")


#: The options that a scene calibration's recipe fixes; any of them given turns it off.
RECIPE_FIXES = ("method", "iterations", "tv", "l1", "prior")


def scene_recipe_default(psf_path, options):
    """``options`` with a scene calibration's recipe applied by default.

    When ``psf_path`` is a ``calibrate psf-from-scenes`` run holding its recipe
    (``early_stop.json``, :mod:`recon.early_stop`: fitted on that camera's own
    calibration pairs), and neither ``--early-stop`` nor any of the options the recipe
    fixes (:data:`RECIPE_FIXES`) departs from its default, the recipe is used:
    on the real pairs it led LenslessPiCam by 0.69 dB on the same PSF, and it is now
    level with the default given the same PSF as a file (15.89 against 15.94 dB,
    docs/real-data.md).
    ``--early-stop off`` declines it. A recipe recorded as not trusted (its PSF
    explained little of the calibration scenes, :data:`recon.early_stop.TRUSTED_RESIDUAL`)
    is not the default: a warning says why and that ``--early-stop RUN`` forces it.

    Parameters
    ----------
    psf_path : str or Path
    options : recon.options.ReconOptions

    Returns
    -------
    recon.options.ReconOptions
        ``options``, or ``options`` naming the run's recipe (its ``early_stop.json``).

    Raises
    ------
    recon.errors.ReconInputError
        The run recorded a recipe that is missing, changed or not its own
        (:func:`instrument.runs.run_recipe.load_run_recipe`; the message names
        ``--early-stop off``), or a recipe out of range.
    """
    from recon.early_stop import FILE, TRUSTED_RESIDUAL
    from recon.options import ReconOptions

    from ..runs.run_recipe import load_run_recipe, recorded_recipe

    recipe = Path(psf_path) / FILE
    if options.early_stop is not None or not (recipe.is_file()
                                              or recorded_recipe(psf_path) is not None):
        return options
    defaults = ReconOptions.from_defaults()
    if any(getattr(options, f) != getattr(defaults, f) for f in RECIPE_FIXES):
        return options
    fit = load_run_recipe(psf_path)  # a deleted or changed recipe is refused here
    if not fit.trusted:
        log.warning("%s's scene-calibration recipe is not trusted (held-out residual %.2f > "
                    "%.2f: the PSF explains little of its calibration scenes): "
                    "reconstructing without it; --early-stop %s uses it anyway",
                    psf_path, fit.held_out_residual, TRUSTED_RESIDUAL, psf_path)
        return options
    log.info("%s holds its scene calibration's recipe (%s): "
             "reconstructing with it (--early-stop off declines)", psf_path, FILE)
    return options.replace(early_stop=str(recipe))


def read_recipe_once(options):
    """``options`` with the recipe its ``early_stop`` names read (and checked against its
    run's record, :func:`instrument.runs.run_recipe.load_recipe`) once: the solve uses, and
    the record names, exactly that recipe, whatever happens to the file meanwhile.

    Parameters
    ----------
    options : recon.options.ReconOptions

    Returns
    -------
    recon.options.ReconOptions
        ``options``, its ``early_stop`` a :class:`recon.early_stop.EarlyStop` when it
        named one.

    Raises
    ------
    recon.errors.ReconInputError
        As :func:`instrument.runs.run_recipe.load_recipe`.
    """
    from recon.early_stop import named

    from ..runs.run_recipe import load_recipe

    if not named(options.early_stop):
        return options
    return options.replace(early_stop=load_recipe(options.early_stop))


def run_recon(psf_path: str, raw_path: str, options, *, out: str,
              metrics_json: str | None = None, depth_mm: float | None = None,
              psf_product: str = "psf_stack", pitch_um: float | None = None) -> dict:
    """Load, reconstruct, write PNG + float32 OME-TIFF (+ metrics JSON); return metrics.

    With a scene-calibrated PSF run, its recipe is the default
    (:func:`scene_recipe_default`). The PNG is a view turned upright
    (:func:`recon.io.scene_view`); the TIFF keeps the model grid
    (:data:`recon.io.DATA_ORIENTATION`), its pixel size the grid's pitch
    (``pitch_um``, or a PSF run's frame pitch, times the binning) and the metrics
    record in its description (:func:`instrument.writer.products.write_recon_tiff`).

    Parameters
    ----------
    psf_path, raw_path : str
        PSF (image or stack, see :func:`load_psf`) and raw measurement files.
    options : recon.options.ReconOptions
        The reconstruction's parameters (validated: ``ReconOptions.from_namespace``
        of the command line, or ``ReconOptions.validated``); its one-PSF keywords go
        to :func:`recon.reconstruct`, its ``dark`` through :func:`resolve_dark`.
    out : str
        Output stem (see :func:`instrument.writer.products.output_paths`).
    metrics_json : str, optional
        Where to write the metrics.
    depth_mm, psf_product
        Plane and product of a PSF stack (see :func:`load_psf`).
    pitch_um : float, optional
        The sensor's pixel pitch, micrometres, unbinned (``--pitch-um``); None: the
        PSF run's, or no pixel size.

    Returns
    -------
    dict
        :meth:`recon.Reconstruction.metrics` (FFT floor: median of three timings)
        plus the input paths, seed, PSF depth, the grid's pitch (``pixel_size_um``,
        None when unknown) and output paths.

    Raises
    ------
    recon.errors.ReconInputError
        Bad files or parameters.
    recon.errors.DivergenceError
        The solver diverged.
    """
    from recon import reconstruct
    from recon.fft import fft_pair_seconds
    from recon.io import DATA_ORIENTATION, load_image

    from ..runs.stacks import dark_subtracted
    from ..writer.products import output_paths, write_image_products

    psf, depth = load_psf(psf_path, depth_mm, psf_product)
    options = read_recipe_once(scene_recipe_default(psf_path, options))
    psf, dark = resolve_dark(options.dark, psf, calibrated=dark_subtracted(psf_path),
                             what=f"--psf {psf_path}")
    raw = load_image(raw_path)
    with named_pair(psf_path, raw_path):
        result = reconstruct(psf, raw, options, dark=dark)
    floor = float(np.median([fft_pair_seconds(result.operator.padded_shape) for _ in range(3)]))
    metrics = result.metrics(floor)
    grid_pitch = _grid_pitch_um(psf_path, psf_product, pitch_um,
                                options.bin_factor)
    metrics.update(psf=str(psf_path), raw=str(raw_path), seed=options.seed,
                   psf_depth_mm=depth, pixel_size_um=grid_pitch)
    png, tif = output_paths(out)
    metrics.update(output_png=str(png), output_tiff=str(tif),
                   orientation={"png": "scene, upright", "tiff": DATA_ORIENTATION})
    write_image_products(result.image, png, tif, metrics_json, metrics, grid_pitch)
    return metrics


@contextlib.contextmanager
def named_pair(psf_path, raw_path):
    """Name the files in a :class:`recon.preprocess.RawSignalError` raised inside (the
    numerics speak of "the PSF" and "the raw")."""
    from recon.preprocess import RawSignalError

    try:
        yield
    except RawSignalError as exc:
        raise RawSignalError(f"--raw {raw_path} (PSF {psf_path}): {exc}") from None


def _grid_pitch_um(psf_stack: str, product: str, pitch_um: float | None,
                   bin_factor: int) -> float | None:
    """The pitch of the reconstruction grid, um: the sensor pitch given (``--pitch-um``)
    or the PSF run's frame pitch (:func:`instrument.runs.ome.frame_pitch_um`, times the
    product's own ``bin_factor``), times the reconstruction's binning; None when
    neither is known (a plain TIFF or .npy stack without ``--pitch-um``)."""
    from ..runs.ome import frame_pitch_um
    from ..runs.runstore import RunStore, is_run_store

    if pitch_um:
        return float(pitch_um) * bin_factor
    if not is_run_store(psf_stack):
        return None
    store = RunStore.open(psf_stack)
    pitch = frame_pitch_um(store.attrs)
    if pitch is None or product not in store.products():
        return None
    b = store.product_attrs(product).get("bin_factor", 1)
    return pitch * float(b) * bin_factor


def run_recon3d(psf_stack: str, raw_path: str, options, *, out: str,
                depths_mm: list[float] | None = None, psf_product: str = "psf_stack",
                metrics_json: str | None = None, planes: str = "all",
                pitch_um: float | None = None, d_mm: float | None = None,
                scene_range_mm=None, memory_limit_bytes: int | None = None,
                slab_group=None, announce=print, overwrite: bool = True) -> dict:
    """Load, reconstruct a volume (:func:`recon.reconstruct` of a :class:`recon.PsfStack`),
    write it and its
    projections and metrics.

    Parameters
    ----------
    psf_stack : str
        Run store, TIFF or ``.npy`` stack (see
        :func:`instrument.runs.stacks.load_psf_stack`).
    raw_path : str
        Raw measurement (TIFF, PNG or ``.npy``), the size of one PSF plane.
    options : recon.options.ReconOptions
        The reconstruction's parameters (validated: ``check_recon_flags`` of the
        command line, or ``ReconOptions.validated``); its volume keywords (method,
        iterations, tv, l1, bin_factor, allow_mixed_ranges, empty_planes, device) go to
        :func:`recon.reconstruct`, its ``dark`` through :func:`resolve_dark` (then
        :func:`recon.volume.api.prepare_volume_problem`).
    out : str
        ``OUT.tif``/``OUT.tiff`` or ``OUT.zarr``; projections go to
        ``OUT_mip_xy.png``, ``OUT_mip_xz.png`` and ``OUT_mip_yz.png``.
    depths_mm : list of float, optional
        One depth per plane when the stack does not record them.
    psf_product : str
        Product of a run store to read.
    metrics_json : str, optional
        Where to write the metrics.
    planes : {"all", "auto"}
        ``"auto"``: only the calibrated planes nearest the recommended ones
        (:func:`instrument.processing.planes.select_planes`; needs ``pitch_um`` and ``d_mm``).
    pitch_um, d_mm, scene_range_mm
        Sensor pitch (um, unbinned), diffuser-to-sensor distance (mm) and the scene's
        depth span (mm, optional) for ``planes="auto"``.
    memory_limit_bytes : int, optional
        Memory the solve may use (``--memory-limit``); default what is available.
        Above it the streamed 3D FISTA runs (:func:`recon.volume.api.reconstruct_stack`).
    slab_group : callable, optional
        Streamed 3D FISTA with the plane slabs elsewhere
        (:func:`instrument.processing.volume_shards.slab_workers` of ``recon3d --scheduler``).
    announce : callable
        Where the memory plan and estimate go before the solve (``print``).
    overwrite : bool
        Replace existing outputs; False (``recon3d`` without ``--overwrite``): an
        output another process wrote meanwhile is kept and this call refused
        (:func:`instrument.atomic.output_group`).

    Returns
    -------
    dict
        :meth:`recon.Reconstruction.metrics` (FFT floor measured after the
        solve in this process; ``seconds_total`` includes loading) plus the input
        paths and shapes and the output paths.

    Raises
    ------
    recon.errors.ReconInputError
        Bad files, shapes or parameters.
    instrument.runs.runstore.RunStoreError
        Unreadable stack, missing or mismatched depths.
    instrument.processing.volume_shards.ShardLostError
        A worker lost during a sharded solve (nothing is written).
    ValueError
        Bad ``--out`` name.
    recon.errors.DivergenceError
        The solver diverged.
    """
    from recon import PsfStack, reconstruct
    from recon.auto import AUTO, parse_weight
    from recon.io import DATA_ORIENTATION, load_image
    from recon.options import l1_given
    from recon.volume.api import check_volume_parameters

    from ..atomic import output_group, write_json
    from ..runs.stacks import dark_subtracted, load_psf_stack
    from ..writer.products import volume_output_paths, write_volume_products

    kw = options.keywords("volume")
    if l1_given(kw["l1"]) is None:  # --l1 not given: a volume's own default is 0
        kw["l1"] = float(kw["l1"])
    method, tv, l1 = kw["method"], parse_weight(kw["tv"], "tv"), parse_weight(kw["l1"], "l1")
    bin_factor = kw["bin_factor"]
    if planes not in ("all", "auto"):
        raise InputError(f"planes {planes!r}: use all or auto")
    check_volume_parameters("admm" if method == AUTO else method, kw["iterations"],
                            0.0 if tv == AUTO else tv, 0.0 if l1 == AUTO else l1)
    vol_path, mip_paths = volume_output_paths(out)
    t_start = time.perf_counter()
    stack, depths, _ = load_psf_stack(psf_stack, depths_mm, product=psf_product)
    stack, dark = resolve_dark(options.dark, stack, calibrated=dark_subtracted(psf_stack),
                               what=f"--psf-stack {psf_stack}", stack=True)
    stack_shape_in = list(stack.shape)
    raw = load_image(raw_path)
    raw_shape_in = list(raw.shape)
    plane_record = None
    if planes == "auto":
        from .planes import select_planes

        keep, plane_record = select_planes(stack, depths, raw, pitch_um=pitch_um, d_mm=d_mm,
                                           bin_factor=bin_factor, dark=dark,
                                           scene_depth_range_mm=scene_range_mm)
        stack, depths = stack[keep], [depths[i] for i in keep]
    with named_pair(psf_stack, raw_path):
        rec = reconstruct(PsfStack(stack, depths), raw, options, dark=dark,
                          memory_limit_bytes=memory_limit_bytes,
                          slab_group=slab_group, announce=announce)
    seconds_total = time.perf_counter() - t_start
    del stack
    attrs = {"depths_mm": rec.depths_mm, "units": "measurement counts per unit of the "
             "normalised PSF stack (sum_z (sum h_z)^2 = 1)", "method": method,
             "psf_stack": str(psf_stack), "raw": str(raw_path), "bin_factor": int(bin_factor),
             "orientation": DATA_ORIENTATION}
    grid_pitch = _grid_pitch_um(psf_stack, psf_product, pitch_um, bin_factor)
    write_volume_products(rec.volume, vol_path, mip_paths, attrs, grid_pitch,
                          replace=overwrite)
    solved = rec.metrics()
    solved["seconds_total"] = seconds_total
    files = {"psf_stack": str(psf_stack), "psf_product": psf_product,
             "stack_shape_in": stack_shape_in, "raw": str(raw_path),
             "raw_shape_in": raw_shape_in}
    head = ("method", "iterations", "tv", "l1", "shape", "sensor_shape", "padded_shape",
            "n_planes", "depths_mm")
    metrics = {**{k: solved.pop(k) for k in head}, **files, **solved,
               "output_volume": str(vol_path),
               "output_mips": {k: str(v) for k, v in mip_paths.items()},
               "orientation": {"mips": "scene, upright", "volume": DATA_ORIENTATION},
               "planes": plane_record}
    metrics = jsonable(metrics, nonfinite_to_none=True)
    if metrics_json:
        with output_group(replace=overwrite):
            write_json(metrics_json, metrics)
    log.debug("recon3d: wrote %s and %s", vol_path, ", ".join(map(str, mip_paths.values())))
    return metrics
