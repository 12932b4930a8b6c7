"""Acquisition benchmarks: video recording and batch reconstruction of a recorded run.

``diffuserlab benchmark recording`` (:func:`run_recording_benchmark`) records the
real-time simulated camera at full size (1200 x 1600 uint16, 20 fps: 77 MB/s raw)
into sharded run stores, once per frame compressor, and reports frames lost,
the sustained write rate, the CPU the process used while recording (camera grab,
recorder, zarr's encoders), the bytes on disk and the files per 1000 frames.

``diffuserlab benchmark batch`` (:func:`run_batch_benchmark`) reconstructs a
recorded run (ADMM, 100 iterations, 300 x 400) with ``recon-run``'s dask batch at 1
and 2 workers and states its frame rate as a ratio to a single-process loop over
the same frames measured in the same run (the machine is shared: ratios, not
seconds, are the figures to compare), with a chart.
"""

from __future__ import annotations

import os
import resource
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["batch_table", "recording_table", "run_batch_benchmark", "run_recording_benchmark"]


def _files(path: Path) -> tuple[int, int]:
    """(file count, bytes) under ``path``."""
    n = size = 0
    for root, _, names in os.walk(path):
        for name in names:
            n += 1
            size += os.path.getsize(os.path.join(root, name))
    return n, size


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _bench(sensor_shape: tuple[int, int], realtime: bool, seed: int = 1):
    """A virtual bench with a ``sensor_shape`` camera and a flowing-bead scene."""
    from instrument.config import default_bench
    from instrument.devices.video_scenes import BeadFlowScene
    from instrument.devices.virtual_bench import VirtualBench

    cfg = default_bench()
    geo = cfg.geometry.model_copy(update={"sensor_shape_px": tuple(sensor_shape)})
    vb = VirtualBench(cfg.model_copy(update={"geometry": geo}), seed=seed, realtime=realtime,
                      render_cache_size=8).open()
    vb.led_array.all_off()
    scene = BeadFlowScene(seed=2, time_step_s=0.5)
    vb.set_scene(scene)
    return vb, scene


def run_recording_benchmark(seconds: float = 120.0, fps: float = 20.0,
                            sensor_shape: tuple[int, int] = (1200, 1600),
                            compressors: tuple[str, ...] = ("none", "blosc-lz4"),
                            shard_frames: int | None = None,
                            directory: str | Path | None = None) -> dict[str, Any]:
    """Record ``seconds`` of real-time simulated video per compressor; report losses,
    write rate, CPU and files.

    Parameters
    ----------
    seconds : float
        Length of each recording, s (2 min by default; 10 min for the long version).
    fps : float
        Camera frame rate, Hz.
    sensor_shape : (rows, cols)
        Simulated sensor (uint16 frames, 12-bit data).
    compressors : tuple of str
        :data:`instrument.runs.runstore.FRAME_COMPRESSORS` to compare.
    shard_frames : int, optional
        Frames per shard (default :data:`instrument.acquisition.video.DEFAULT_SHARD_FRAMES`).
    directory : path, optional
        Where the runs are written (default a temporary directory, removed after).

    Returns
    -------
    dict
        Per compressor: ``recorded``, ``lost`` (camera + ring + recorder),
        ``index_gaps``, ``camera_fps``, ``write_mb_s`` (raw frame bytes per second of
        recording), ``capacity_mb_s`` (raw frame bytes per second spent in the store's
        writes: what the recorder could take from a faster camera), ``disk_mb_s``,
        ``compression_ratio``, ``process_cpu`` (CPU seconds per wall second of the
        whole process while recording),
        ``recorder_thread_cpu_s``, ``files_per_1000_frames``.
    """
    from ..acquisition.video import DEFAULT_SHARD_FRAMES, record_video

    shard = shard_frames or DEFAULT_SHARD_FRAMES
    tmp = Path(directory) if directory is not None else Path(tempfile.mkdtemp(prefix="rec"))
    out: dict[str, Any] = {"seconds": seconds, "fps": fps, "sensor_shape": list(sensor_shape),
                           "shard_frames": shard, "raw_mb_s": None, "runs": {}}
    vb, _ = _bench(sensor_shape, realtime=True)
    try:
        vb.prerender()
        cam = vb.camera
        cam.apply_settings({"exposure_s": 0.005, "frame_rate_hz": fps})
        frame_mb = sensor_shape[0] * sensor_shape[1] * cam.dtype.itemsize / 1e6
        out["raw_mb_s"] = frame_mb * cam.resulting_frame_rate_hz
        for comp in compressors:
            path = tmp / f"{comp}.zarr"
            cpu0, t0 = _cpu_s(), time.monotonic()
            s = record_video(vb, path, seconds=seconds, shard_frames=shard, compressor=comp,
                             overwrite=True)
            wall, cpu = time.monotonic() - t0, _cpu_s() - cpu0
            n_files, size = _files(path)
            lost = s["dropped_by_camera"] + s["skipped_by_ring"] + s["lost_by_recorder"]
            out["runs"][comp] = {
                "recorded": s["recorded"], "requested": s["frames_requested"], "lost": lost,
                "index_gaps": s["index_gaps"], "camera_fps": s["fps"],
                "write_mb_s": s["bytes_written"] / 1e6 / s["elapsed_s"],
                "capacity_mb_s": s["bytes_written"] / 1e6 / max(s["write_s"], 1e-9),
                "disk_mb_s": size / 1e6 / s["elapsed_s"],
                "compression_ratio": s["bytes_written"] / max(size, 1),
                "process_cpu": cpu / wall, "recorder_thread_cpu_s": s["thread_cpu_s"],
                "files_per_1000_frames": 1000.0 * n_files / max(s["recorded"], 1)}
            if directory is None:
                shutil.rmtree(path, ignore_errors=True)
    finally:
        vb.close()
        if directory is None:
            shutil.rmtree(tmp, ignore_errors=True)
    return out


def recording_table(result: dict) -> str:
    """Text table of :func:`run_recording_benchmark`."""
    rows, cols = result["sensor_shape"]
    lines = [f"recording {rows}x{cols} uint16 at {result['fps']:g} fps "
             f"({result['raw_mb_s']:.1f} MB/s raw) for {result['seconds']:g} s per "
             f"compressor, {result['shard_frames']} frames per shard",
             "compressor  recorded/requested  lost  camera fps  write MB/s  capacity MB/s  "
             "disk MB/s  ratio  process CPU  recorder-thread CPU s  files/1000 frames"]
    for comp, r in result["runs"].items():
        lines.append(f"{comp:<10}  {r['recorded']:>8}/{r['requested']:<9}  {r['lost']:>4}  "
                     f"{r['camera_fps']:>10.2f}  {r['write_mb_s']:>10.1f}  "
                     f"{r['capacity_mb_s']:>13.1f}  "
                     f"{r['disk_mb_s']:>9.1f}  {r['compression_ratio']:>5.2f}  "
                     f"{r['process_cpu']:>11.2f}  {r['recorder_thread_cpu_s']:>21.1f}  "
                     f"{r['files_per_1000_frames']:>17.1f}")
    return "\n".join(lines)


def run_batch_benchmark(frames: int = 16, iterations: int = 100,
                        sensor_shape: tuple[int, int] = (300, 400),
                        workers: tuple[int, ...] = (1, 2),
                        chart: str | Path | None = None) -> dict[str, Any]:
    """Frames per second of batch ADMM over a recorded run, against a single-process loop.

    A ``frames``-frame bead video is recorded from the virtual bench (simulated clock)
    at ``sensor_shape``; the PSF is the bench's on-axis PSF as recorded. The reference
    is a loop of :func:`recon.reconstruct` over the frames in this process (all
    cores); each batch is :func:`instrument.processing.batch.reconstruct_run` with a fresh local
    cluster of ``w`` worker processes (one frame at a time each, with the caller's
    thread count). Rates are in steady state (from the
    first stored frame to the last) and overall (including the cluster's start).

    Returns
    -------
    dict
        ``loop_fps``, and per worker count ``fps_steady``, ``fps_overall``,
        ``startup_s``, ``ratio_to_loop`` (steady) and ``max_rel_diff_to_loop`` (the
        largest absolute difference of a batch frame from the loop's, over the loop
        frame's largest magnitude: 0 when bit for bit equal; float32 rounding when a
        worker's BLAS or thread layout sums in another order).
    """
    import recon
    from recon.options import ReconOptions

    from ..acquisition.video import record_video
    from ..processing.batch import reconstruct_run
    from ..runs.runstore import RunStore

    tmp = Path(tempfile.mkdtemp(prefix="batch"))
    try:
        vb, scene = _bench(sensor_shape, realtime=False)
        try:
            h = vb.psf((0.0, 0.0, scene.z_mm))
            psf = (h / h.max() * 4000.0 + vb.camera.dark_offset_dn).astype(np.float32)
            dark = float(vb.camera.dark_offset_dn)
            record_video(vb, tmp / "v.zarr", frames=frames, fps=20.0, shard_frames=8)
        finally:
            vb.close()
        store = RunStore.open(tmp / "v.zarr")
        raws = [store.frame(i).image for i in range(frames)]
        opts = {"method": "admm", "iterations": iterations, "dark": dark}
        options = ReconOptions.validated({"method": "admm", "iterations": iterations},
                                         front="python")
        recon.reconstruct(psf, raws[0], **{**opts, "iterations": 2})  # compile, warm up
        t0 = time.perf_counter()
        loop = [recon.reconstruct(psf, r, **opts).image for r in raws]
        loop_s = time.perf_counter() - t0
        out: dict[str, Any] = {"frames": frames, "iterations": iterations,
                               "sensor_shape": list(sensor_shape),
                               "loop_fps": frames / loop_s, "batch": {}}
        for w in workers:
            stamps: list[float] = []
            t0 = time.perf_counter()
            reconstruct_run(tmp / "v.zarr", psf, options, dark=dark, product=f"w{w}",
                            workers=w,
                            on_progress=lambda p, s=stamps: s.append(time.perf_counter()))
            total = time.perf_counter() - t0
            steady = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 else 0.0
            data, _ = RunStore.open(tmp / "v.zarr").product(f"w{w}")
            out["batch"][w] = {"fps_steady": steady, "fps_overall": frames / total,
                               "startup_s": stamps[0] - t0 if stamps else None,
                               "ratio_to_loop": steady / out["loop_fps"],
                               "max_rel_diff_to_loop": max(
                                   float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))
                                   for a, b in zip(data, loop, strict=True))}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if chart is not None:
        _batch_chart(out, chart)
    return out


def _batch_chart(result: dict, path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..writer.figures import save_figure

    names = ["loop\n(1 process,\nall cores)"] + [f"dask\n{w} worker{'s' * (w > 1)}"
                                                  for w in result["batch"]]
    steady = [result["loop_fps"]] + [b["fps_steady"] for b in result["batch"].values()]
    overall = [result["loop_fps"]] + [b["fps_overall"] for b in result["batch"].values()]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    x = np.arange(len(names))
    ax.bar(x - 0.2, steady, 0.4, label="steady state")
    ax.bar(x + 0.2, overall, 0.4, label="overall (with cluster start)")
    for xi, b in zip(x[1:], result["batch"].values(), strict=True):
        ax.annotate(f"{b['ratio_to_loop']:.2f} x loop", (xi - 0.2, b["fps_steady"]),
                    ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, names)
    ax.set_ylabel("frames per second")
    rows, cols = result["sensor_shape"]
    ax.set_title(f"batch ADMM, {result['iterations']} iterations, {rows} x {cols}, "
                 f"{result['frames']} frames")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path, format="png")
    plt.close(fig)


def batch_table(result: dict) -> str:
    """Text table of :func:`run_batch_benchmark`."""
    rows, cols = result["sensor_shape"]
    lines = [f"batch ADMM ({result['iterations']} iterations, {rows}x{cols}) over "
             f"{result['frames']} recorded frames; single-process loop "
             f"{result['loop_fps']:.2f} frames/s",
             "workers  steady fps  overall fps  start s  steady / loop  max diff to loop"]
    for w, b in result["batch"].items():
        lines.append(f"{w:>7}  {b['fps_steady']:>10.2f}  {b['fps_overall']:>11.2f}  "
                     f"{b['startup_s']:>7.1f}  {b['ratio_to_loop']:>13.2f}  "
                     f"{b['max_rel_diff_to_loop']:>16.1e}")
    return "\n".join(lines)
