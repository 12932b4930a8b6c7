"""What the panels run on their workers: thin calls into the library.

* :func:`build_live` - a live reconstruction for the session's camera, in a process of
  its own (:class:`instrument.acquisition.live_process.LiveReconstructionProcess`), and a PSF from a
  file or run store (:func:`instrument.processing.reconstruct_files.load_psf`), with the frames'
  dark level as ``capture live`` takes it.
* :func:`routine_options` / :func:`check_values` - a calibration routine's parameters
  are its typed model (:mod:`calibration_routines.parameters`), from which the
  ``calibrate`` command's options are generated too; the form's texts become the
  model, and the model builds the plan (:func:`calibration_routines.bench_jobs.build_plan`, in the
  bench process).
* :func:`run_plan` / :func:`resume_plan` - :class:`instrument.acquisition.runner.Runner` with the
  job's progress and a :class:`~instrument.acquisition.runner.RunControl`, run in the bench
  process (:mod:`calibration_routines.bench_jobs`, :mod:`instrument.bench.bench_jobs`) with
  the camera claimed.
* :func:`run_alignment` - the mask alignment as ``align mask`` runs it (in the bench
  process).
* :func:`record` / :func:`batch_reconstruct` - a video recording
  (:func:`instrument.acquisition.video.record_video`, in the bench process) and the batch
  reconstruction of a run (:func:`instrument.processing.batch.reconstruct_run`, options as
  ``recon-run`` takes them, :func:`batch_options`, in a process of its own).
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Any

# the bodies the bench process runs, re-exported for the panels and the tests
from calibration_routines.bench_jobs import ALIGNMENT_STEPS, build_plan, section_summary

__all__ = ["ALIGNMENT_STEPS", "ROUTINES", "batch_options", "batch_reconstruct", "build_live",
           "build_plan", "check_values", "default_run_path", "record", "resume_plan",
           "routine_options", "run_alignment", "run_plan", "section_summary",
           "stack_depths"]

#: Whether :func:`build_live` runs the live reconstruction in a child process (the
#: default: the window's process then shares its interpreter lock with no solver) or,
#: False, on a thread of the window's process (tests that replace the reconstructor's
#: device in this process).
LIVE_IN_PROCESS = True

#: Calibration routines, as ``calibrate`` names them.
ROUTINES = ("dark", "psf-sweep", "psf-grid", "angular-response", "slm-lut")

def build_live(session, psf_path: str, *, depth_mm: float | None = None, live=None,
               options=None, threads: int | None = 1):
    """A live reconstruction for the session's camera (not started).

    Parameters
    ----------
    session : gui.session.Session
        Connected.
    psf_path : str
        PSF image, PSF stack or calibration run.
    depth_mm : float, optional
        Depth of the stack's plane.
    live : recon.options.LiveOptions, optional
        The method (``"wiener"`` or ``"admm"``) and its warm-started iterations per
        frame (default: the declared ones).
    options : recon.options.ReconOptions, optional
        ``capture live``'s reconstruction options (default: the declared ones): the
        frames' dark level, as ``--dark`` (one meaning,
        :func:`instrument.processing.reconstruct_files.resolve_dark`: auto for a plain PSF image its
        dark corner, for a calibration run's PSF the simulated camera's offset on the
        virtual bench, else refused; ``none``; a level in DN; a ``calibrate dark`` run or
        dark image), the binning and the device where the solves run
        (:class:`recon.live.LiveReconstructor`'s; the reconstructor's
        ``backend.label`` says which).
    threads : int, optional
        Threads of the reconstruction (default 1, leaving a core to the GUI and a
        recorder).

    Returns
    -------
    live : instrument.acquisition.live_process.LiveReconstructionProcess
        Not started: its ``start()`` builds the reconstructor in the child and raises
        what building raised. With :data:`LIVE_IN_PROCESS` False an
        :class:`instrument.acquisition.live.LiveReconstruction` built here.
    depth_mm : float or None
        The depth of the stack's plane used (the nearest to ``depth_mm``); None for a
        single PSF image.

    Raises
    ------
    gui.workers.InputError
        No PSF given.
    recon.errors.ReconInputError
        Unreadable PSF, a PSF whose shape is not the camera's frames, a calibrated
        stack without a dark level on a real bench (the unusable ``device``, what is
        missing, or a GPU without the memory the live reconstruction needs: from the
        process's ``start()``).
    """
    from instrument.acquisition.live import LiveReconstruction
    from instrument.acquisition.live_process import LiveReconstructionProcess
    from instrument.processing.reconstruct_files import load_psf, resolve_dark
    from instrument.runs.stacks import dark_subtracted
    from recon.errors import ReconInputError
    from recon.live import LiveReconstructor
    from recon.options import LiveOptions, ReconOptions

    from .workers import BACKGROUND_NICE, InputError

    live = live or LiveOptions.from_defaults()
    options = options or ReconOptions.from_defaults()
    if not psf_path.strip():
        raise InputError("give the PSF: an image, a PSF stack or a calibration run (PSF "
                         "sweep); Browse... picks one")
    psf, depth = load_psf(psf_path, depth_mm)
    cam = session.service.camera_format()
    if tuple(cam.image_shape) != tuple(psf.shape):
        raise ReconInputError(
            f"the PSF {psf_path} is {psf.shape[0]}x{psf.shape[1]} but the camera delivers "
            f"{cam.image_shape[0]}x{cam.image_shape[1]} frames; calibrate the PSF with the "
            "camera's current ROI and binning")
    psf, level = resolve_dark(  # one meaning of the dark level, as the CLI's
        options.dark, psf, calibrated=dark_subtracted(psf_path),
        recorded=cam.dark_offset_dn, what=psf_path)
    options = options.replace(dark=level)  # the level resolved here
    if not LIVE_IN_PROCESS:
        return LiveReconstruction(LiveReconstructor(psf, options), live, threads=threads,
                                  nice=BACKGROUND_NICE), depth
    return LiveReconstructionProcess(psf, live, options=options, threads=threads,
                                     nice=BACKGROUND_NICE), depth


def stack_depths(psf_path: str) -> list[float]:
    """The depths (mm) of the planes of a PSF stack or calibration run; ``[]`` for a
    single PSF image or a path that is not a stack (offered as the depth field's
    choices, read on a worker)."""
    from instrument.runs.runstore import RunStoreError
    from instrument.runs.stacks import load_psf_stack
    from recon.errors import ReconInputError

    path = Path(psf_path.strip()) if psf_path.strip() else None
    if path is None or not path.exists() or path.suffix.lower() in (
            ".png", ".jpg", ".jpeg"):
        return []
    try:
        _, depths, _ = load_psf_stack(path)
    except (RunStoreError, ReconInputError, OSError, ValueError):
        return []  # not a stack: the depth field stays free
    return [float(z) for z in depths]


def routine_options(routine: str) -> list:
    """The parameters of ``calibrate ROUTINE``, in the command's order: the fields of
    its model (:data:`calibration_routines.parameters.PARAMETERS`), each an
    :class:`instrument.options.OptionSpec` (flag, type, default, choices, unit,
    limits, help)."""
    from calibration_routines.parameters import PARAMETERS

    return PARAMETERS[routine].specs()


def check_values(routine: str, values: dict[str, Any]) -> None:
    """Check the form's texts against ``calibrate ROUTINE``'s parameter model (no
    bench needed: on the GUI thread, before the run starts).

    Raises
    ------
    diffuserlab.errors.InputError
        A value the option does not accept (the message names the option and its
        limits).
    """
    from calibration_routines.parameters import PARAMETERS

    PARAMETERS[routine].from_text(values)


def default_run_path(routine: str, folder: str = "out/runs") -> str:
    """``out/runs/ROUTINE-YYYYmmdd-HHMMSS.zarr`` (what ``calibrate`` writes by default)."""
    return str(Path(folder) / f"{routine}-{_dt.datetime.now():%Y%m%d-%H%M%S}.zarr")


def run_plan(job, session, routine: str, values: dict[str, Any], path: str, control, *,
             overwrite: bool = False):
    """Run ``routine``'s plan, built from the form's ``values``, into a new store at
    ``path``, in the bench process (:func:`calibration_routines.bench_jobs.run_plan`)
    with the camera claimed; progress: ``{"kind": "planned", ...}``, then the runner's events.

    Returns
    -------
    instrument.acquisition.runner.RunResult

    Raises
    ------
    instrument.acquisition.plan.PlanError, diffuserlab.errors.InputError
        Parameters the plan refuses; a store at ``path`` already.
    """
    with session.camera_claimed("the calibration run"):
        return session.run_on_bench(
            "run_plan", {"routine": routine, "values": values, "path": path,
                                        "overwrite": overwrite},
            report=job.report, control=control)


def resume_plan(job, session, path: str, control, *, accept_differences: bool = False):
    """Resume the run at ``path`` in the bench process
    (:meth:`instrument.acquisition.runner.Runner.resume`,
    :func:`calibration_routines.bench_jobs.resume_plan`)."""
    with session.camera_claimed("the calibration run"):
        return session.run_on_bench(
            "resume_plan", {"path": path,
                                           "accept_differences": accept_differences},
            report=job.report, control=control)


def run_alignment(job, session, out: str, control, *, mask_seed: str = "", frames: int = 3,
                  focus: bool = True):
    """The mask alignment (:class:`calibration_routines.mask_alignment.MaskAligner`) on
    the session's bench, run in the bench process
    (:func:`calibration_routines.bench_jobs.run_alignment`) and recorded in ``out``;
    progress: ``{"kind": "event", ...}`` per step message and ``{"kind": "reading",
    ...}`` per spot reading.

    The parameters are ``align mask``'s model
    (:class:`calibration_routines.parameters.AlignMaskParams`), built from the panel's
    values. On the virtual bench the mask is misplaced as ``align mask --simulate``
    places it by default (the model's ``sim_*`` defaults), so there is something to
    align. The aligned mask stage stays where the alignment put it (the rest of the
    bench is put back).

    Returns
    -------
    dict
        The alignment report (:meth:`MaskAligner.run`).

    Raises
    ------
    diffuserlab.errors.InputError
        A mask seed that is not a whole number, fewer than 1 frame.
    instrument.acquisition.plan.PlanError
        No mask pattern on a real bench, an existing record, a bench without the
        holography devices.
    instrument.acquisition.runner.RunAborted
        Aborted (the record keeps every reading).
    """
    with session.camera_claimed("the mask alignment"):
        return session.run_on_bench(
            "run_alignment", {"out": out, "mask_seed": mask_seed,
                                             "frames": frames, "focus": focus},
            report=job.report, control=control)


def record(job, session, out: str, stop, *, frames: int | None, seconds: float | None,
           fps: float | None, exposure_s: float | None, live=None) -> dict:
    """Record a video run (:func:`instrument.acquisition.video.record_video`) in the bench process
    (:func:`instrument.bench.bench_jobs.record`) with the camera claimed (its settings put back and
    the live stream resumed afterwards). Its frames come to the window as the stream's
    do (the display and the live reconstruction, if running, take them); ``live``: that
    reconstruction, whose statistics each progress report carries as ``live``. On the
    virtual bench the run records the scene, seed and the camera's dark offset, as
    ``capture video --simulate`` does (``recon-run`` takes the dark level from it)."""
    simulated = ({"scene": session.scene_name, "seed": session.seed}
                 if session.is_virtual else None)
    options = {k: v for k, v in (("fps", fps), ("exposure_s", exposure_s)) if v is not None}

    def report(p: dict) -> None:
        if live is not None:
            p["live"] = live.stats()
        job.report(p)

    with session.camera_claimed("the video recording"):
        result = session.run_on_bench(
            "record", {"out": out, "frames": frames, "seconds": seconds,
                                      "options": options, "simulated": simulated},
            report=report, stop=stop)
    if live is not None and isinstance(result, dict):
        result["live"] = live.stats()
    return result


def batch_options(texts: dict[str, str]):
    """``recon-run``'s options from a form's ``{flag: text}``: each converted and
    checked by its one declaration (:class:`recon.options.ReconOptions` for the
    reconstruction, :class:`instrument.options.RunOptions` for the run's own:
    type, choices, limits, default, the checks between fields such as workers against
    a scheduler), no command line assembled; an empty text takes the declared default.
    As ``recon-run --psf RUN``, a scene-calibrated PSF run's recipe is the default
    (:func:`instrument.processing.reconstruct_files.scene_recipe_default`): ``recon.early_stop``
    then names it, unless the form declines it (``off``) or names a method, count or
    prior.

    Returns
    -------
    recon : recon.options.ReconOptions
        Only ``recon-run``'s fields set; the others at their defaults.
    own : instrument.options.RunOptions

    Raises
    ------
    gui.workers.InputError
        An unknown option, a value its type, choices or limits refuse, two options that
        exclude each other (the message names the option).
    """
    import diffuserlab.errors
    from instrument.options import COMMAND_FIELDS, GRID_FIELDS, RunOptions
    from recon.options import ReconOptions

    from .workers import InputError

    taken = (*COMMAND_FIELDS["recon-run"], *GRID_FIELDS["recon-run"])
    recon_flags = {s.flag for s in ReconOptions.specs() if s.dest in taken}
    run_flags = {s.flag for s in RunOptions.specs()}
    for flag in texts:
        if flag not in recon_flags | run_flags:
            raise InputError(f"recon-run has no option {flag}")
    try:
        rec = ReconOptions.from_text({f: v for f, v in texts.items() if f in recon_flags})
        own = RunOptions.from_text({f: v for f, v in texts.items() if f in run_flags})
    except diffuserlab.errors.InputError as exc:
        raise InputError(str(exc)) from None
    if str(own.psf or "").strip():
        from instrument.processing.reconstruct_files import scene_recipe_default

        rec = scene_recipe_default(own.psf, rec)
    return rec, own


def batch_reconstruct(job, run: str, recon, own) -> dict:
    """Reconstruct a recorded run with dask (:func:`instrument.processing.batch.reconstruct_run`),
    with ``recon-run``'s options (:func:`batch_options`), cancelled by the job.

    The batch runs in a child process
    (:func:`instrument.processing.batch_process.reconstruct_run_in_process`): dask's scheduler and
    client never live in the GUI's process, whose references, memory and interpreter
    lock each batch would otherwise take a share of for the rest of the session.

    Parameters
    ----------
    job : gui.workers.Job
    run : str
        The run store.
    recon : recon.options.ReconOptions
        The reconstruction's options (validated).
    own : instrument.options.RunOptions
        The run's own (PSF, depth, frames, workers, ...; validated).

    Raises
    ------
    gui.workers.InputError
        No PSF.
    instrument.runs.runstore.RunStoreError, recon.errors.ReconInputError
        From the run, the PSF or a frame's reconstruction (frames done are kept).
    """
    from instrument.processing.batch import batch_psf, parse_frames
    from instrument.processing.batch_process import reconstruct_run_in_process
    from instrument.runs.runstore import RunStore

    from .workers import InputError

    if not str(own.psf or "").strip():
        raise InputError("give the PSF to reconstruct with: an image, a PSF stack or a "
                         "calibration run (PSF sweep)")
    store = RunStore.open(run)
    frames = parse_frames(own.frames, store.n_frames)
    job.report({"kind": "start", "total": len(frames), "run": run})
    psf, dark, source = batch_psf(own.psf, store.attrs, depth_mm=own.depth_mm,
                                  psf_product=own.psf_product, dark=recon.dark)
    return reconstruct_run_in_process(
        run, psf, recon, dark=dark, frames=frames, product=own.product,
        workers=own.workers, scheduler=own.scheduler, dff_percentile=own.dff,
        overwrite=own.overwrite, psf_source=source, on_progress=job.report,
        cancel=job.cancel_event)
