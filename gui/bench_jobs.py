"""The window's jobs as the bench process runs them (no Qt here).

Each function is ``function(ctx, **kwargs)`` with an
:class:`instrument.bench_host.JobContext` (``ctx.bench``, ``ctx.report``,
``ctx.control``, ``ctx.stop``, ``ctx.cancel``, ``ctx.publish``), started by
:meth:`instrument.bench_process.BenchClient.run_job` from :mod:`gui.jobs` and
:mod:`gui.session`: opening and closing the bench, the virtual bench's scene, a
calibration run (:class:`instrument.runner.Runner`), the mask alignment
(:class:`calibration_routines.mask_alignment.MaskAligner`) and a video recording
(:func:`instrument.video.record_video`). They run where the devices are, so their
compute and device waits never share the window's interpreter lock.

A job that changes the bench to take its measurement gives it back as it was
(:func:`kept`, :mod:`gui.benchstate`), except the state it exists to produce.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any

__all__ = ["ALIGNMENT_STEPS", "build_plan", "close_bench", "kept", "open_bench", "record",
           "resume_plan", "run_alignment", "run_plan", "section_summary", "set_scene"]

#: The mask alignment's steps, in order (the names its events and record use).
ALIGNMENT_STEPS = ("preflight", "coarse", "translation", "rigid", "focus", "piecewise",
                   "verify")


def open_bench(ctx, *, bench_path: str | None, simulate: bool, seed: int,
               scene: str) -> dict:
    """Open the bench of ``bench_path`` (``simulate``: the real-time virtual bench with
    ``scene`` in front of its camera) and make it the host's; returns
    :meth:`~instrument.bench_host.BenchHost.describe`. A real bench's prompts go to the
    operator (:meth:`~instrument.bench_host.BenchHost.ask`); ``ctx.cancel`` stops the
    opening (homing included)."""
    from instrument.bench import Bench
    from instrument.cli.common import bench_config
    from instrument.virtual_bench import VirtualBench

    config = bench_config(bench_path, simulate=simulate, command="gui")
    if not simulate:
        bench = Bench.open(config, on_prompt=ctx.host.ask, cancel=ctx.cancel)
    else:
        bench = VirtualBench(config, seed=seed, realtime=True).open()
        bench.led_array.all_off()
        show_scene(bench, scene)
    ctx.host.open_bench(bench)
    return ctx.host.describe()


def close_bench(ctx) -> None:
    """Stop the stream and every job, and close the devices."""
    ctx.host.close()


def show_scene(bench, name: str) -> None:
    """Put the moving scene ``name`` (``"none"``: nothing) in front of the virtual
    bench's camera, as ``capture --simulate --scene`` does."""
    from instrument.bench_scenes import show_video_scene

    if name == "none":
        bench.set_scene(None)
        return
    show_video_scene(bench, name, seed=bench.seed)


def set_scene(ctx, *, name: str) -> None:
    """:func:`show_scene` on the host's bench (rendered ahead here)."""
    show_scene(ctx.bench, name)


@contextmanager
def kept(ctx, *, sample_out: bool = True, produces: tuple[str, ...] = ()):
    """Give the bench back as it was: the camera's settings, the stages' positions and
    the LEDs put back (:func:`gui.benchstate.restore`, also after an abort or a
    failure; not while the window closes: the devices close next).

    ``produces``: the devices whose state is the job's result (the mask stage of the
    mask alignment), left as the job set them when it completes, and put back only
    when it was aborted or failed (a half-done alignment is no pose to keep); what the
    job changed only to take its measurement (exposure, LEDs, other stages) is put back
    either way.

    ``sample_out``: on the virtual bench, take the moving scene out of the beam for the
    run (as an operator removes the sample) and put it back."""
    from .benchstate import capture, restore

    bench = ctx.bench
    scene = getattr(bench, "scene", None) if sample_out else None
    before = capture(bench)
    if scene is not None:
        bench.set_scene(None)
    completed = False
    try:
        yield
        completed = True
    finally:
        if scene is not None:
            bench.set_scene(scene)
        if not ctx.host.closing:
            restore(bench, before.without(produces) if completed else before)


def build_plan(bench, routine: str, values: dict[str, Any]):
    """The plan ``calibrate ROUTINE`` would run with ``values``: the routine's parameter
    model built from the form's texts, handed to its plan.

    Parameters
    ----------
    bench : instrument.bench.Bench
        Open.
    routine : str
        One of :data:`gui.jobs.ROUTINES`.
    values : dict
        ``{option flag: text}`` for the options the operator set (empty text: the
        default); flags map to True/False.

    Raises
    ------
    diffuserlab.errors.InputError
        A value the option does not accept (the message names the option and its
        limits).
    instrument.plan.PlanError
        Parameters the plan refuses.
    """
    from calibration_routines.parameters import PARAMETERS

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


def run_plan(ctx, *, routine: str, values: dict[str, Any], path: str,
             overwrite: bool = False):
    """Build ``routine``'s plan from the form's ``values`` and run it into a new store
    at ``path``; the first progress is ``{"kind": "planned", "total": frames,
    "light_frames": bool}``, then the runner's events.

    Returns
    -------
    instrument.runner.RunResult
    """
    from instrument.output_safety import check_outputs
    from instrument.runner import Runner

    plan = build_plan(ctx.bench, routine, values)
    points = plan.points()
    ctx.report({"kind": "planned", "total": sum(len(p.tags) for p in points),
                "light_frames": any(t != "dark" for p in points for t in p.tags)})
    check_outputs([path], {}, overwrite, store=True)
    with kept(ctx):
        runner = Runner(ctx.bench, control=ctx.control,
                        on_event=_tagged(ctx.report, lambda i: points[i].tags))
        return runner.run(plan, path, overwrite=overwrite)


def resume_plan(ctx, *, path: str, accept_differences: bool = False):
    """Resume the run at ``path`` (:meth:`instrument.runner.Runner.resume`)."""
    from calibration_routines import register_plans
    from instrument.runner import Runner
    from instrument.runstore import RunStore

    register_plans()  # resuming rebuilds the plan from its recorded name
    store = RunStore.open(path)

    def tags_of_point(point: int) -> list[str]:
        return [store.tag_of(i) for i in store.frame_range(point)]

    with kept(ctx):
        runner = Runner(ctx.bench, control=ctx.control,
                        on_event=_tagged(ctx.report, tags_of_point))
        return runner.resume(path, accept_differences=accept_differences)


def run_alignment(ctx, *, out: str, mask_seed: str = "", frames: int = 3,
                  focus: bool = True) -> dict:
    """The mask alignment (:class:`calibration_routines.mask_alignment.MaskAligner`) on
    the host's bench, recorded in ``out``; progress: ``{"kind": "event", ...}`` per
    step message and ``{"kind": "reading", ...}`` per spot reading. See
    :func:`gui.jobs.run_alignment`."""
    from calibration_routines import mask_alignment
    from calibration_routines.cli.align import simulated_truth
    from calibration_routines.holo_bench import holography_branch
    from calibration_routines.parameters import AlignMaskParams
    from instrument.plan import PlanError
    from recon.optics.holo_display import MaskModel

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


class _Publisher:
    """What :func:`instrument.video.record_video` offers each recorded frame to: the
    window (:meth:`~instrument.bench_host.JobContext.publish`), whose reader hands it
    to the display and the live reconstruction as it does the stream's."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx

    def start(self) -> None:
        pass

    def stop(self, timeout_s: float = 5.0) -> None:
        pass

    def offer(self, frame) -> None:
        self.ctx.publish(frame)

    def stats(self) -> None:
        return None


def record(ctx, *, out: str, frames: int | None, seconds: float | None,
           options: dict[str, float], simulated: dict | None = None) -> dict:
    """Record a video run (:func:`instrument.video.record_video`), the bench given back
    after (the sample stays); ``simulated``: the virtual bench's scene and seed, with
    the camera's dark offset added here, as ``capture video --simulate`` records."""
    from instrument.video import record_video

    attrs = {}
    if simulated is not None:
        attrs["simulated"] = {**simulated,
                              "dark_offset_dn": float(ctx.bench.camera.dark_offset_dn)}
    with kept(ctx, sample_out=False):
        return record_video(ctx.bench, out, frames=frames, seconds=seconds, stop=ctx.stop,
                            on_progress=ctx.report, progress_every_s=0.25,
                            live=_Publisher(ctx), **options, **attrs)
