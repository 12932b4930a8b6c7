"""``diffuserlab capture live``: watch the reconstruction while adjusting the scene.

``diffuserlab capture live [BENCH.toml] [--simulate] --psf PSF [--depth Z]
[--method wiener|admm:K] [--seconds T] [--preview-png FILE]``
    Streams the bench's camera into a ring, reconstructs the newest frame on a worker
    thread (:class:`instrument.live.LiveReconstruction`: Wiener preview by default,
    or K ADMM iterations per frame warm-started from the previous frame), prints the
    camera's and the reconstruction's rates, the latency and every counter once a
    second, and writes the latest reconstruction to ``--preview-png`` now and then
    (upright view, written atomically). No GUI needed. With ``--simulate`` the
    virtual bench streams in real time and shows a moving video scene
    (``--scene``: beads flowing in a channel, or neurons with calcium transients).
    Ctrl-C stops cleanly. Exit 0; 1 if the worker reported errors; 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .common import bench_config

__all__ = ["add_subcommands", "run_live"]

SCENES = ("beads-flow", "neurons", "none")


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``capture`` (with ``live``) to the ``diffuserlab`` subparsers."""
    cp = sub.add_parser("capture", help="stream the camera: live reconstruction")
    csub = cp.add_subparsers(dest="mode", required=True)
    lp = csub.add_parser(
        "live", help="reconstruct the newest camera frame continuously; fps and latency "
        "once a second, the latest image to a PNG",
        description="Stream the camera and reconstruct the newest frame continuously "
        "(frames the reconstruction cannot take are skipped and counted). Ctrl-C stops.")
    lp.add_argument("bench", nargs="?", default=None,
                    help="bench TOML file (with --simulate and no file: the built-in one)")
    lp.add_argument("--simulate", action="store_true",
                    help="the virtual bench, streaming in real time")
    lp.add_argument("--seed", type=int, default=0, help="--simulate: random seed")
    lp.add_argument("--scene", choices=SCENES, default="beads-flow",
                    help="--simulate: the moving scene in front of the camera")
    lp.add_argument("--psf", required=True,
                    help="PSF image, PSF stack or calibration run (with --depth)")
    lp.add_argument("--depth", type=float, default=None, dest="depth_mm",
                    help="depth of the stack's plane to use, mm")
    lp.add_argument("--method", default="wiener",
                    help="wiener (default) or admm:K (K warm-started iterations per frame)")
    lp.add_argument("--dark", default=None,
                    help="the frames' dark level: a number (DN) or a `calibrate dark` run "
                    "(its dark_mean frame). Default: the simulated camera's offset with "
                    "--simulate; required on a real bench with a calibrated PSF stack (its "
                    "PSFs are dark-subtracted); with a plain PSF image, estimated from the "
                    "PSF's corner as `recon` does")
    lp.add_argument("--bin", type=int, default=1, dest="bin_factor",
                    help="bin PSF and frames by this factor")
    lp.add_argument("--seconds", type=float, default=10.0,
                    help="how long to stream, s (default 10; Ctrl-C stops earlier)")
    lp.add_argument("--fps", type=float, default=None, help="camera frame rate, Hz")
    lp.add_argument("--exposure-s", type=float, default=None, help="camera exposure, s")
    lp.add_argument("--threads", type=int, default=None,
                    help="cap the reconstruction's threads (default: all cores)")
    lp.add_argument("--preview-png", default=None,
                    help="write the latest reconstruction here every --preview-every-s")
    lp.add_argument("--preview-every-s", type=float, default=2.0,
                    help="seconds between preview PNGs (default 2)")
    lp.add_argument("--overwrite", action="store_true",
                    help="replace an existing --preview-png")
    lp.set_defaults(handler=run_live)


def _method(text: str) -> tuple[str, int]:
    from recon.errors import ReconInputError

    name, _, k = text.partition(":")
    if name == "wiener" and not k:
        return "wiener", 1
    if name == "admm" and k.isdigit() and int(k) >= 1:
        return "admm", int(k)
    raise ReconInputError(f"--method {text!r}: use wiener or admm:K with K >= 1 iterations "
                          "per frame (e.g. admm:5)")


def _check_numbers(args: argparse.Namespace) -> None:
    from recon.errors import ReconInputError
    from recon.fft import check_threads

    for option, value in (("--seconds", args.seconds), ("--fps", args.fps),
                          ("--exposure-s", args.exposure_s),
                          ("--preview-every-s", args.preview_every_s)):
        if value is not None and not 0 < value < float("inf"):
            raise ReconInputError(f"{option} {value}: give a number > 0")
    if args.bin_factor < 1:
        raise ReconInputError(f"--bin {args.bin_factor}: give a factor >= 1")
    if args.seed < 0:
        raise ReconInputError(f"--seed {args.seed}: give a seed >= 0")
    if args.threads is not None:
        check_threads(args.threads)


def _open(args: argparse.Namespace, config):
    """The bench: the real one, or the virtual bench streaming a video scene."""
    from ..bench import Bench
    from ..video_scenes import BeadFlowScene, NeuronFieldScene
    from ..virtual_bench import VirtualBench

    if not args.simulate:
        return Bench.open(config)
    vb = VirtualBench(config, seed=args.seed, realtime=True).open()
    vb.led_array.all_off()
    if args.scene != "none":
        scene = (BeadFlowScene(seed=args.seed, time_step_s=0.5) if args.scene == "beads-flow"
                 else NeuronFieldScene(seed=args.seed, time_step_s=0.25))
        vb.set_scene(scene)
        vb.prerender()
    return vb


def _frame_dark(args: argparse.Namespace, cam, stacked: bool):
    """The frames' dark level (float DN or a per-pixel frame), None to estimate it from
    the PSF's corner like ``recon`` (a plain PSF image, no --dark)."""
    import numpy as np

    from recon.errors import ReconInputError

    from ..runstore import RunStore, RunStoreError

    if args.dark is None:
        if args.simulate:
            return float(cam.dark_offset_dn)
        if stacked:
            raise ReconInputError(
                f"--psf {args.psf} is a calibrated (dark-subtracted) PSF stack: give the "
                "frames' dark level with --dark DN or --dark DARK_RUN.zarr (diffuserlab "
                "calibrate dark)")
        return None
    try:
        level = float(args.dark)
    except ValueError:
        try:
            dark, _ = RunStore.open(args.dark).product("dark_mean")
        except RunStoreError as exc:
            raise ReconInputError(f"--dark {args.dark}: {exc}") from None
        return np.asarray(dark, np.float32)
    if not 0 <= level < float("inf"):
        raise ReconInputError(f"--dark {args.dark}: give a level >= 0 DN or a dark run")
    return level


def _status(t_s: float, ring, live) -> str:
    c, s = ring.counters(), live.stats()
    lat = "-" if s["latency_median_s"] is None else f"{1e3 * s['latency_median_s']:.0f} ms"
    rate = c["acquired"] / t_s if t_s > 0 else 0.0  # a camera short of its rate shows here
    return (f"{t_s:5.1f} s  camera: {rate:.1f} fps, acquired {c['acquired']}, dropped "
            f"{c['dropped']}  |  "
            f"live: {s['fps']:.1f} fps, latency {lat}, reconstructed {s['reconstructed']}, "
            f"skipped {s['skipped']}, errors {s['errors']}")


def run_live(args: argparse.Namespace) -> int:
    """Run ``capture live``; returns the exit status (module docstring)."""
    from drivers.camera import FrameRing
    from recon.errors import ReconInputError
    from recon.io import save_image, scene_view
    from recon.live import LiveReconstructor

    from ..live import LiveReconstruction
    from ..output_safety import check_outputs
    from ..reconstruct_files import load_psf

    method, iterations = _method(args.method)
    _check_numbers(args)
    if args.preview_png is not None:
        check_outputs([args.preview_png], {"--psf": args.psf}, args.overwrite,
                      option="--preview-png")
    config = bench_config(args.bench, simulate=args.simulate, command="capture live")
    psf, depth = load_psf(args.psf, args.depth_mm)
    stacked = depth is not None or Path(args.psf).is_dir()
    bench = _open(args, config)
    try:
        cam = bench.camera
        if tuple(cam.image_shape) != tuple(psf.shape):
            raise ReconInputError(
                f"the PSF {args.psf} is {psf.shape[0]}x{psf.shape[1]} but the camera "
                f"delivers {cam.image_shape[0]}x{cam.image_shape[1]} frames; calibrate "
                "the PSF with the camera's current ROI and binning")
        dark = _frame_dark(args, cam, stacked)
        if dark is not None and stacked:  # the stack's PSF is dark-subtracted already:
            psf = psf + dark  # LiveReconstructor subtracts the same dark from both
        live = LiveReconstruction(
            LiveReconstructor(psf, bin_factor=args.bin_factor, dark=dark),
            method=method, iterations=iterations, threads=args.threads)
        settings = {k: v for k, v in (("frame_rate_hz", args.fps),
                                      ("exposure_s", args.exposure_s)) if v is not None}
        cam.apply_settings(settings)
        print(f"live {method}{'' if method == 'wiener' else f' x{iterations}'} on "
              f"{cam.device_id} ({cam.image_shape[0]}x{cam.image_shape[1]}, "
              f"{cam.resulting_frame_rate_hz:.1f} fps), PSF {args.psf}"
              f"{'' if depth is None else f' at {depth:g} mm'}; Ctrl-C stops", flush=True)
        ring = FrameRing(64)
        cam.start_stream(ring)
        t0 = last_print = last_png = time.monotonic()
        try:
            live.start(ring=ring)
            while (now := time.monotonic()) - t0 < args.seconds:
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
        except KeyboardInterrupt:
            print("stopped (Ctrl-C)", flush=True)
        finally:
            cam.stop_stream()
            live.stop(timeout_s=5.0)
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
