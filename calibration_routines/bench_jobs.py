"""The calibration runs and the mask alignment as the bench process runs them (no Qt).

Jobs of :class:`instrument.bench.bench_host.BenchHost` (``function(ctx, **params)``, see
:mod:`instrument.bench.bench_jobs`): a calibration run
(:class:`instrument.acquisition.runner.Runner`),
its resumption and the mask alignment
(:class:`calibration_routines.mask_alignment.MaskAligner`). The client that starts
the bench process hands them over by name (:data:`JOBS`, ``BenchClient(jobs=JOBS)``;
the window's ``gui.session.Session`` does), since the instrument layer does not
import this package. Each holds every device of the bench while it runs
(:func:`instrument.bench.bench_jobs.holding`): another client's job that needs one is
refused, and the live view yields the camera to it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from instrument.bench.bench_jobs import holding, kept

__all__ = ["ALIGNMENT_STEPS", "JOBS", "build_plan", "resume_plan", "run_alignment",
           "run_plan", "section_summary"]

#: The mask alignment's steps, in order (the names its events and record use).
ALIGNMENT_STEPS = ("preflight", "coarse", "translation", "rigid", "focus", "piecewise",
                   "verify")


def build_plan(bench, routine: str, values: dict[str, Any]):
    """The plan ``calibrate ROUTINE`` would run with ``values``: the routine's parameter
    model built from the form's texts, handed to its plan.

    Parameters
    ----------
    bench : instrument.devices.bench.Bench
        Open.
    routine : str
        One of ``gui.jobs.ROUTINES``.
    values : dict
        ``{option flag: text}`` for the options the operator set (empty text: the
        default); flags map to True/False.

    Raises
    ------
    diffuserlab.errors.InputError
        A value the option does not accept (the message names the option and its
        limits).
    instrument.acquisition.plan.PlanError
        Parameters the plan refuses.
    """
    from .parameters import PARAMETERS

    return PARAMETERS[routine].from_text(values).plan(bench)


def _tagged(report, tags_of_point):
    """The runner's event handler: ``report(event)`` with ``event.tag``, the plan's tag
    of each captured frame (``psf``, ``dark``, ...; None on other events), so the panel
    can show the frames of interest as they are taken."""
    seen = {"point": None, "k": 0}

    def on_event(e) -> None:
        e.tag = None
        if e.kind == "frame" and e.point is not None:
            if e.point != seen["point"]:
                seen.update(point=e.point, k=0)
            tags = tags_of_point(e.point)
            e.tag = tags[seen["k"]] if seen["k"] < len(tags) else None
            seen["k"] += 1
        report(e)

    return on_event


@holding("*")
def run_plan(ctx, *, routine: str, values: dict[str, Any], path: str,
             overwrite: bool = False):
    """Build ``routine``'s plan from the form's ``values`` and run it into a new store
    at ``path``; the first progress is ``{"kind": "planned", "total": frames,
    "light_frames": bool}``, then the runner's events.

    Returns
    -------
    instrument.acquisition.runner.RunResult
    """
    from instrument.acquisition.runner import Runner
    from instrument.writer.guards import check_outputs

    plan = build_plan(ctx.bench, routine, values)
    points = plan.points()
    ctx.report({"kind": "planned", "total": sum(len(p.tags) for p in points),
                "light_frames": any(t != "dark" for p in points for t in p.tags)})
    check_outputs([path], {}, overwrite, store=True)
    with kept(ctx):
        runner = Runner(ctx.bench, control=ctx.control,
                        on_event=_tagged(ctx.report, lambda i: points[i].tags))
        return runner.run(plan, path, overwrite=overwrite)


@holding("*")
def resume_plan(ctx, *, path: str, accept_differences: bool = False):
    """Resume the run at ``path`` (:meth:`instrument.acquisition.runner.Runner.resume`)."""
    from instrument.acquisition.runner import Runner
    from instrument.runs.runstore import RunStore

    from . import register_plans

    register_plans()  # resuming rebuilds the plan from its recorded name
    store = RunStore.open(path)

    def tags_of_point(point: int) -> list[str]:
        return [store.tag_of(i) for i in store.frame_range(point)]

    with kept(ctx):
        runner = Runner(ctx.bench, control=ctx.control,
                        on_event=_tagged(ctx.report, tags_of_point))
        return runner.resume(path, accept_differences=accept_differences)


@holding("*")
def run_alignment(ctx, *, out: str, mask_seed: str = "", frames: int = 3,
                  focus: bool = True) -> dict:
    """The mask alignment (:class:`calibration_routines.mask_alignment.MaskAligner`) on
    the host's bench, recorded in ``out``; progress: ``{"kind": "event", ...}`` per
    step message and ``{"kind": "reading", ...}`` per spot reading. See
    ``gui.jobs.run_alignment``."""
    from instrument.acquisition.plan import PlanError
    from recon.optics.holo_display import MaskModel

    from . import mask_alignment
    from .cli.align import simulated_truth
    from .holo_bench import holography_branch
    from .parameters import AlignMaskParams

    bench = ctx.bench
    virtual = hasattr(bench, "set_scene")
    args = AlignMaskParams.from_text({"--mask-seed": mask_seed, "--frames": str(frames),
                                      "--no-focus": not focus})
    if not virtual and args.mask_seed is None:
        raise PlanError("on a real bench, give the installed mask's seed (or run `diffuserlab "
                        "align mask --mask-pattern FILE.npy`)")

    class _Record(mask_alignment.AlignmentRecord):
        def log(self, entry: dict) -> None:
            super().log(entry)
            ctx.report({"kind": "reading", "eta": entry.get("eta"), "pose": entry.get("pose"),
                        "step": entry.get("step")})

    with kept(ctx, produces=("mask_stage",)), holography_branch(bench):
        relay_na = bench.relay_na if virtual else args.relay_na
        cfg = mask_alignment.AlignmentConfig(
            coarse_range_px=args.coarse_range_px, frames=args.frames,
            rotation=not args.no_rotation, focus=not args.no_focus, relay_na=relay_na,
            focus_range_mm=args.focus_range_mm)
        if virtual:
            bench.hologram.mask.truth = simulated_truth(args)
            seed = bench.hologram.mask.seed if args.mask_seed is None else args.mask_seed
        else:
            seed = args.mask_seed
        slm = bench.slm
        model = MaskModel(slm.resolution, slm.pixel_pitch_um, args.k, 4, seed,
                          margin=args.mask_margin)
        record = _Record(out)
        aligner = None

        def on_event(step: str, message: str, data: dict) -> None:
            steps = aligner.state["steps"] if aligner is not None else {}
            ctx.report({"kind": "event", "step": step, "message": message,
                        "done": list(steps), "steps": section_summary(steps)})

        aligner = mask_alignment.MaskAligner(bench, model, cfg, record=record,
                                             control=ctx.control, on_event=on_event)
        report = aligner.run()
        ctx.report({"kind": "event", "step": "verify", "message": "completed",
                    "done": list(report["steps"]), "steps": section_summary(report["steps"])})
        return report


def section_summary(steps: dict) -> dict:
    """Per-section offsets (rigid step, mask px), integer shifts (piecewise) and
    efficiency ratios (verify) found so far."""
    out: dict = {}
    rigid = steps.get("rigid")
    if rigid and rigid.get("rounds"):
        out["offsets_px"] = [list(map(float, s["offset"])) for s in rigid["rounds"][-1]["sections"]]
    if "verify" in steps:
        out["eta_ratio"] = [float(v) for v in steps["verify"]["eta_ratio"]]
    return out


#: The jobs of this module by name (:meth:`instrument.bench.bench_host.BenchHost.start_job`).
JOBS: dict[str, Callable] = {"run_plan": run_plan, "resume_plan": resume_plan,
                             "run_alignment": run_alignment}
