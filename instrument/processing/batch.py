"""Batch reconstruction of a recorded run on dask (``diffuserlab recon-run``).

Every selected frame of a run store is reconstructed independently with
:func:`recon.reconstruct` (the same call, with the same arguments, as
``diffuserlab recon`` on that frame, so the results are equal to float32 rounding:
bit for bit unless a worker's BLAS sums in another order) by dask
workers: a local cluster of ``workers`` processes (one task at a time each, with
the caller's FFT and numba thread count, so the numerics are the caller's) by default, or
the workers of a running ``dask.distributed`` scheduler given by its address (the
workers must see the run's path). Each result is written into the run as a
per-frame product (:meth:`instrument.runs.runstore.RunStore.write_product_frame`) as soon
as it arrives, under the run's writer lock, so an interrupted batch keeps every
finished frame and a second call with the same settings reconstructs only what is
missing. A frame whose data cannot be reconstructed (a dark frame, a diverging
solve) is left out and named with its reason; the others go on, and the next call
tries it again. With ``dff_percentile`` the ΔF/F of the reconstructed frames against a
per-pixel percentile baseline (Kuo 2020, Fig. 6.5b) is stored as a second product.

With ``device="cuda"`` every worker process runs its solves on a GPU through
:func:`recon.reconstruct`'s ``device`` (each resolves the name itself: local workers
share the machine's GPU 0, one local worker by default as dask-cuda runs one worker
per GPU; a cluster's workers use their own machine's GPU, with ``auto`` the CPU where
none is usable). The device is not part of the product's settings: a batch resumed on
another device continues the same product (the images agree to float32 rounding).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from recon.options import ReconOptions

from ..runs.runstore import DamagedFrameError, RunStore, RunStoreError
from .batch_grid import (
    GridBatchModel,
    reconstruct_run_frame,
    reconstruct_stored_frame_grid,
)
from .cluster_close import close_local_cluster

__all__ = ["batch_psf", "check_dark_level", "check_scheduler", "check_workers",
           "checked_recipe", "parse_frames", "reconstruct_run", "reconstruct_stored_frame",
           "recipe_record"]

log = logging.getLogger(__name__)


def parse_frames(text: str | None, n_frames: int) -> range:
    """The frames of ``--frames A:B`` (Python slice rules, no step) in a run of ``n_frames``.

    Raises
    ------
    RunStoreError
        Not of the form ``A:B``, ``A:`` or ``:B``, or an empty selection.
    """
    if text is None:
        return range(n_frames)
    a, sep, b = text.partition(":")
    try:
        if not sep or ":" in b:
            raise ValueError
        sel = range(n_frames)[slice(int(a) if a.strip() else None,
                                    int(b) if b.strip() else None)]
    except ValueError:
        raise RunStoreError(f"--frames {text!r}: give A:B (frames A to B-1; A: or :B for "
                            "open ends), e.g. 0:100") from None
    if len(sel) == 0:
        raise RunStoreError(f"--frames {text!r} selects no frame of the run's {n_frames}")
    return sel


def batch_psf(psf_path: str, run_attrs: dict, *, depth_mm: float | None = None,
              psf_product: str = "psf_stack", dark: str | None = None
              ) -> tuple[np.ndarray, float | np.ndarray | None, str]:
    """The PSF and the frames' dark level for reconstructing a recorded run.

    ``--dark`` has its one meaning (:func:`instrument.processing.reconstruct_files.resolve_dark`):
    a calibration run's PSF is dark-subtracted, so the frames' level is ``dark`` (a
    number in DN, a ``calibrate dark`` run or image), else the simulated camera's
    offset a run recorded on the virtual bench stores, added to the PSF so that
    :func:`recon.reconstruct` subtracts the same level from both; a plain PSF (an
    image, a TIFF stack's plane) and ``auto`` estimate the level from the PSF's corner
    as ``diffuserlab recon`` does (returned as None).

    Parameters
    ----------
    psf_path : str
        PSF image, stack or calibration run
        (:func:`instrument.processing.reconstruct_files.load_psf`).
    run_attrs : dict
        The recorded run's attributes (``simulated.dark_offset_dn``).
    depth_mm : float, optional
        Plane of a stack.
    psf_product : str
        Stack product of a calibration run.
    dark : str, optional
        ``--dark``: ``auto`` (or None), ``none``, a level in DN, a dark run or a dark
        image.

    Returns
    -------
    psf : ndarray, (rows, cols) float
    dark : float, ndarray (rows, cols) or None
    source : str
        The PSF's description (path and depth) stored with the product.

    Raises
    ------
    recon.errors.ReconInputError
        Unreadable PSF, no matching depth, a bad ``dark``, or a calibrated stack with
        no dark level known.
    """

    from ..runs.stacks import dark_subtracted
    from .reconstruct_files import load_psf, resolve_dark

    psf, depth = load_psf(psf_path, depth_mm, psf_product)
    recorded = (run_attrs.get("simulated") or {}).get("dark_offset_dn")
    psf, level = resolve_dark(dark, psf, calibrated=dark_subtracted(psf_path),
                              recorded=recorded, what=f"--psf {psf_path}")
    level = None if isinstance(level, str) and level == "auto" else (
        0.0 if isinstance(level, str) else level)  # "none": the frames are dark-subtracted
    return psf, level, f"{psf_path}" + ("" if depth is None else f" at {depth:g} mm")


def checked_recipe(early_stop, psf, dark=None):
    """The scene calibration's recipe ``early_stop`` names (:mod:`recon.early_stop`),
    read once (:func:`instrument.runs.run_recipe.load_recipe`: checked against its run's
    record) and checked against ``psf`` (carrying the dark level ``dark``, as
    :func:`batch_psf` returns it) before any frame is done; None when none is named
    (or ``"off"``). A batch hands this one object to every frame's solve and records
    it in the product, so an edit of the file meanwhile changes neither.

    Parameters
    ----------
    early_stop : str, recon.early_stop.EarlyStop or None
        The recipe: a calibration run or its ``early_stop.json`` (or one read
        already), ``"off"`` or None.
    psf : ndarray, (rows, cols) float
        The PSF the frames will be reconstructed with.
    dark : float, ndarray or None
        The dark level ``psf`` carries (:func:`batch_psf`'s), DN; None for none.

    Returns
    -------
    recon.early_stop.EarlyStop or None

    Raises
    ------
    recon.errors.ReconInputError
        The recipe cannot be read, is not its run's own, is out of range, or was
        fitted for another PSF.
    """
    from recon.early_stop import named

    from ..runs.run_recipe import load_recipe

    if not named(early_stop):
        return None
    fit = load_recipe(early_stop)
    fit.check_psf(psf, dark)
    return fit


def recipe_record(early_stop, psf, dark=None) -> dict | None:
    """:meth:`recon.early_stop.EarlyStop.record` of :func:`checked_recipe` (None when no
    recipe is named); raises as it does."""
    fit = checked_recipe(early_stop, psf, dark)
    return None if fit is None else fit.record()


def reconstruct_stored_frame(run_path: str, index: int, psf: np.ndarray,
                             options: dict[str, Any], threads: int | None = None
                             ) -> tuple[int, np.ndarray]:
    """Reconstruct frame ``index`` of a run: the task every dask worker runs.

    Parameters
    ----------
    run_path : str
        The run store (opened read-only once per worker process).
    index : int
        Frame slot.
    psf : ndarray, (rows, cols)
        PSF at the camera's frame shape.
    options : dict
        Keywords of :func:`recon.reconstruct` (method, iterations, tv, l1, bin_factor,
        dark, device).
    threads : int, optional
        The task's FFT and numba threads (:func:`recon.fft.limited_threads`; the
        batch passes the caller's count, so the results equal a reconstruction in the
        calling process to float32 rounding); None leaves the worker's defaults.

    Returns
    -------
    (int, ndarray)
        ``index`` and the image, float32 (rows // bin, cols // bin), model grid.

    Raises
    ------
    RunStoreError
        The frame is not stored or is damaged.
    recon.errors.ReconInputError, recon.errors.DivergenceError
        From :func:`recon.reconstruct`.
    """
    result = reconstruct_run_frame(run_path, index, psf, threads, **options)
    return int(index), np.asarray(result.image, np.float32)


class FrameRefused:
    """A frame's refusal, returned by :func:`refusals_returned` instead of raised: a
    task that raises is logged by each dask worker with its traceback ("Compute
    Failed"), which reads as a crash for what is the frame's own data."""

    def __init__(self, error: BaseException) -> None:
        self.kind = type(error).__name__
        self.message = " ".join(str(error).split())


def refusals_returned(task, *args):
    """``task(*args)``, with a refusal of the frame's data (ReconInputError,
    DivergenceError) returned as a :class:`FrameRefused` (the batch lists it as
    ``failed``) rather than raised on the worker.

    Parameters
    ----------
    task : callable
        :func:`reconstruct_stored_frame` or the grid's task.
    *args
        Its arguments.
    """
    from recon.errors import DivergenceError, ReconInputError

    try:
        return task(*args)
    except (ReconInputError, DivergenceError) as exc:
        return FrameRefused(exc)


def check_dark_level(store: RunStore, index: int, psf: np.ndarray, dark,
                     bin_factor: int) -> None:
    """Refuse, before any frame is reconstructed, a dark level with which no frame can
    be: one that leaves the PSF without signal (:func:`recon.preprocess.check_psf_signal`)
    or that frame ``index`` lies below (:class:`recon.preprocess.RawBelowDarkError`: a
    pixel cannot read below its dark level, so that level is not the camera's). The
    checks are those of ``diffuserlab recon`` (:func:`recon.preprocess.prepare_pair`);
    what is wrong with that frame's own data (no light, a constant frame, a damaged
    one) is left to the batch, which names the frame and goes on.

    Parameters
    ----------
    store : RunStore
        The run.
    index : int
        A frame to check the dark level against (the first of the batch).
    psf : ndarray, (rows, cols)
        The batch's PSF.
    dark : float, ndarray (rows, cols) or None
        As :func:`reconstruct_run`'s (None: each frame's estimate from the PSF).
    bin_factor : int
        The reconstruction's binning.

    Raises
    ------
    recon.errors.ReconInputError
        The PSF has no signal above the dark level, or the frame lies below it (the
        message names the frame, both levels and the fix).
    """
    import warnings

    from recon.errors import ReconInputError
    from recon.preprocess import RawBelowDarkError, check_psf_signal, prepare_pair
    from recon.preprocess.dark import front_door_dark

    level = front_door_dark("auto" if dark is None else dark)  # as each frame's solve
    check_psf_signal(psf, dark=level, bin_factor=bin_factor)
    try:
        raw = store.frame(int(index)).image
    except RunStoreError:  # damaged: the batch names it
        return
    try:
        with warnings.catch_warnings():  # each frame's warnings come with its solve
            warnings.simplefilter("ignore")
            prepare_pair(psf, raw, dark=level, bin_factor=bin_factor)
    except RawBelowDarkError as exc:
        raise ReconInputError(f"frame {index} of {store.path}: {exc}") from None
    except ReconInputError:  # that frame's own data: the batch names it and goes on
        pass


def _frame_number(line: str) -> int:
    """The frame index a ``failed`` line of :func:`reconstruct_run` starts with."""
    return int(line.split()[1])


def check_workers(workers: int | None, n_frames: int) -> int:
    """The local worker processes for ``n_frames`` frames: ``workers`` (default one per
    core), at most one per frame; refused beyond the machine's cores.

    Raises
    ------
    RunStoreError
        Not a whole number >= 1, or more than :func:`os.cpu_count` (each worker is a
        process computing full-time: more only queue for the cores and their memory).
    """
    cores = os.cpu_count() or 1
    if workers is None:
        return max(1, min(cores, n_frames))
    if isinstance(workers, bool) or not isinstance(workers, int | np.integer) or workers < 1:
        raise RunStoreError(f"--workers {workers}: give a whole number >= 1")
    if workers > cores:
        raise RunStoreError(f"--workers {workers}: this machine has {cores} cores; give at "
                            f"most {cores} (a worker is a process busy full-time)")
    return int(max(1, min(workers, n_frames)))


def check_scheduler(scheduler: str, timeout_s: float = 5.0) -> None:
    """Refuse a scheduler address that is not one, or where nothing listens, at once.

    ``tcp://HOST:PORT`` (or ``HOST:PORT``, ``tls://...``): the address is parsed and a
    TCP connection opened within ``timeout_s``; dask's own client would retry for its
    whole timeout (a minute) before saying the port is closed.

    Raises
    ------
    RunStoreError
        Not an address (one line naming it and the form), or nothing answering there.
    """
    import socket

    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler, strict=False)
        if scheme not in ("tcp", "tls"):
            return  # inproc, ucx, ws: no TCP port to try
        host, port = parse_host_port(location)
    except (ValueError, TypeError):
        raise RunStoreError(f"--scheduler {scheduler!r} is not a scheduler address; give "
                            "tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)") from None
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise RunStoreError(f"--scheduler {scheduler}: nothing answers at {host}:{port} "
                            f"({exc.strerror or exc}); start one (dask scheduler) or drop "
                            "--scheduler for local workers") from None


def _client(workers: int | None, scheduler: str | None, timeout_s: float):
    """A dask.distributed client: to ``scheduler``, else a local cluster of processes."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - dask is a dependency
        raise RunStoreError("batch reconstruction needs dask.distributed: pip install "
                            "'dask[distributed]'") from exc
    if scheduler is not None:
        try:
            return Client(scheduler, timeout=timeout_s), None
        except (OSError, ValueError, TypeError) as exc:
            raise RunStoreError(f"--scheduler {scheduler}: no dask scheduler answered within "
                                f"{timeout_s:g} s ({exc}); start one (dask scheduler) or "
                                "drop --scheduler for local workers") from None
    cluster = client = None
    try:
        with _signals_deferred():  # dask turns an interrupt mid-start into its own errors
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", host="127.0.0.1")
            client = Client(cluster, timeout=timeout_s)
    except BaseException:  # Ctrl-C, SIGTERM (raised as the block ends): nothing left running
        for part in (client, cluster):
            if part is not None:
                part.close()
        raise
    return client, cluster


@contextlib.contextmanager
def _signals_deferred():
    """SIGINT, SIGTERM and SIGHUP held while the local cluster starts (seconds) and
    handled as the block ends, by the handler that was in place then.

    Interrupted midway, dask reports "Nanny failed to start" instead of the
    interrupt, and its exit hook fails to close the half-started cluster with a
    traceback; with the signal held, the caller gets the interrupt with a whole cluster
    to close. Outside the main thread nothing changes (signals go to the main thread).
    """
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    names = [s for s in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, s)]
    previous = {getattr(signal, n): signal.signal(getattr(signal, n),
                                                  lambda signum, frame: held.append(signum))
                for n in names}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if held:
            handler = previous[held[0]]
            if callable(handler):
                handler(held[0], None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(held[0])


def reconstruct_run(run: str | Path, psf, options: ReconOptions | None = None, *,
                    dark: float | np.ndarray | None = None, frames: range | None = None,
                    product: str | None = None, workers: int | None = None,
                    scheduler: str | None = None, dff_percentile: float | None = None,
                    overwrite: bool = False, psf_source: str = "",
                    on_progress: Callable[[dict], None] | None = None,
                    cancel: threading.Event | None = None,
                    timeout_s: float = 60.0) -> dict[str, Any]:
    """Reconstruct every selected frame of a recorded run with dask; store the results.

    Parameters
    ----------
    run : str or Path
        The run store (``capture video`` or any run); opened for writing and locked
        while the batch runs.
    psf : ndarray (rows, cols), or instrument.processing.batch_grid.GridBatchModel
        PSF at the run's frame shape (:func:`instrument.processing.reconstruct_files.load_psf`),
        or a PSF grid with its model chosen and built once for the batch
        (:func:`instrument.processing.batch_grid.prepare_grid_batch`; the frames are then
        reconstructed by :func:`instrument.processing.batch_grid.reconstruct_stored_frame_grid`
        with ``background``, ``grid_l1``, ``iterations`` and ``dark``).
    options : recon.options.ReconOptions, optional
        The reconstruction's parameters, as ``recon-run`` validates them from its flags
        (``ReconOptions.validated(..., front="python")`` from Python; default: the
        declared defaults, i.e. ``diffuserlab recon``'s: the method and weights chosen
        from each frame's data, at most 200 iterations). Its ``dark`` is not read here
        (pass the resolved ``dark``). With a grid, ``method`` and ``tv`` are not used,
        ``bin_factor`` is the grid model's, ``background`` applies, and the l1 weight is
        ``l1`` when given, else :data:`recon.options.GRID_L1` (Eq. 6.2); with one PSF
        an l1 not given is 0.
    dark : float, ndarray (rows, cols) or None
        The dark level or frame (DN) subtracted from each frame, resolved by the
        caller (:func:`batch_psf`); None: each frame's own estimate.
    frames : range, optional
        Frame slots to reconstruct (see :func:`parse_frames`; each must be stored).
        Default: every stored frame (a recording killed midway keeps a prefix).
        A frame whose checksum fails is left out and listed (``damaged``).
    product : str, optional
        Name of the per-frame product (default ``recon_<method>``, with a grid
        ``recon_grid_<model>``); the ΔF/F product is ``<product>_dff``, a grid's
        background estimates the per-frame product ``<product>_background``.
    workers : int, optional
        Local worker processes (default: one per core, one with a GPU ``device``), at
        most one per frame and at most the machine's cores (:func:`check_workers`,
        before the run is locked); ignored with ``scheduler``.
    scheduler : str, optional
        Address of a running dask.distributed scheduler (``tcp://host:8786``); parsed
        and tried (:func:`check_scheduler`) before the run is touched.
    dff_percentile : float, optional
        Also store ΔF/F against this per-pixel percentile of the selected frames.
    overwrite : bool
        Replace an existing product made with other settings (without it, such a
        product is refused; one made with the same settings is resumed).
    psf_source : str
        Where the PSF came from, stored with the product.
    on_progress : callable, optional
        Called after each stored frame with ``{"done", "total", "skipped",
        "elapsed_s", "fps"}``.
    cancel : threading.Event, optional
        Stops the batch (queued tasks cancelled); finished frames are kept.
    timeout_s : float
        Longest wait for the scheduler and for the local cluster to come up, s.
        ``options.device`` is resolved first (:func:`recon.backend.resolve_device`), so
        an unusable one is refused before the run is touched; each worker's solves run
        there (module notes), a grid model's too (:mod:`recon.spatial.device`).

    Returns
    -------
    dict
        ``product``, ``frames`` (first and one past the last selected),
        ``reconstructed`` (this call), ``skipped`` (already done), ``not_stored``
        (ranges of frame slots left out because nothing was stored there, default
        selection), ``damaged`` (one line per damaged frame left out), ``failed``
        (one line per frame whose data cannot be reconstructed, e.g. a dark frame: its
        index, point and the reason; left out, the others go on), ``cancelled``,
        ``seconds``, ``fps``, ``workers``, ``device`` (as asked),
        ``dff_product`` when computed and ``background_product`` with a grid's
        background estimate.

    Raises
    ------
    RunStoreError
        Missing, locked or damaged run, a selected frame not stored, a product clash,
        too many workers, or no scheduler at the address.
    recon.errors.ReconInputError
        An unusable ``device`` or a dark frame of another shape (before the run is
        touched), a dark level with which no frame can be reconstructed
        (:func:`check_dark_level`, before any frame is). A frame's own reconstruction
        error leaves that frame out (``failed``).
    """
    from recon.backend import resolve_device
    from recon.errors import DivergenceError, ReconInputError
    from recon.io import DATA_ORIENTATION
    from recon.options import GRID_L1, l1_given
    from recon.validate import as_int

    from ..runs.runstore_records import ranges_text

    options = ReconOptions.validated({}) if options is None else options
    method, tv, background = options.method, options.tv, options.background
    iterations, bin_factor, device = options.iterations, options.bin_factor, options.device
    given_l1 = l1_given(options.l1)  # not given: 0 with one PSF, GRID_L1 with a grid
    l1, grid_l1 = (0.0, GRID_L1) if given_l1 is None else (given_l1, given_l1)
    backend = resolve_device(device)  # before the store is touched, as the scheduler
    if scheduler is not None:  # before the store is touched: nothing written on failure
        check_scheduler(scheduler)
    store = RunStore.open(run, "r+")
    if scheduler is None:
        if workers is None and not backend.is_numpy:
            workers = 1  # one worker per GPU (module notes)
        workers = check_workers(workers, len(frames or range(store.n_frames)))
    store.lock()  # a second writer (or a stale lock) is refused before anything else
    t0 = time.monotonic()
    done_now = 0
    cancelled = False
    client = cluster = None
    damaged: list[str] = []
    failed: list[str] = []
    try:
        stored = store.done()
        if frames is None:  # the stored frames (a recording killed midway kept a prefix)
            not_stored = np.flatnonzero(~stored)
            frames = [int(i) for i in np.flatnonzero(stored)]
            if not frames:
                raise RunStoreError(f"{store.path} holds no stored frame")
        else:
            not_stored = np.array([i for i in frames if not stored[i]], int)
            if not_stored.size:
                raise RunStoreError(f"{store.path}: frames {ranges_text(not_stored)} are not "
                                    "stored; select stored frames with --frames")
        frames = list(frames)
        iterations = as_int(iterations, "iterations", minimum=1)
        bin_factor = as_int(bin_factor, "bin_factor", minimum=1)
        rows, cols = store.frame_shape
        grid = psf if isinstance(psf, GridBatchModel) else None
        shape = tuple(grid.grid.sensor_shape if grid else np.shape(psf))
        if shape != (rows, cols):
            raise RunStoreError(f"the PSF is {shape} but the run's frames are {rows}x{cols}; "
                                "use a PSF calibrated at the camera's frame shape")
        from .reconstruct_files import RECIPE_FIXES, check_dark_frame

        check_dark_frame(dark, (rows, cols), "the run's frames")  # before any frame is done
        if grid is None:  # a level above the signal fails every frame: refused now
            check_dark_level(store, frames[0], psf, dark, bin_factor)
        dark_attr = None if dark is None else (float(dark) if np.ndim(dark) == 0 else "frame")
        hint = f"diffuserlab recon-run {store.path} with the same options"
        if grid is None:
            task_options = {"method": method, "iterations": iterations, "tv": tv, "l1": l1,
                       "bin_factor": bin_factor, "dark": "auto" if dark is None else dark,
                       "device": device, "prior": options.prior}
            settings = {"method": method, "tv": tv, "l1": l1, "prior": options.prior,
                        "psf": psf_source, "orientation": DATA_ORIENTATION}
            name, task = product or f"recon_{method}", reconstruct_stored_frame
            fit = checked_recipe(options.early_stop, psf, dark)  # read once per product
            if fit is not None:  # a scene calibration's recipe fixes the solve
                recipe = fit.record()
                task_options = {k: v for k, v in task_options.items()
                                if k not in RECIPE_FIXES}
                task_options["early_stop"] = fit  # the recipe read, not its file
                settings.update(method="fista", tv=0.0, l1=0.0, calibration=recipe)
                name, iterations = product or "recon_recipe", recipe["iterations"]
        else:
            bin_factor = grid.bin_factor
            task_options = {"background": background, "l1": grid_l1, "iterations": iterations,
                       "dark": dark, "device": device}
            settings = {**grid.settings(), "background": background, "l1": grid_l1,
                        "orientation": DATA_ORIENTATION}
            name, task = product or grid.product_name, reconstruct_stored_frame_grid
        plane = (rows // bin_factor, cols // bin_factor)
        settings.update(iterations=iterations, bin_factor=bin_factor, dark=dark_attr,
                        resume_hint=hint)
        store.create_frame_product(name, store.n_frames, plane, np.float32,
                                   overwrite=overwrite, **settings)
        bg_name = f"{name}_background" if grid and background == "estimate" else None
        if bg_name:
            store.create_frame_product(bg_name, store.n_frames, plane, np.float32,
                                       overwrite=overwrite, source=name, **settings)
        already = store.product_frames_done(name)
        if bg_name:  # a frame is done when both planes are
            already &= store.product_frames_done(bg_name)
        todo = [i for i in frames if not already[i]]
        skipped = len(frames) - len(todo)
        n_workers = None
        if todo:
            from dask.distributed import as_completed

            client, cluster = _client(workers, scheduler, timeout_s)
            n_workers = len(client.scheduler_info()["workers"])
            from recon.jit import thread_count

            # each task computes with the caller's thread count: numba's parallel
            # reductions depend on it, and the results must equal `recon`'s (to float32
            # rounding: dask's workers run one BLAS thread)
            psf_future = client.scatter(grid or np.asarray(psf), broadcast=True)
            futures = [client.submit(refusals_returned, task, str(store.path), i,
                                     psf_future, task_options, thread_count(), pure=False)
                       for i in todo]
            index_of = dict(zip(futures, todo, strict=True))
            try:
                for fut in as_completed(futures):
                    try:
                        done = fut.result()
                    except DamagedFrameError as exc:  # left out, as runs verify says
                        damaged.append(str(exc))
                        continue
                    except (ReconInputError, DivergenceError) as exc:  # this frame's data
                        done = FrameRefused(exc)
                    if isinstance(done, FrameRefused):
                        i = index_of[fut]
                        failed.append(f"frame {i} (point {store.point_of(i)}): "
                                      f"{done.message}")
                        continue
                    index, image, *bg = done
                    if bg_name:
                        store.write_product_frame(bg_name, index, bg[0])
                    store.write_product_frame(name, index, image)
                    done_now += 1
                    if on_progress is not None:
                        el = time.monotonic() - t0
                        on_progress({"done": done_now + skipped, "total": len(frames),
                                     "skipped": skipped, "elapsed_s": el,
                                     "fps": done_now / el if el > 0 else 0.0})
                    if cancel is not None and cancel.is_set():
                        cancelled = True
                        break
            finally:
                client.cancel([f for f in futures if not f.done()])
        elapsed = time.monotonic() - t0
        span = [frames[0], frames[-1] + 1]
        out: dict[str, Any] = {
            "product": name, "frames": span,
            "reconstructed": done_now, "skipped": skipped, "cancelled": cancelled,
            "seconds": round(elapsed, 3), "fps": done_now / elapsed if elapsed > 0 else 0.0,
            "workers": n_workers, "not_stored": ranges_text(not_stored),
            "damaged": damaged, "failed": sorted(failed, key=_frame_number),
            "device": device}
        if bg_name:
            out["background_product"] = bg_name
        if dff_percentile is not None and not cancelled:
            from recon.analysis import delta_f_over_f

            have = store.product_frames_done(name)
            used = [i for i in frames if have[i]]
            stack = np.stack([store.product_frame(name, i) for i in used])
            dff, baseline = delta_f_over_f(stack, dff_percentile)
            store.write_product(f"{name}_dff", dff, percentile=dff_percentile,
                                frames=span, frame_indices=used, source=name)
            store.write_product(f"{name}_dff_baseline", baseline, percentile=dff_percentile,
                                frames=span, frame_indices=used, source=name)
            out["dff_product"] = f"{name}_dff"
        return out
    finally:
        try:
            close_local_cluster(client, cluster)
        finally:
            store.unlock()
