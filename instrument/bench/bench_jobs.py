"""The jobs the bench process runs, by name (no Qt here).

Each job is ``function(ctx, **params)`` with an
:class:`instrument.bench.bench_host.JobContext` (``ctx.bench``, ``ctx.report``,
``ctx.control``, ``ctx.stop``, ``ctx.cancel``, ``ctx.publish``), started by name with
:meth:`instrument.bench.bench_process.BenchClient.run_job`. :data:`JOBS` holds the
instrument's own: opening and closing the bench, the virtual bench's scene and a video
recording (:func:`instrument.acquisition.video.record_video`). Jobs of the packages above (the
calibration runs and the mask alignment of
:mod:`calibration_routines.bench_jobs`) are handed to the client that starts the bench
process (``BenchClient(jobs=...)``), an import the layer contracts see. They run where
the devices are, so their compute and device waits never share the window's
interpreter lock.

A job that changes the bench to take its measurement gives it back as it was
(:func:`kept`, :mod:`instrument.bench.bench_state`), except the state it exists to produce.
A job declares the devices it holds while it runs (:func:`holding`) and takes only the
parameters its signature names (:func:`instrument.bench.bench_job_handle.check_params`).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import contextmanager
from typing import Any

__all__ = ["JOBS", "RECORD_OPTIONS", "close_bench", "holding", "kept", "open_bench", "record",
           "set_scene", "show_scene"]


def holding(*devices: str, check: Callable[[dict], None] | None = None):
    """Declare what a job holds while it runs: ``devices``, device ids or roles
    (``"camera"``; ``"*"``: every device of the bench). The bench process refuses a job
    whose devices another job holds, before anything touches them, and the live stream
    yields the camera to it (:meth:`instrument.bench.bench_host.BenchHost.start_job`); a job
    that declares nothing holds nothing. ``check(params)``, if given, refuses bad
    parameters before the job starts (raising
    :class:`~instrument.bench.bench_service.BenchServiceError`).

    Returns
    -------
    callable
        A decorator that sets ``fn.holds`` (and ``fn.check``) and returns ``fn``.
    """
    def mark(fn: Callable) -> Callable:
        fn.holds = tuple(devices)
        if check is not None:
            fn.check = check
        return fn

    return mark


def open_bench(ctx, *, bench_path: str | None, simulate: bool, seed: int,
               scene: str) -> dict:
    """Open the bench of ``bench_path`` (``simulate``: the real-time virtual bench with
    ``scene`` in front of its camera) and make it the host's; returns
    :meth:`~instrument.bench.bench_host.BenchHost.describe`. A real bench's prompts go to the
    operator (:meth:`~instrument.bench.bench_host.BenchHost.ask`); ``ctx.cancel`` stops the
    opening (homing included)."""
    from ..devices.bench import Bench
    from ..devices.virtual_bench import VirtualBench

    config = _bench_config(bench_path, simulate)
    if not simulate:
        bench = Bench.open(config, on_prompt=ctx.host.ask, cancel=ctx.cancel)
    else:
        bench = VirtualBench(config, seed=seed, realtime=True).open()
        bench.led_array.all_off()
        show_scene(bench, scene)
    ctx.host.open_bench(bench)
    return ctx.host.describe()


def _bench_config(path: str | None, simulate: bool):
    """The bench file's configuration; none with ``simulate``: the built-in simulated
    bench.

    Raises
    ------
    instrument.bench.bench_service.BenchServiceError
        No file and no ``simulate``.
    instrument.config.BenchConfigError
        The file has problems (every one listed).
    """
    from ..config import default_bench
    from .bench_service import BenchServiceError

    if path is None:
        if not simulate:
            raise BenchServiceError("give a bench file (BENCH.toml), or --simulate for the "
                                    "built-in simulated bench")
        return default_bench()
    from ..devices.bench_setup import load_bench

    return load_bench(path, simulate=simulate)


def close_bench(ctx) -> None:
    """Stop the stream and every job, and close the devices."""
    ctx.host.close()


def show_scene(bench, name: str) -> None:
    """Put the moving scene ``name`` (``"none"``: nothing) in front of the virtual
    bench's camera, as ``capture --simulate --scene`` does."""
    from ..devices.bench_scenes import show_video_scene

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
    the LEDs put back (:func:`instrument.bench.bench_state.restore`, also after an abort or a
    failure; not while the window closes: the devices close next).

    ``produces``: the devices whose state is the job's result (the mask stage of the
    mask alignment), left as the job set them when it completes, and put back only
    when it was aborted or failed (a half-done alignment is no pose to keep); what the
    job changed only to take its measurement (exposure, LEDs, other stages) is put back
    either way.

    ``sample_out``: on the virtual bench, take the moving scene out of the beam for the
    run (as an operator removes the sample) and put it back."""
    from .bench_state import capture, restore

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


class _Publisher:
    """What :func:`instrument.acquisition.video.record_video` offers each recorded frame to: the
    window (:meth:`~instrument.bench.bench_host.JobContext.publish`), whose reader hands it
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


#: The ``options`` the :func:`record` job passes on to
#: :func:`instrument.acquisition.video.record_video` (any other key is refused).
RECORD_OPTIONS = ("fps", "exposure_s", "shard_frames", "compressor", "queue_frames",
                  "ring_frames", "frame_timeout_s", "note", "overwrite")


def _check_record(params: dict) -> None:
    from .bench_service import BenchServiceError

    options = params.get("options") or {}
    if not isinstance(options, dict):
        raise BenchServiceError(f"record: options must be a dict of "
                                f"{', '.join(RECORD_OPTIONS)}, not {type(options).__name__}")
    for key in options:
        if key not in RECORD_OPTIONS:
            raise BenchServiceError(f"record: unknown option {key!r}; the options are "
                                    f"{', '.join(RECORD_OPTIONS)}")


@holding("camera", check=_check_record)
def record(ctx, *, out: str, frames: int | None = None, seconds: float | None = None,
           options: dict[str, Any] | None = None, simulated: dict | None = None) -> dict:
    """Record a video run (:func:`instrument.acquisition.video.record_video`), the bench given back
    after (the sample stays); ``options``: :data:`RECORD_OPTIONS` (any other key is
    refused before the job starts); ``simulated``: the virtual bench's scene and seed,
    with the camera's dark offset added here, as ``capture video --simulate`` records.
    Holds the camera while it runs (:func:`holding`).

    """
    from ..acquisition.video import record_video


    attrs = {}
    if simulated is not None:
        attrs["simulated"] = {**simulated,
                              "dark_offset_dn": float(ctx.bench.camera.dark_offset_dn)}
    with kept(ctx, sample_out=False):
        return record_video(ctx.bench, out, frames=frames, seconds=seconds, stop=ctx.stop,
                            on_progress=ctx.report, progress_every_s=0.25,
                            live=_Publisher(ctx), **(options or {}), **attrs)



#: The instrument's jobs by name (:meth:`instrument.bench.bench_host.BenchHost.start_job`).
JOBS: dict[str, Callable] = {"open_bench": open_bench, "close_bench": close_bench,
                             "set_scene": set_scene, "record": record}
