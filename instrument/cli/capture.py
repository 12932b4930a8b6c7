"""``diffuserlab capture live|video``: watch the reconstruction, record a video.

``diffuserlab capture live [BENCH.toml] [--simulate] --psf PSF [--depth Z]
[--method wiener|admm:K] [--device cpu|cuda|auto] [--seconds T] [--preview-png FILE]``
    Streams the bench's camera into a ring, reconstructs the newest frame on a worker
    thread (:class:`instrument.acquisition.live.LiveReconstruction`: Wiener preview by default,
    or K ADMM iterations per frame warm-started from the previous frame), prints the
    camera's and the reconstruction's rates, the latency and every counter once a
    second, and writes the latest reconstruction to ``--preview-png`` now and then
    (upright view, written atomically). No GUI needed. With ``--simulate`` the
    virtual bench streams in real time and shows a moving video scene
    (``--scene``: beads flowing in a channel, or neurons with calcium transients).
    ``--device cuda`` reconstructs on a GPU (the PSF spectrum and the warm-start
    state kept there); an unusable device exits 2 before the bench is opened.
    Ctrl-C stops cleanly. Exit 0; 1 if the worker reported errors; 2 bad input.

``diffuserlab capture video [BENCH.toml] [--simulate] (--frames N | --seconds T)
[--fps F] [--scene ...] --out RUN.zarr [--live-recon wiener|admm:K --psf PSF
[--device cpu|cuda|auto]]``
    Records at the camera's rate into a new sharded run store
    (:func:`instrument.acquisition.video.record_video`): every frame in order, none skipped; a
    frame the recorder cannot take is lost, counted and named by index. A progress
    line once a second; Ctrl-C stops and keeps what was recorded. With
    ``--live-recon`` a live reconstruction runs beside it on the newest frames.
    Exit 0 no frame lost; 1 frames lost (count and indices printed); 2 bad input;
    130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
import time

from ..devices.bench_file import bench_config
from .startup_signals import SignalSeen

__all__ = ["add_subcommands", "run_live"]

SCENES = ("beads-flow", "neurons", "none")


def _stream_options(p: argparse.ArgumentParser) -> None:
    """Options both ``capture`` modes take: the bench, its camera, the simulated scene."""
    p.add_argument("bench", nargs="?", default=None,
                   help="bench TOML file (with --simulate and no file: the built-in one)")
    p.add_argument("--simulate", action="store_true",
                   help="the virtual bench, streaming in real time")
    p.add_argument("--seed", type=int, default=0, help="--simulate: random seed")
    p.add_argument("--scene", choices=SCENES, default="beads-flow",
                   help="--simulate: the moving scene in front of the camera")
    p.add_argument("--fps", type=float, default=None, help="camera frame rate, Hz")
    p.add_argument("--exposure-s", type=float, default=None, help="camera exposure, s")


def _recon_options(p: argparse.ArgumentParser, *, required: bool, method_flag: str,
                   default_method: str | None) -> None:
    """Options of the live reconstruction (its PSF, dark level, binning, threads)."""
    p.add_argument("--psf", required=required,
                   help="PSF image, PSF stack or calibration run (with --depth)")
    p.add_argument("--depth", type=float, default=None, dest="depth_mm",
                   help="depth of the stack's plane to use, mm")
    from recon.options import LiveOptions

    p.add_argument(method_flag, default=default_method, dest="method",
                   help="wiener or admm:K (K warm-started ADMM iterations per frame; admm: "
                   f"{LiveOptions.defaults()['iterations']})"
                   + ("" if default_method is None else f"; default {default_method}"))
    from .recon_flags import add_recon_flags

    add_recon_flags(p, "capture live")
    p.add_argument("--threads", type=int, default=None,
                   help="cap the reconstruction's threads (default: all cores)")


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``capture`` (``live`` and ``video``) to the ``diffuserlab`` subparsers."""
    cp = sub.add_parser("capture", help="stream the camera: live reconstruction, video")
    csub = cp.add_subparsers(dest="mode", required=True)
    lp = csub.add_parser(
        "live", help="reconstruct the newest camera frame continuously; fps and latency "
        "once a second, the latest image to a PNG",
        description="Stream the camera and reconstruct the newest frame continuously "
        "(frames the reconstruction cannot take are skipped and counted). Ctrl-C stops.")
    _stream_options(lp)
    from recon.options import LiveOptions

    _recon_options(lp, required=True, method_flag="--method",
                   default_method=LiveOptions.defaults()["method"])
    lp.add_argument("--seconds", type=float, default=10.0,
                    help="how long to stream, s (default 10; Ctrl-C stops earlier)")
    lp.add_argument("--preview-png", default=None,
                    help="write the latest reconstruction here every --preview-every-s")
    lp.add_argument("--preview-every-s", type=float, default=2.0,
                    help="seconds between preview PNGs (default 2)")
    lp.add_argument("--overwrite", action="store_true",
                    help="replace an existing --preview-png")
    lp.set_defaults(handler=run_live)

    vp = csub.add_parser(
        "video", help="record a video into a run store (no frame skipped; losses counted)",
        description="Record the camera's frames at its rate into a new run store "
        "(sharded Zarr, lossless). A progress line once a second shows fps, written "
        "MB/s and every counter. Ctrl-C stops cleanly and keeps what was recorded. Exit 0 "
        "when every frame the camera acquired was stored, 1 when any was lost (the "
        "count and the camera indices are printed), 2 bad input, 130 stopped by Ctrl-C "
        "(the run keeps its frames, status 'stopped').")
    _stream_options(vp)
    length = vp.add_mutually_exclusive_group(required=True)
    length.add_argument("--frames", type=int, default=None, help="frames to record")
    length.add_argument("--seconds", type=float, default=None,
                        help="seconds to record at the camera's frame rate")
    vp.add_argument("--out", required=True, help="the new run store, RUN.zarr")
    vp.add_argument("--overwrite", action="store_true",
                    help="replace an earlier run store at --out (never anything else)")
    vp.add_argument("--shard-frames", type=int, default=None,
                    help=f"frames per shard file (default {_defaults()[0]})")
    vp.add_argument("--compressor", default=None,
                    help="lossless frame compression: none, zstd1, blosc-lz4 or default "
                    f"(zarr's zstd); default {_defaults()[1]}")
    vp.add_argument("--queue-frames", type=int, default=64,
                    help="frames the recorder may queue before one is lost (default 64)")
    vp.add_argument("--note", default="", help="the operator's note, stored with the run")
    _recon_options(vp, required=False, method_flag="--live-recon", default_method=None)
    vp.add_argument("--preview-png", default=None,
                    help="with --live-recon: write the latest reconstruction here at the end")
    vp.set_defaults(handler=run_video)


def _defaults() -> tuple[int, str]:
    from ..acquisition.video_defaults import DEFAULT_COMPRESSOR, DEFAULT_SHARD_FRAMES

    return DEFAULT_SHARD_FRAMES, DEFAULT_COMPRESSOR


def _method(text: str) -> tuple[str, int]:
    from recon.errors import ReconInputError
    from recon.options import LiveOptions

    name, _, k = text.partition(":")
    if name == "wiener" and not k:
        return "wiener", 1
    if name == "admm" and not k:  # the live form's default iterations per frame
        return "admm", LiveOptions.defaults()["iterations"]
    if name == "admm" and k.isdigit() and int(k) >= 1:
        return "admm", int(k)
    raise ReconInputError(f"--method {text!r}: use wiener or admm:K with K >= 1 iterations "
                          "per frame (e.g. admm:5)")


#: Longest ``--seconds`` of a capture (a recording's frame count is bounded too, by
#: :data:`instrument.acquisition.video.MAX_FRAMES`, once the camera's rate is known).
MAX_SECONDS = 1e7


def _check_numbers(args: argparse.Namespace) -> None:
    from recon.errors import ReconInputError
    from recon.fft import check_threads

    for option, value in (("--seconds", args.seconds), ("--fps", args.fps),
                          ("--exposure-s", args.exposure_s),
                          ("--preview-every-s", getattr(args, "preview_every_s", None))):
        if value is not None and not 0 < value < float("inf"):
            raise ReconInputError(f"{option} {value}: give a number > 0")
    if args.seconds is not None and args.seconds > MAX_SECONDS:
        raise ReconInputError(f"--seconds {args.seconds:g}: give at most {MAX_SECONDS:g} s "
                              f"({MAX_SECONDS / 86400:.0f} days) per run")
    if args.bin_factor < 1:
        raise ReconInputError(f"--bin {args.bin_factor}: give a factor >= 1")
    if args.seed < 0:
        raise ReconInputError(f"--seed {args.seed}: give a seed >= 0")
    if args.threads is not None:
        check_threads(args.threads)


def _open(args: argparse.Namespace, config):
    """The bench: the real one, or the virtual bench streaming a video scene."""
    from ..devices.bench import Bench
    from ..devices.bench_scenes import show_video_scene
    from ..devices.virtual_bench import VirtualBench

    if not args.simulate:
        return Bench.open(config)
    vb = VirtualBench(config, seed=args.seed, realtime=True).open()
    vb.led_array.all_off()
    if args.scene != "none":  # placed, scaled and rendered ahead for the bench
        show_video_scene(vb, args.scene, seed=args.seed)
    return vb


def _live_inputs(args: argparse.Namespace) -> tuple:
    """The PSF, its depth and ``--dark`` read before the bench opens: a given level or
    frame is read and a frame checked against the PSF's shape, which the camera's frames
    must have; ``auto`` and ``none`` are passed on as they are
    (:func:`instrument.processing.reconstruct_files.resolve_dark` resolves them with the camera)."""
    from ..processing.reconstruct_files import check_dark_frame, dark_level, load_psf

    psf, depth = load_psf(args.psf, args.depth_mm)
    dark = args.dark
    if dark is not None and str(dark).strip().lower() not in ("auto", "none"):
        dark = dark_level(str(dark))
        check_dark_frame(dark, psf.shape[-2:], f"the PSF {args.psf} and the camera's frames")
    return psf, depth, dark


def _status(t_s: float, ring, live) -> str:
    c, s = ring.counters(), live.stats()
    lat = "-" if s["latency_median_s"] is None else f"{1e3 * s['latency_median_s']:.0f} ms"
    rate = c["acquired"] / t_s if t_s > 0 else 0.0  # a camera short of its rate shows here
    return (f"{t_s:5.1f} s  camera: {rate:.1f} fps, acquired {c['acquired']}, dropped "
            f"{c['dropped']}  |  "
            f"live: {s['fps']:.1f} fps, latency {lat}, reconstructed {s['reconstructed']}, "
            f"skipped {s['skipped']}, errors {s['errors']}")


def _live(args: argparse.Namespace, cam, inputs: tuple):
    """The live reconstruction the options ask for (``inputs`` from
    :func:`_live_inputs`), checked against the camera; with the PSF's description for
    the banner."""
    from recon.errors import ReconInputError
    from recon.live import LiveReconstructor
    from recon.options import LiveOptions, ReconOptions

    from ..acquisition.live import LiveReconstruction
    from ..processing.reconstruct_files import resolve_dark
    from ..runs.stacks import dark_subtracted

    method, iterations = _method(args.method)
    psf, depth, dark = inputs
    if tuple(cam.image_shape) != tuple(psf.shape):
        raise ReconInputError(
            f"the PSF {args.psf} is {psf.shape[0]}x{psf.shape[1]} but the camera "
            f"delivers {cam.image_shape[0]}x{cam.image_shape[1]} frames; calibrate "
            "the PSF with the camera's current ROI and binning")
    psf, dark = resolve_dark(  # one meaning of --dark auto (docs/cli.md)
        dark, psf, calibrated=dark_subtracted(args.psf),
        recorded=float(cam.dark_offset_dn) if args.simulate else None,
        what=f"--psf {args.psf}")
    recon = LiveReconstructor(psf, ReconOptions.from_defaults(
        bin_factor=args.bin_factor, dark=dark, device=args.device))
    live = LiveReconstruction(recon, LiveOptions.from_defaults(method=method,
                                                               iterations=iterations),
                              threads=args.threads)
    label = (f"{method}{'' if method == 'wiener' else f' x{iterations}'}, PSF {args.psf}"
             f"{'' if depth is None else f' at {depth:g} mm'}, on {recon.backend.label}")
    return live, label


def run_live(args: argparse.Namespace) -> int:
    """Run ``capture live``; returns the exit status (module docstring)."""
    from drivers.camera import FrameRing
    from recon.io import scene_view

    from ..writer.files import save_image
    from ..writer.guards import check_outputs
    from .recon_flags import check_device

    _method(args.method)
    _check_numbers(args)
    check_device(args.device)  # before the bench is opened or a file written
    if args.preview_png is not None:
        check_outputs([args.preview_png], {"--psf": args.psf}, args.overwrite,
                      option="--preview-png")
    inputs = _live_inputs(args)  # the PSF and a dark frame, before the bench opens
    config = bench_config(args.bench, simulate=args.simulate, command="capture live")
    bench = _open(args, config)
    try:
        cam = bench.camera
        settings = {k: v for k, v in (("frame_rate_hz", args.fps),
                                      ("exposure_s", args.exposure_s)) if v is not None}
        live, label = _live(args, cam, inputs)
        cam.apply_settings(settings)
        print(f"live {label} on {cam.device_id} ({cam.image_shape[0]}x{cam.image_shape[1]}, "
              f"{cam.resulting_frame_rate_hz:.1f} fps); Ctrl-C stops", flush=True)
        ring = FrameRing(64)
        cam.start_stream(ring)
        t0 = last_print = last_png = time.monotonic()
        seen = SignalSeen()  # Ctrl-C stops it even where a library swallowed the interrupt
        try:
            live.start(ring=ring)
            while (now := time.monotonic()) - t0 < args.seconds and not seen.is_set():
                time.sleep(min(0.1, max(0.0, args.seconds - (now - t0))))
                now = time.monotonic()
                if now - last_print >= 1.0:
                    print(_status(now - t0, ring, live), flush=True)
                    last_print = now
                latest = live.latest()
                if args.preview_png and latest is not None and \
                        now - last_png >= args.preview_every_s:
                    save_image(args.preview_png, scene_view(latest.image))
                    last_png = now
            if seen.is_set():
                raise KeyboardInterrupt
        except KeyboardInterrupt:
            print("stopped (Ctrl-C)", flush=True)
        finally:
            cam.stop_stream()
            live.stop()  # waits for its frame (a hang guard)
        latest = live.latest()
        if args.preview_png and latest is not None:
            save_image(args.preview_png, scene_view(latest.image))
            print(f"latest reconstruction (frame {latest.frame_index}): {args.preview_png}")
        print(_status(time.monotonic() - t0, ring, live))
    finally:
        bench.close()
    errors = live.stats()["errors"]
    if errors:
        print(f"diffuserlab: error: {errors} frame(s) failed to reconstruct; last: "
              f"{live.stats()['last_error']}", file=sys.stderr)
        return 1
    return 0


def _video_line(p: dict) -> str:
    """One progress line of ``capture video`` from
    :func:`instrument.acquisition.video.record_video`'s
    counters."""
    line = (f"{p['elapsed_s']:6.1f} s  {p['fps']:.1f} fps, {p['write_mb_s']:.1f} MB/s  "
            f"acquired {p['acquired']}, delivered {p['delivered']}, recorded "
            f"{p['recorded']}, queued {p['queued']}, lost: camera {p['dropped_by_camera']}, "
            f"ring {p['skipped_by_ring']}, recorder {p['lost_by_recorder']}")
    live = p.get("live")
    if live:
        lat = live["latency_median_s"]
        line += (f"  |  live: {live['fps']:.1f} fps, latency "
                 f"{'-' if lat is None else f'{1e3 * lat:.0f} ms'}, skipped {live['skipped']}")
    return line


def run_video(args: argparse.Namespace) -> int:
    """Run ``capture video``; returns the exit status (the parser's description)."""
    from drivers.errors import DeviceError, DeviceValueError
    from recon.errors import ReconInputError
    from recon.io import scene_view

    from ..acquisition.recorder import index_ranges
    from ..acquisition.video import (
        DEFAULT_COMPRESSOR,
        DEFAULT_SHARD_FRAMES,
        MAX_FRAMES,
        record_video,
    )
    from ..runs.runstore import FRAME_COMPRESSORS, RunStore, is_run_store
    from ..writer.files import save_image
    from ..writer.guards import check_outputs
    from .recon_flags import check_device

    if args.method is not None:
        _method(args.method)
        if args.psf is None:
            raise ReconInputError("--live-recon needs the PSF to reconstruct with: add "
                                  "--psf PSF (and --depth for a stack)")
    elif args.psf is not None or args.preview_png is not None or args.device != "cpu":
        raise ReconInputError("--psf, --preview-png and --device go with --live-recon "
                              "wiener|admm:K")
    _check_numbers(args)
    check_device(args.device)  # before the bench is opened or a file written
    if args.frames is not None and not 1 <= args.frames <= MAX_FRAMES:
        raise ReconInputError(f"--frames {args.frames}: give a whole number >= 1 and at most "
                              f"{MAX_FRAMES} (record longer videos in parts)")
    for option, value in (("--shard-frames", args.shard_frames),
                          ("--queue-frames", args.queue_frames)):
        if value is not None and value < 1:
            raise ReconInputError(f"{option} {value}: give a whole number >= 1")
    if args.compressor is not None and args.compressor not in FRAME_COMPRESSORS:
        raise ReconInputError(f"--compressor: unknown frame compressor {args.compressor!r}; "
                              f"use one of {list(FRAME_COMPRESSORS)}")
    inputs = {"--psf": args.psf} if args.psf else {}
    check_outputs([args.out], inputs, args.overwrite, store=True)
    if args.preview_png:
        check_outputs([args.preview_png], {**inputs, "--out": args.out}, args.overwrite,
                      option="--preview-png")
    live_inputs = _live_inputs(args) if args.method is not None else None
    seen = SignalSeen()  # stops the recording even where a library swallowed the interrupt
    config = bench_config(args.bench, simulate=args.simulate, command="capture video")
    bench = _open(args, config)
    try:
        cam = bench.camera
        live = label = None
        if live_inputs is not None:
            live, label = _live(args, cam, live_inputs)
        extra = {}
        if args.simulate:
            extra["simulated"] = {"scene": args.scene, "seed": args.seed,
                                  "dark_offset_dn": float(cam.dark_offset_dn)}
        print(f"recording {cam.device_id} ({cam.image_shape[0]}x{cam.image_shape[1]} "
              f"{cam.dtype}) to {args.out}"
              f"{'' if label is None else f'; live {label}'}; Ctrl-C stops", flush=True)
        try:
            summary = record_video(
                bench, args.out, frames=args.frames, seconds=args.seconds, fps=args.fps,
                exposure_s=args.exposure_s,
                shard_frames=args.shard_frames or DEFAULT_SHARD_FRAMES,
                compressor=args.compressor or DEFAULT_COMPRESSOR,
                queue_frames=args.queue_frames,
                on_progress=lambda p: print(_video_line(p), flush=True), live=live,
                overwrite=args.overwrite, note=args.note, stop=seen, **extra)
        except DeviceError as exc:
            if isinstance(exc, DeviceValueError):  # a refused setting: nothing recorded
                raise
            kept = RunStore.open(args.out).done().sum() if is_run_store(args.out) else 0
            print(f"diffuserlab: device error: {' '.join(str(exc).split())} (the {kept} "
                  f"frames recorded before are kept in {args.out}, status failed)",
                  file=sys.stderr)
            return 1
        if live is not None and args.preview_png and live.latest() is not None:
            save_image(args.preview_png, scene_view(live.latest().image))
            print(f"latest reconstruction (frame {live.latest().frame_index}): "
                  f"{args.preview_png}")
    finally:
        bench.close()
    print(_video_line({**summary, "elapsed_s": summary["elapsed_s"]}))
    print(f"{summary['status']}: {summary['recorded']} frames in {args.out} "
          f"({summary['frames_requested']} requested)")
    lost = summary["dropped_by_camera"] + summary["skipped_by_ring"] + \
        summary["lost_by_recorder"]
    if summary["index_gaps"] or lost:
        missing = index_ranges(i for a, b in summary["index_gaps"] for i in range(a, b + 1))
        print(f"diffuserlab: error: {lost} frame(s) lost (camera {summary['dropped_by_camera']}"
              f", ring {summary['skipped_by_ring']}, recorder {summary['lost_by_recorder']}); "
              f"camera indices missing from the run: {missing}", file=sys.stderr)
        return 1
    return 130 if summary["status"] == "stopped" else 0
