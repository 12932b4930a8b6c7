"""Video recording on a bench: the camera's stream into a sharded run store.

:func:`record_video` is what ``diffuserlab capture video`` (and the GUI's record
panel) runs: the camera streams into a bounded :class:`drivers.camera.FrameRing`
from its own grab thread; this thread takes every frame from the ring in order and
offers it to the :class:`instrument.acquisition.recorder.Recorder` (never skipped: a frame the
recorder's bounded queue cannot take is lost, counted and kept by index) and, when
given, to a live reconstruction (which only ever takes the newest frame, so it
cannot slow the recorder). The run is a one-point plan ``"video"`` whose frames are
stored in the order recorded, ``shard_frames`` per shard file, with the per-frame
coordinates of :data:`instrument.acquisition.recorder.VIDEO_COORDS`; when the recording ends
early (Ctrl-C, ``stop``) or frames were lost, the run is cut to the frames it holds,
so a stored video never has empty slots. A recording killed outright keeps every
completed shard (see :mod:`instrument.acquisition.recorder`).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera import FrameRing

from ..atomic import missing_dirs, remove_empty_dirs
from ..runs.coords import coord_specs
from ..runs.runstore import RunStore, RunStoreError, discard_partial_run
from ..runs.runstore_records import VIDEO_PLAN
from .recorder import VIDEO_COORDS, Recorder, record_from_ring
from .video_defaults import DEFAULT_COMPRESSOR, DEFAULT_SHARD_FRAMES, MAX_FRAMES

__all__ = ["DEFAULT_COMPRESSOR", "DEFAULT_SHARD_FRAMES", "MAX_FRAMES", "VIDEO_PLAN",
           "check_disk_space", "create_video_run", "record_video", "video_frame_count"]

log = logging.getLogger(__name__)


def video_frame_count(*, frames: int | None, seconds: float | None, rate_hz: float) -> int:
    """Frames a recording takes: ``frames``, or ``ceil(seconds * rate_hz)``.

    Raises
    ------
    RunStoreError
        Neither or both given, or a count below 1.
    """
    if (frames is None) == (seconds is None):
        raise RunStoreError("give the length of the recording as frames or as seconds "
                            "(--frames N or --seconds T), not both")
    if frames is not None:
        if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or frames < 1:
            raise RunStoreError(f"--frames {frames}: give a whole number >= 1")
        n = int(frames)
        what = f"--frames {frames}"
    else:
        if not (0 < seconds < math.inf):
            raise RunStoreError(f"--seconds {seconds}: give a number > 0")
        count = seconds * rate_hz - 1e-9
        n = max(1, math.ceil(count)) if count < MAX_FRAMES else MAX_FRAMES + 1
        what = f"--seconds {seconds:g} at {rate_hz:g} fps"
    if n > MAX_FRAMES:
        raise RunStoreError(f"{what} asks for more than {MAX_FRAMES} frames; record in "
                            "parts of at most that many")
    return n


def check_disk_space(path: str | Path, n_frames: int, frame_shape, dtype) -> None:
    """Refuse a recording whose frames, uncompressed, exceed the free space where its
    run store goes (a lossless compressor saves little on noisy frames).

    Raises
    ------
    RunStoreError
        Not enough space: what it needs, what is free and where.
    """
    import shutil

    need = int(n_frames) * int(np.prod(frame_shape)) * np.dtype(dtype).itemsize
    where = Path(os.path.abspath(path)).parent
    while not where.exists() and where != where.parent:
        where = where.parent
    free = shutil.disk_usage(where).free
    if need > free:
        raise RunStoreError(
            f"recording {n_frames} frames of {frame_shape[0]}x{frame_shape[1]} "
            f"{np.dtype(dtype)} needs {need / 1e9:.3g} GB (uncompressed), {free / 1e9:.3g} GB "
            f"are free on {where}; record fewer frames (--frames/--seconds) or free space")


def create_video_run(path: str | Path, camera, n_frames: int, *,
                     bench_config: dict | None = None, device_settings: dict | None = None,
                     shard_frames: int = DEFAULT_SHARD_FRAMES,
                     compressor: str = DEFAULT_COMPRESSOR, note: str = "",
                     overwrite: bool = False, **attrs: Any) -> RunStore:
    """Create the run store of a recording of ``n_frames`` frames from ``camera``.

    Parameters
    ----------
    path : str or Path
        ``RUN.zarr`` to create.
    camera : drivers.camera.Camera
        Open; its image shape, dtype, id, bit depth and pixel pitch are recorded.
    n_frames : int
        Frame slots (the run is cut to the frames recorded when it ends).
    bench_config, device_settings : dict, optional
        Snapshots stored with the run.
    shard_frames : int
        Frames per shard file.
    compressor : str
        One of :data:`instrument.runs.runstore.FRAME_COMPRESSORS` (all lossless).
    note : str
    overwrite : bool
        Replace an earlier run store at ``path`` (never anything else).
    **attrs
        Extra JSON-able run attributes (e.g. the simulated scene).

    Returns
    -------
    RunStore
        Writable, holding the run's writer lock from its creation (no other process
        replaces it meanwhile; the recorder's :meth:`~instrument.runs.runstore.RunStore.lock`
        finds it held and its close releases it).

    Raises
    ------
    RunStoreError
        As :meth:`RunStore.create`.
    """
    store = RunStore.create(
        path, plan_name=VIDEO_PLAN, plan_params={"frames": int(n_frames)}, points=[{}],
        frame_tags=[["video"] * int(n_frames)], frame_shape=camera.image_shape,
        frame_dtype=camera.dtype, coord_names=list(VIDEO_COORDS),
        coord_specs=coord_specs(VIDEO_COORDS, {camera.device_id: camera}),
        bench_config=bench_config,
        device_settings=device_settings, note=note, overwrite=overwrite,
        shard_frames=int(shard_frames), compressor=compressor, keep_lock=True)
    try:
        store.update_attrs(camera={"id": camera.device_id, "bit_depth": camera.bit_depth,
                                   "full_scale_dn": 2 ** int(camera.bit_depth) - 1,
                                   "pixel_pitch_um": camera.pixel_pitch_um,
                                   "frame_rate_hz": camera.resulting_frame_rate_hz,
                                   "exposure_s": camera.exposure_s, "gain": camera.gain},
                           **attrs)
    except BaseException:  # the run this call created, never finished: removed
        discard_partial_run(store.path, token=store.creation_token)
        raise
    return store


def _progress(t0: float, rec: Recorder, ring: FrameRing, live) -> dict[str, Any]:
    elapsed = time.monotonic() - t0
    out = rec.counters(ring)
    out["elapsed_s"] = round(elapsed, 3)
    out["fps"] = out["acquired"] / elapsed if elapsed > 0 else 0.0
    out["write_mb_s"] = out["bytes_written"] / 1e6 / elapsed if elapsed > 0 else 0.0
    if live is not None:
        out["live"] = live.stats()
    return out


def _stop_live(live) -> str | None:
    """Stop the live reconstruction beside a recording; what went wrong, or None.

    A live view that does not stop in time (its thread ends with its frame: a daemon)
    must not keep the recording from closing its run, so the error is returned for the
    summary and the log, not raised.
    """
    if live is None:
        return None
    from .live import LiveReconstructionError

    try:
        live.stop()
    except LiveReconstructionError as exc:
        log.warning("recording closed; the live reconstruction did not stop: %s", exc)
        return str(exc)
    return None


def record_video(bench, out: str | Path, *, frames: int | None = None,
                 seconds: float | None = None, fps: float | None = None,
                 exposure_s: float | None = None, shard_frames: int = DEFAULT_SHARD_FRAMES,
                 compressor: str = DEFAULT_COMPRESSOR, queue_frames: int = 64,
                 ring_frames: int = 64, stop: threading.Event | None = None,
                 on_progress: Callable[[dict], None] | None = None,
                 progress_every_s: float = 1.0, live=None, overwrite: bool = False,
                 note: str = "", frame_timeout_s: float | None = None,
                 **attrs: Any) -> dict[str, Any]:
    """Record a video from the bench's camera into a new run store.

    Parameters
    ----------
    bench : instrument.devices.bench.Bench or instrument.devices.virtual_bench.VirtualBench
        Open; its ``camera`` is used (and ``config`` / ``settings_snapshot()`` stored).
    out : str or Path
        ``RUN.zarr`` to create.
    frames, seconds : int or float
        Length of the recording: a frame count, or seconds at the camera's resulting
        frame rate (exactly one of the two).
    fps, exposure_s : float, optional
        Camera settings applied first (validated by the camera interface).
    shard_frames, compressor
        Storage of the run (see :func:`create_video_run`).
    queue_frames : int
        Frames the recorder's queue holds before a frame is lost.
    ring_frames : int
        Capacity of the camera's ring.
    stop : threading.Event, optional
        Ends the recording early (Ctrl-C, the GUI's stop button); what was recorded is
        kept and the run is marked ``stopped``. Any object with ``is_set()`` serves
        (the command line's ``instrument.cli.startup_signals.SignalSeen``).
    on_progress : callable, optional
        Called every ``progress_every_s`` with the counters (``delivered``,
        ``recorded``, ``acquired``, ``dropped_by_camera``, ``skipped_by_ring``,
        ``lost_by_recorder``, ``fps``, ``write_mb_s``, ``elapsed_s`` and ``live``).
    live : instrument.acquisition.live.LiveReconstruction, optional
        Started by this function, offered every frame (it keeps only the newest),
        stopped at the end; its statistics go into the summary.
    overwrite : bool
        Replace an earlier run store at ``out``.
    note : str
    frame_timeout_s : float, optional
        Longest wait for one frame, s (default: 10 frame periods plus 5 s, so a busy
        machine's hiccup is not taken for a dead camera).
    **attrs
        Extra run attributes.

    Returns
    -------
    dict
        The recording summary (:meth:`Recorder.close` plus ``path``, ``status``,
        ``frames_requested``, ``fps``, ``write_mb_s`` and ``live``; ``live_error``
        when the live reconstruction did not stop in time: the run is closed all the
        same).

    Raises
    ------
    RunStoreError
        Bad length or storage options, an existing ``out``, a failed write.
    drivers.errors.DeviceError
        A refused camera setting, the camera lost or silent past the timeout (the
        frames recorded so far are kept, the run marked ``failed``).
    """
    cam = bench.camera
    settings = {k: v for k, v in (("frame_rate_hz", fps), ("exposure_s", exposure_s))
                if v is not None}
    if settings:
        cam.apply_settings(settings)
    rate = float(cam.resulting_frame_rate_hz)
    n = video_frame_count(frames=frames, seconds=seconds, rate_hz=rate)
    check_disk_space(out, n, cam.image_shape, cam.dtype)
    config = getattr(bench, "config", None)
    store, made = None, missing_dirs(out)
    try:  # until the recorder holds the run, a failure (Ctrl-C too) leaves no run behind
        store = create_video_run(
            out, cam, n,
            bench_config=config.model_dump(mode="json") if config is not None else {},
            device_settings=bench.settings_snapshot(), shard_frames=shard_frames,
            compressor=compressor, note=note, overwrite=overwrite, **attrs)
        rec = Recorder(store, queue_frames=queue_frames)
        ring = FrameRing(ring_frames)
        rec.start()
    except BaseException:  # the empty run this call created, never another's (a run
        # created at ``out`` by another process meanwhile refuses this one: kept)
        if store is not None:
            discard_partial_run(out, made, token=store.creation_token)
        else:  # refused, or create_video_run removed its own half-made run
            remove_empty_dirs(made)
        raise
    stop = stop or threading.Event()
    timeout_s = frame_timeout_s if frame_timeout_s is not None else 10.0 / rate + 5.0
    t0 = time.monotonic()
    last = [t0]

    def on_frame(frame) -> None:
        if live is not None:
            live.offer(frame)
        now = time.monotonic()
        if on_progress is not None and now - last[0] >= progress_every_s:
            last[0] = now
            on_progress(_progress(t0, rec, ring, live))

    status, error = "complete", None
    try:
        if live is not None:
            live.start()
        cam.start_stream(ring)
        record_from_ring(rec, ring, n, stop=stop, timeout_s=timeout_s, on_frame=on_frame)
        if stop.is_set():
            status = "stopped"
    except KeyboardInterrupt:
        status = "stopped"
    except BaseException as exc:
        status, error = "failed", exc
    finally:
        if cam.is_streaming:
            cam.stop_stream()
        live_error = _stop_live(live)
    final = _progress(t0, rec, ring, live)
    summary = rec.close(ring=ring, status=status, trim=True)  # whatever the live view did
    if live_error is not None:
        summary["live_error"] = live_error
    if error is not None:
        store.update_attrs(error=f"recording stopped by {type(error).__name__}: {error}")
        raise error
    elapsed = max(float(summary["elapsed_s"]), 1e-9)  # to the last frame written
    summary.update(path=str(store.path), status=status, frames_requested=n,
                   fps=final["fps"], write_mb_s=summary["bytes_written"] / 1e6 / elapsed,
                   live=final.get("live"))
    return summary
