"""``diffuserlab calibrate {dark,psf-sweep,psf-grid,psf-blind,angular-response,slm-lut,resume}``.

Registered with the ``diffuserlab`` command through the entry-point group
``diffuserlab.commands`` (so the instrument layer never imports this one). Each
routine opens the bench (``--simulate``: the virtual bench, which carries out the
operator's actions itself, built from the bench file or, without one, from the
built-in simulated bench; otherwise the real devices, and the operator is asked
at each prompt), runs the plan into a run store with a progress bar and ETA, and
prints the result. Ctrl-C aborts cleanly (LEDs off, stages stopped, data kept) and
prints the command that resumes the run; exit status 0 done, 1 failed, 130
interrupted; every error reaches the command line's one boundary
(:func:`instrument.cli.main`), as in every other command: bad input (an InputError, a
bench file's problems, a device that cannot be opened) 2, a device failing 1, and
any other exception is a bug, not bad input.

``slm-lut --apply`` also loads the fitted LUT onto the SLM at the end and prints a
blazed grating's first-order efficiency with the previous and the new LUT (mask
retracted); the LUT lasts for that session: load it later with
:func:`calibration_routines.slm_lut_io.apply_lut`.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import logging
import sys
import time
from pathlib import Path

from ..parameters import PARAMETERS
from .common import add_bench_arguments, make_bench

__all__ = ["add_subcommands", "plan_from_args", "run"]

#: The routines, in the order of their parameter models.
ROUTINES = tuple(PARAMETERS)


def _common(p: argparse.ArgumentParser, *, resume: bool = False) -> None:
    if resume:
        p.add_argument("run", help="the run store to continue (RUN.zarr)")
    add_bench_arguments(p)
    p.add_argument("--reconnect-timeout", type=float, default=30.0, dest="reconnect_timeout_s",
                   help="seconds to keep reconnecting a device that disconnected (default 30)")
    if not resume:
        p.add_argument("--out", default=None, help="run store to create (default "
                       "out/runs/ROUTINE-TIME.zarr)")
        p.add_argument("--note", default="", help="operator's note stored with the run")
        p.add_argument("--overwrite", action="store_true", help="replace an existing --out")


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` and its routines to the ``diffuserlab`` subparsers."""
    cp = sub.add_parser("calibrate", help=f"calibration routines ({', '.join(PARAMETERS)}) "
                        "and resuming them")
    csub = cp.add_subparsers(dest="routine", required=True)
    for name, model in PARAMETERS.items():
        rp = csub.add_parser(name, help=model.summary)
        _common(rp)
        if name == "psf-grid":  # the sigma given, or read from an angular-response run
            fall = rp.add_mutually_exclusive_group()
            model.add_arguments(rp, {"falloff_sigma_deg": fall})
            fall.add_argument("--falloff-run", default=None,
                              help="angular-response run to take the fall-off sigma from")
        else:
            model.add_arguments(rp)
        if name == "psf-from-scenes":  # pairs from files instead of the bench
            rp.add_argument("--scenes", nargs="+", default=None, metavar="PATH",
                            help="known scenes on the sensor grid: image files or "
                            "directories (.npy, .tif, .png); with --measurements, no bench")
            rp.add_argument("--measurements", nargs="+", default=None, metavar="PATH",
                            help="their measurements (dark-subtracted), matched by file name")
        if name == "slm-lut":
            rp.add_argument("--apply", action="store_true",
                            help="load the new LUT onto the SLM and compare a blazed "
                            "grating's first-order efficiency with the previous LUT")
    rp = csub.add_parser("resume", help="continue an aborted, failed or killed run")
    _common(rp, resume=True)
    rp.add_argument("--redo", default="", metavar="POINT[,POINT...]",
                    help="capture these plan points again (e.g. a point with a damaged "
                    "frame, see `diffuserlab runs verify`) before resuming")
    rp.add_argument("--accept-differences", action="store_true",
                    help="resume although the set-up differs from the recorded one in "
                    "harmless ways (a serial port or address, the bench name, calibration "
                    "defaults, the software version; recorded with the resume). Another "
                    "geometry, device set or driver parameter is always refused")
    cp.set_defaults(handler=run)


def plan_from_args(args, bench):
    """The calibration plan ``calibrate ROUTINE`` runs, built from its parsed options
    through the routine's parameter model
    (:data:`calibration_routines.parameters.PARAMETERS`).

    Parameters
    ----------
    args : argparse.Namespace
        The options of ``calibrate`` (``routine``, ``seed`` and the routine's own).
    bench : instrument.devices.bench.Bench or instrument.devices.virtual_bench.VirtualBench
        The open bench (plans read its devices and geometry).

    Returns
    -------
    instrument.acquisition.plan.Plan

    Raises
    ------
    diffuserlab.errors.InputError
        A parameter outside its declared limits (the message names the option).
    instrument.acquisition.plan.PlanError, recon.errors.ReconInputError
        Options a plan refuses (the message names the option).
    """
    return PARAMETERS[args.routine].from_namespace(args).plan(bench, seed=args.seed)


def _routine_params(args, routine: str) -> dict | None:
    """The parameters of ``routine`` as given on the command line (an argparse
    namespace) or, for ``resume``, as the run being resumed recorded them; None for
    another routine or an unreadable run (the resume itself reports that)."""
    from instrument.runs.runstore import RunStore, RunStoreError

    if args.routine == routine:
        return vars(args)
    if args.routine != "resume":
        return None
    try:
        plan = RunStore.open(args.run).attrs["plan"]
    except (RunStoreError, OSError):
        return None
    return plan["params"] if plan.get("name") == routine else None


def _bead_slide(bench, args) -> None:
    """The virtual bench's bead slide for ``psf-blind --simulate`` (and for resuming a
    psf-blind run on it): 8 beads (seeded by ``--seed``) over the node grid's field,
    carried by the source stage. Nothing for the other routines."""
    import numpy as np

    from instrument.devices.virtual_bench import BeadScene

    params = _routine_params(args, "psf-blind")
    if params is None:
        return
    if args.routine == "psf-blind":
        spacing, grid = params["node_spacing_mm"], params["grid"]
    else:
        spacing, grid = params["node_spacing_mm"], params["grid_shape"][0]
    rng = np.random.default_rng([args.seed, 0x51])
    half = spacing * (grid - 1) / 2
    xy = rng.uniform(-half, half, (8, 2))
    points = np.column_stack([xy, np.zeros(8)])
    bench.set_scene(BeadScene(points, np.full(8, bench.source_power), on_stage=True))


def _display_scene(bench, args) -> None:
    """The virtual bench's display facing the camera at ``--z-mm`` for
    ``psf-from-scenes --simulate`` (and for resuming such a run): what the display
    device shows is the scene. Nothing for the other routines."""
    from instrument.devices.virtual_bench import DisplayScene

    params = _routine_params(args, "psf-from-scenes")
    if params is not None:
        bench.set_scene(DisplayScene(params["z_mm"], params["display"]))


def _falloff_sigma_deg(path: str) -> float:
    """The widest fall-off sigma (degrees) a complete angular-response run measured.

    Raises
    ------
    PlanError
        ``path`` is a run of another routine, or incomplete, or lacks the fit.
    """
    from instrument.acquisition.plan import PlanError
    from instrument.runs.runstore import RunStore

    from ..angular_response import AngularResponsePlan

    store = RunStore.open(path)
    name = store.attrs["plan"]["name"]
    fix = ("pass a complete `calibrate angular-response` run, or give the sigma with "
           "--falloff-sigma-deg")
    if name != AngularResponsePlan.name:
        raise PlanError(f"--falloff-run {path} is a {name!r} run, not an angular-response run; "
                        f"{fix}")
    axes = (store.attrs.get("summary") or {}).get("axes") or {}
    sigmas = [a.get("sigma_deg") for a in axes.values() if isinstance(a, dict)]
    if store.status != "complete" or not sigmas or None in sigmas:
        raise PlanError(f"--falloff-run {path} holds no fitted fall-off (status "
                        f"{store.status!r}); {fix}")
    return float(max(sigmas))


def _progress(total: int, initial: int):
    """A run's event handler drawing a progress bar; the bar appears with the run's
    first event, so a run refused before it starts prints only its error line."""
    from tqdm import tqdm

    bar = None

    def on_event(e) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, initial=initial, unit="frame", dynamic_ncols=True)
        if e.kind == "frame":
            bar.update(e.frames_done - bar.n)
            bar.set_postfix_str(f"point {e.point + 1}/{e.points_total}")
        elif e.kind in ("reconnecting", "reconnected", "retrying", "paused", "resumed"):
            bar.write(f"{e.kind}: {e.message}")
        elif e.kind in ("completed", "aborted", "failed"):
            bar.close()

    def close() -> None:  # a run that raised: its error line starts a line of its own
        if bar is not None:
            bar.close()

    on_event.close = close
    return on_event


def _apply_lut(bench, plan, path) -> bool:
    """Blazed-grating efficiency with the SLM's LUT, apply the new one, again; False
    (reason on stderr) if a device failed."""
    from drivers.errors import DeviceError

    from ..slm_lut_io import apply_lut, blazed_efficiency, load_lut

    lut = load_lut(path)
    try:
        with plan.session(bench):
            before = blazed_efficiency(bench, lut)
            apply_lut(bench.slm, lut)
            after = blazed_efficiency(bench, lut)
    except DeviceError as exc:
        print(f"diffuserlab: error: the LUT was calibrated ({path}) but --apply failed: "
              f"{exc}", file=sys.stderr)
        return False
    print(f"blazed grating (period {lut.attrs['period_px']} px) first-order efficiency: "
          f"{before:.3f} with the previous LUT, {after:.3f} with the calibrated one; the "
          f"LUT is on {bench.slm.device_id} for this session - load it later with "
          f"calibration_routines.slm_lut_io.apply_lut(bench.slm, '{path}')")
    return True


def _psf_from_files(args, check_outputs) -> int:
    """``calibrate psf-from-scenes --scenes ... --measurements ...``: no bench; a line per
    step as it ends (``[done/total] what (seconds)``: the PSF, each pair's held-out PSF,
    each solve of the recipe's fit), one line
    per pair (its fit and held-out residuals per channel), then the run's summary
    (``check_outputs``: the outputs' guard of :func:`run`)."""
    from diffuserlab.errors import InputError
    from instrument.cli.runs import format_summary

    from ..psf_from_scenes import psf_run_from_files

    if not args.scenes or not args.measurements:
        raise InputError("psf-from-scenes from files takes both --scenes and --measurements "
                         "(or neither, to show the scenes on the bench's display)")
    if args.bench is not None or args.simulate:
        raise InputError("psf-from-scenes from files opens no bench: leave out the bench "
                         "file and --simulate, or --scenes and --measurements")
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.out or f"out/runs/{args.routine}-{stamp}.zarr")
    inputs = {f"{option} {path}": path for option, paths in (
        ("--scenes", args.scenes), ("--measurements", args.measurements)) for path in paths}
    check_outputs([out], inputs, args.overwrite, store=True)
    params = PARAMETERS[args.routine].from_namespace(args)

    def on_pair(name, fit, held) -> None:
        held_text = ("" if held is None else
                     "  held-out " + " ".join(f"{v:.3f}" for v in held))
        print(f"{name}: fit {' '.join(f'{v:.3f}' for v in fit)}{held_text}")

    started = time.monotonic()

    def on_progress(done, total, what) -> None:  # one line a step: the fit takes minutes
        print(f"[{done}/{total}] {what} ({time.monotonic() - started:.0f} s)", flush=True)

    store = psf_run_from_files(args.scenes, args.measurements, out, z_mm=params.z_mm,
                               note=args.note, overwrite=args.overwrite, on_pair=on_pair,
                               on_progress=on_progress, iterations=params.iterations)
    recipe = store.attrs.get("summary", {}).get("early_stop")
    if recipe:
        print(recipe_line(recipe))
    print(format_summary(store.summary()))
    return 0


def recipe_line(recipe: dict) -> str:
    """One line on a calibration's recipe (its summary record, ``early_stop``): what
    ``recon --psf RUN`` will run, and whether the field response was kept."""
    gain = recipe.get("field_gain_db")
    field = ("" if gain is None else
             f", field response {'kept' if recipe.get('field_response') else 'not kept'} "
             f"({gain:+.2f} dB on held-out pairs)")
    denoise = (f"TV denoising {recipe['denoise_weight']:g}" if recipe["denoise_weight"]
               else "no denoising")
    trusted = "" if recipe.get("trusted", True) else " (not trusted: no default)"
    return (f"recipe{trusted}: FISTA {recipe['iterations']} iterations, {denoise}{field}")


def _run_whole_or_nothing(runner, plan, out, **options):
    """``runner.run(plan, out)``; a new run that fails before it stored a frame (a full
    disk while its camera record is written, say) is removed instead of left half-made.
    A run holding frames is kept (its data are the operator's; it resumes), and so is
    a run this process did not create (another process's, created at ``out``
    meanwhile: this one is refused)."""
    from instrument.atomic import missing_dirs, remove_empty_dirs
    from instrument.runs.runstore import RunStoreError, discard_partial_run

    made = missing_dirs(out)
    try:
        return runner.run(plan, out, **options)
    except BaseException:
        store = runner.created  # None: refused, or create removed its own half-made run
        if store is None:
            remove_empty_dirs(made)
            raise
        try:
            empty = not store.done().any()
        except RunStoreError:  # its bookkeeping was not even written whole
            empty = True
        if empty:
            discard_partial_run(out, made, token=store.creation_token)
        raise


def run(args: argparse.Namespace) -> int:
    """Run ``calibrate ROUTINE``; returns the exit status (module docstring)."""
    from calibration_routines import register_plans
    from diffuserlab.errors import InputError
    from instrument.acquisition.runner import Runner
    from instrument.cli.runs import format_summary
    from instrument.runs.runstore import RunStore, RunStoreError, is_run_store
    from instrument.runs.runstore_records import video_cannot_continue
    from instrument.writer.guards import check_outputs

    if not 0 <= args.reconnect_timeout_s < float("inf"):  # NaN fails; every wait ends
        raise InputError(f"--reconnect-timeout {args.reconnect_timeout_s}: give the seconds "
                         "to keep reconnecting a device, finite and >= 0")
    if getattr(args, "scenes", None) is not None or getattr(args, "measurements", None):
        return _psf_from_files(args, check_outputs)
    out = None
    if args.routine != "resume":  # outputs and input runs checked before the bench opens
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        out = Path(args.out or f"out/runs/{args.routine}-{stamp}.zarr")
        if args.overwrite and out.exists() and not is_run_store(out):
            raise InputError(f"not replacing {out}: it is not a diffuserlab run store "
                             "(--overwrite only replaces a run); choose another --out or "
                             "remove it yourself")
        check_outputs([out], {"--falloff-run": getattr(args, "falloff_run", None)},
                      args.overwrite, store=True)
        if getattr(args, "falloff_run", None):
            args.falloff_sigma_deg = _falloff_sigma_deg(args.falloff_run)
        PARAMETERS[args.routine].from_namespace(args)  # limits, before the bench opens
    else:  # a recording is never continued: said before the bench opens
        try:
            why = video_cannot_continue(RunStore.open(args.run))
        except (RunStoreError, OSError):
            why = None  # the resume itself reports an unreadable run
        if why is not None:
            raise InputError(why)
    if not getattr(args, "verbose", False):  # device chatter would break the progress bar
        logging.getLogger("drivers").setLevel(logging.WARNING)
        logging.getLogger("instrument").setLevel(logging.WARNING)
    bench = make_bench(args, f"calibrate {args.routine}")  # errors: the CLI's boundary
    if args.simulate:
        bench.open()
        _bead_slide(bench, args)
        _display_scene(bench, args)
    applied = True  # slm-lut --apply: False if loading the LUT onto the SLM failed
    bars = None
    try:
        with bench:
            if args.routine == "resume":
                store = RunStore.open(args.run)
                events = bars = _progress(store.n_frames, int(store.done().sum()))
                runner = Runner(bench, on_event=events,
                                reconnect_timeout_s=args.reconnect_timeout_s)
                try:
                    redo = [int(v) for v in args.redo.split(",") if v.strip()]
                except ValueError:
                    raise InputError(f"--redo {args.redo!r}: give point numbers separated "
                                     "by commas, e.g. --redo 3,7") from None
                register_plans()  # the run's plan is rebuilt from its recorded name
                result = runner.resume(args.run, redo=redo,
                                       accept_differences=args.accept_differences)
            else:
                plan = plan_from_args(args, bench)
                total = sum(len(p.tags) for p in plan.points())
                bars = _progress(total, 0)
                runner = Runner(bench, on_event=bars,
                                reconnect_timeout_s=args.reconnect_timeout_s)
                result = _run_whole_or_nothing(runner, plan, out, note=args.note,
                                               overwrite=args.overwrite)
                if getattr(args, "apply", False) and result.status == "complete":
                    applied = _apply_lut(bench, plan, result.path)
    finally:
        if bars is not None:
            bars.close()
    print(format_summary(RunStore.open(result.path).summary()))
    if result.status == "complete":
        return 0 if applied else 1
    for action in result.pending_actions:
        print(f"not resuming? then first: {action}", file=sys.stderr)
    bench_arg = "" if args.bench is None else f" {args.bench}"
    sim = " --simulate" if args.simulate else ""
    where = (f"at point {result.points_done + 1} of {result.points_total}"
             if result.points_done < result.points_total else
             f"after all {result.points_total} points (computing the products)")
    print(f"\n{result.status} {where}: {result.error}\nthe data so far is kept; resume "
          f"with:\n  diffuserlab calibrate resume {result.path}{bench_arg}{sim}",
          file=sys.stderr)
    return 130 if result.status == "aborted" else 1
