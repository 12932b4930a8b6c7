"""``diffuserlab benchmark {recon,gpu,live,recording,batch,volume-scale,memory-limit}``.

``gpu`` runs :func:`instrument.benchmarks.gpu.run_gpu_benchmark` (speed per device and
backend: the NumPy path, the array-API path on PyTorch's CPU backend and on a CUDA GPU).

``recon`` runs :func:`instrument.benchmarks.run.run_benchmarks` (2D and 3D speed against
the FFT floor, 3D memory), prints each benchmark's table as it finishes and the
summary at the end; the accuracy and method studies run from a checkout
(``python -m benchmarks``). ``live`` runs
:func:`instrument.benchmarks.live.run_live_benchmark` (live reconstruction on the real-time
simulated camera: fps, latency, skipped frames; PSNR of warm vs cold ADMM).
``recording`` and ``batch`` run :mod:`instrument.benchmarks.acquisition` (video
recording at full size per compressor; recon-run's dask batch against a loop).
``volume-scale`` runs :func:`instrument.benchmarks.volume_scale.run_volume_scale` (the
seed-size 3D problem streamed or sharded: memory, speed, bytes moved).
``memory-limit`` runs :func:`instrument.benchmarks.memory_limit.run_memory_limit`
(``recon3d --memory-limit`` below, at and above each plan's estimate: refused below
every plan, the measured peak within the limit otherwise).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_subcommands", "run_batch_benchmark", "run_gpu_benchmark", "run_live_benchmark",
           "run_memory_limit_benchmark", "run_recon_benchmarks", "run_recording_benchmark",
           "run_volume_scale_benchmark"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``benchmark`` (with the suite ``recon``) to the ``diffuserlab`` subparsers."""
    from recon.options import BENCHMARKS

    bp = sub.add_parser("benchmark", help="benchmarks (speed vs FFT floor, accuracy, ...)")
    bsub = bp.add_subparsers(dest="suite", required=True)
    rp = bsub.add_parser("recon", help="this machine's reconstruction speed against its FFT "
                         "floor, 2D and 3D",
                         description="This machine's reconstruction speed against its FFT "
                         "floor, 2D and 3D, and the 3D solvers' memory. The accuracy and "
                         "method studies run from a checkout: python -m benchmarks.")
    rp.add_argument("--out", type=Path, default=Path("out/benchmark"),
                    help="output directory (default out/benchmark)")
    rp.add_argument("--quick", action="store_true",
                    help="fewer sizes and repeats (tests/CI)")
    rp.add_argument("--only", choices=BENCHMARKS, help="run a single benchmark")
    rp.add_argument("--overwrite", action="store_true",
                    help="replace the results of an earlier run in --out")
    rp.set_defaults(handler=run_recon_benchmarks)
    gp = bsub.add_parser("gpu", help="speed per device and backend: 2D / 3D ADMM, the "
                         "hologram and live ADMM x5, as s/iteration, ratio to each device's "
                         "FFT floor and speed-up over the CPU",
                         description="Seconds per iteration on every backend present (the "
                         "NumPy path, the array-API path on PyTorch's CPU backend, CuPy or "
                         "PyTorch on a CUDA GPU; absent ones are printed as unmeasured): 2D "
                         "ADMM at 300x400 and 1200x1600, 3D ADMM at 256x256x32 and "
                         "512x512x128, the hologram at 960x540 and 16x, live ADMM x5 at "
                         "1200x1600.")
    gp.add_argument("--quick", action="store_true",
                    help="the 3D cases one size down (128x128x16, 256x256x32) and 4 "
                    "iterations: a few minutes on a 2-core CPU")
    gp.add_argument("--iterations", type=int, default=None,
                    help="iterations per timed solve (default 12, 4 with --quick)")
    gp.add_argument("--no-torch-cpu", action="store_true",
                    help="leave out the generic path on PyTorch's CPU backend")
    gp.add_argument("--json", type=Path, default=None, help="also write the figures here")
    gp.add_argument("--overwrite", action="store_true", help="replace an existing --json")
    gp.set_defaults(handler=run_gpu_benchmark)
    lp = bsub.add_parser("live", help="live reconstruction on the real-time simulated camera "
                         "(fps, latency, skipped frames) and warm- vs cold-start ADMM PSNR",
                         description="Live reconstruction on the real-time simulated camera: "
                         "a Wiener preview and warm-started ADMM, each for --seconds; then "
                         "PSNR per iteration of warm vs cold ADMM on a moving scene.")
    lp.add_argument("--seconds", type=float, default=5.0,
                    help="duration of each streaming run, s (default 5)")
    lp.add_argument("--fps", type=float, default=30.0,
                    help="camera frame rate, Hz (default 30, the simulated maximum)")
    lp.add_argument("--iterations", type=int, default=5,
                    help="ADMM iterations per frame (default 5)")
    lp.add_argument("--threads", type=int, default=None,
                    help="cap the live worker's threads (default: all cores)")
    lp.add_argument("--json", type=Path, default=None, help="also write the figures here")
    lp.add_argument("--overwrite", action="store_true", help="replace an existing --json")
    lp.set_defaults(handler=run_live_benchmark)
    vp = bsub.add_parser("recording", help="record the real-time simulated camera at full "
                         "size (1200x1600 uint16, 20 fps) per compressor: frames lost, MB/s, "
                         "CPU, files per 1000 frames",
                         description="Record the real-time simulated camera into sharded "
                         "run stores, once per lossless compressor, for --seconds each "
                         "(2 minutes by default; --long: 10 minutes, the default compressor "
                         "only).")
    vp.add_argument("--seconds", type=float, default=120.0,
                    help="length of each recording, s (default 120)")
    vp.add_argument("--long", action="store_true",
                    help="one 10-minute recording with the default compressor")
    vp.add_argument("--fps", type=float, default=20.0, help="camera frame rate (default 20)")
    vp.add_argument("--compressors", default="none,blosc-lz4",
                    help="comma-separated compressors to compare (default none,blosc-lz4)")
    vp.add_argument("--dir", type=Path, default=None,
                    help="where to write the runs (default a temporary directory, removed "
                    "after; the disk's speed is part of the figure)")
    vp.add_argument("--json", type=Path, default=None, help="also write the figures here")
    vp.add_argument("--overwrite", action="store_true", help="replace an existing --json")
    vp.set_defaults(handler=run_recording_benchmark)
    ap = bsub.add_parser("batch", help="batch ADMM over a recorded run with 1 and 2 dask "
                         "workers against a single-process loop, with a chart",
                         description="Frames per second of recon-run's dask batch (ADMM, "
                         "300x400) with 1 and 2 local workers, as a ratio to a single-process "
                         "loop over the same frames, and a chart.")
    ap.add_argument("--frames", type=int, default=16, help="frames of the run (default 16)")
    ap.add_argument("--iterations", type=int, default=100,
                    help="ADMM iterations per frame (default 100)")
    ap.add_argument("--out", type=Path, default=Path("out/benchmark-batch"),
                    help="directory for batch.png and batch.json (default out/benchmark-batch)")
    ap.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")
    ap.set_defaults(handler=run_batch_benchmark)
    sp = bsub.add_parser("volume-scale", help="the seed-size 3D problem (2048 x 2048 x 128) "
                         "generated on the fly, streamed in one process or sharded over dask "
                         "workers: peak memory vs estimate, seconds per iteration vs the FFT "
                         "floor, bytes moved per worker",
                         description="Generates a depth-scaled PSF stack from the tutorial PSF "
                         "(a per-plane Zarr store in a temporary directory) and a scene of "
                         "beads and extended objects, then runs streamed 3D FISTA (--workers "
                         "0) or the same sharded over a LocalCluster. Needs about 17 GB at the "
                         "default size; try --sensor 512 --planes 32 first.")
    sp.add_argument("--sensor", type=int, default=2048, help="sensor side, px (default 2048)")
    sp.add_argument("--planes", type=int, default=128, help="depth planes (default 128)")
    sp.add_argument("--iterations", type=int, default=4, help="FISTA iterations (default 4)")
    sp.add_argument("--tv", type=float, default=1e-5, help="3D TV weight (default 1e-5)")
    sp.add_argument("--bead-light", type=float, default=None,
                    help="each bead's light in pixels of an extended object (default 50 x "
                    "(sensor/512)^2: the same scene at every sensor size)")
    sp.add_argument("--workers", type=int, default=0,
                    help="0 (default): one process; K: a LocalCluster of K workers")
    sp.add_argument("--worker-memory", default="10GB",
                    help="memory limit per worker (default 10GB)")
    sp.add_argument("--work-dir", default=None,
                    help="where the temporary PSF store goes (default the system's temp dir)")
    sp.add_argument("--save-estimate", type=Path, default=None,
                    help="write the volume (.npy) here, to compare another run with")
    sp.add_argument("--compare-with", type=Path, default=None,
                    help="an earlier run's --save-estimate: report the relative difference")
    sp.add_argument("--json", type=Path, default=None, help="also write the figures here")
    sp.add_argument("--overwrite", action="store_true",
                    help="replace an existing --json / --save-estimate")
    sp.set_defaults(handler=run_volume_scale_benchmark)
    mp = bsub.add_parser("memory-limit", help="recon3d under --memory-limit: refused below "
                         "every plan's estimate, the measured peak within the limit at each "
                         "plan (two sizes, automatic and fixed weight)",
                         description="Runs recon3d in fresh processes on a synthetic problem "
                         "per size, with the automatic and a fixed weight: with a limit below "
                         "every plan (refused, exit status 2, naming the smallest limit), "
                         "just below that limit (refused), at it and at every other plan's "
                         "estimate (solved; the process's peak resident set must be within "
                         "the limit). About 5 minutes at the default sizes.")
    mp.add_argument("--sizes", default="256x8,512x16",
                    help="comma-separated SIDExPLANES problems (default 256x8,512x16)")
    mp.add_argument("--iterations", type=int, default=10,
                    help="iterations of each solve (default 10)")
    mp.add_argument("--work-dir", default=None,
                    help="where the temporary problem files go (default the system's temp dir)")
    mp.add_argument("--json", type=Path, default=None, help="also write the figures here")
    mp.add_argument("--overwrite", action="store_true", help="replace an existing --json")
    mp.set_defaults(handler=run_memory_limit_benchmark)


def run_recon_benchmarks(args: argparse.Namespace) -> int:
    """Run ``benchmark recon``; returns 0 (bad input exits 2 through the boundary)."""
    from instrument.benchmarks.run import format_result, run_benchmarks

    from ..writer.guards import check_outputs

    # summary.json is written by every run: an --out holding one holds earlier results
    check_outputs([args.out / "summary.json"], None, args.overwrite, directory=args.out)

    def show(name: str, result: dict, seconds: float) -> None:
        print(format_result(name, result))
        print(f"({name}: {seconds:.1f} s)", flush=True)

    _, text = run_benchmarks(args.out, quick=args.quick, only=args.only, on_result=show)
    print(text)
    print(f"results in {args.out}")
    return 0


def run_gpu_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark gpu`` (:func:`instrument.benchmarks.gpu.run_gpu_benchmark`); returns 0."""
    from diffuserlab.jsonio import jsonable
    from instrument.benchmarks.gpu import run_gpu_benchmark as run
    from recon.errors import ReconInputError

    from ..atomic import write_json
    from ..writer.guards import check_outputs

    if args.iterations is not None and args.iterations < 2:
        raise ReconInputError(f"--iterations {args.iterations}: give 2 or more (the first "
                              "iteration carries the set-up and is not counted)")
    if args.json is not None:
        check_outputs([args.json], None, args.overwrite, option="--json")
    print("benchmark gpu: median s per iteration (live: per frame of 5 ADMM iterations), "
          "ratio of one iteration to the backend's FFT floor, speed-up over the NumPy path",
          flush=True)
    result = run(quick=args.quick, iterations=args.iterations,
                 include_torch_cpu=not args.no_torch_cpu,
                 log=lambda line: print(line, flush=True))
    if args.json is not None:
        write_json(args.json, jsonable(result, nonfinite_to_none=True))
        print(f"figures in {args.json}")
    return 0


def run_live_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark live``; returns 0 (bad input exits 2 through the boundary)."""
    from diffuserlab.jsonio import jsonable
    from recon.errors import ReconInputError
    from recon.fft import check_threads

    from ..atomic import write_json
    from ..benchmarks.live import run_live_benchmark as run
    from ..writer.guards import check_outputs

    if not (0 < args.seconds <= 600 and 0 < args.fps and args.iterations >= 1):
        raise ReconInputError(f"--seconds {args.seconds}, --fps {args.fps}, --iterations "
                              f"{args.iterations}: give 0 < seconds <= 600, fps > 0 and "
                              "iterations >= 1")
    if args.threads is not None:
        check_threads(args.threads)
    if args.json is not None:
        check_outputs([args.json], None, args.overwrite, option="--json")
    result = run(args.seconds, args.fps, admm_iterations=args.iterations,
                 threads=args.threads)
    print(result["text"])
    if args.json is not None:
        figures = {k: v for k, v in result.items() if k != "text"}
        write_json(args.json, jsonable(figures, nonfinite_to_none=True))
        print(f"figures in {args.json}")
    return 0


def run_recording_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark recording``; returns 0 (bad input exits 2 through the boundary)."""
    from diffuserlab.jsonio import jsonable
    from recon.errors import ReconInputError

    from ..acquisition.video import DEFAULT_COMPRESSOR
    from ..atomic import write_json
    from ..benchmarks.acquisition import recording_table
    from ..benchmarks.acquisition import run_recording_benchmark as run
    from ..runs.runstore import FRAME_COMPRESSORS
    from ..writer.guards import check_outputs

    seconds = 600.0 if args.long else args.seconds
    comps = (DEFAULT_COMPRESSOR,) if args.long else tuple(
        c.strip() for c in args.compressors.split(",") if c.strip())
    bad = [c for c in comps if c not in FRAME_COMPRESSORS]
    if bad or not comps:
        raise ReconInputError(f"--compressors {args.compressors}: use names from "
                              f"{list(FRAME_COMPRESSORS)}")
    if not (0 < seconds <= 3600 and 0 < args.fps):
        raise ReconInputError(f"--seconds {seconds}, --fps {args.fps}: give 0 < seconds <= "
                              "3600 and fps > 0")
    if args.json is not None:
        check_outputs([args.json], None, args.overwrite, option="--json")
    result = run(seconds, args.fps, compressors=comps, directory=args.dir)
    print(recording_table(result))
    if args.json is not None:
        write_json(args.json, jsonable(result, nonfinite_to_none=True))
        print(f"figures in {args.json}")
    return 0


def run_volume_scale_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark volume-scale``; returns 0 (bad input exits 2 through the boundary)."""
    from drivers.base import jsonable
    from recon.errors import ReconInputError

    from ..atomic import write_json
    from ..benchmarks.volume_scale import run_volume_scale, volume_scale_table
    from ..writer.guards import check_outputs

    if args.bead_light is not None and not args.bead_light > 0:
        raise ReconInputError(f"--bead-light {args.bead_light}: give a positive light (pixels "
                              "of an extended object; leave it out for the scale-consistent "
                              "default)")
    if args.sensor < 16 or args.planes < 2 or args.iterations < 1 or args.workers < 0 \
            or args.workers > args.planes:
        raise ReconInputError(f"--sensor {args.sensor}, --planes {args.planes}, --iterations "
                              f"{args.iterations}, --workers {args.workers}: give sensor >= 16, "
                              "planes >= 2, iterations >= 1 and 0 <= workers <= planes")
    outs = [p for p in (args.json, args.save_estimate) if p is not None]
    check_outputs(outs, {"--compare-with": args.compare_with} if args.compare_with else None,
                  args.overwrite)
    result = run_volume_scale(sensor=args.sensor, planes=args.planes,
                              iterations=args.iterations, tv=args.tv, workers=args.workers,
                              worker_memory=args.worker_memory, work_dir=args.work_dir,
                              save_estimate=(None if args.save_estimate is None
                                             else str(args.save_estimate)),
                              compare_with=(None if args.compare_with is None
                                            else str(args.compare_with)),
                              bead_light=args.bead_light,
                              announce=lambda line: print(line, flush=True))
    print(volume_scale_table(result))
    if args.json is not None:
        write_json(args.json, jsonable(result, nonfinite_to_none=True))
    return 0


def run_memory_limit_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark memory-limit``; returns 0 (bad input exits 2 through the boundary)."""
    from diffuserlab.jsonio import jsonable
    from recon.errors import ReconInputError

    from ..atomic import write_json
    from ..benchmarks.memory_limit import memory_limit_table, run_memory_limit
    from ..writer.guards import check_outputs

    sizes = []
    for item in args.sizes.split(","):
        side, _, planes = item.strip().lower().partition("x")
        if not (side.isdigit() and planes.isdigit() and int(side) >= 16 and int(planes) >= 2):
            raise ReconInputError(f"--sizes {args.sizes!r}: give SIDExPLANES items, side >= 16 "
                                  "and planes >= 2, e.g. 256x8,512x16")
        sizes.append((int(side), int(planes)))
    if args.iterations < 1:
        raise ReconInputError(f"--iterations {args.iterations}: give 1 or more")
    if args.json is not None:
        check_outputs([args.json], None, args.overwrite, option="--json")
    result = run_memory_limit(sizes=sizes, iterations=args.iterations, work_dir=args.work_dir,
                              announce=lambda line: print(line, flush=True))
    print(memory_limit_table(result).splitlines()[-1])
    if args.json is not None:
        write_json(args.json, jsonable(result, nonfinite_to_none=True))
        print(f"figures in {args.json}")
    return 0


def run_batch_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark batch``; returns 0 (bad input exits 2 through the boundary)."""
    from diffuserlab.jsonio import jsonable
    from recon.errors import ReconInputError

    from ..atomic import write_json
    from ..benchmarks.acquisition import batch_table
    from ..benchmarks.acquisition import run_batch_benchmark as run
    from ..writer.guards import check_outputs

    if args.frames < 2 or args.iterations < 1:
        raise ReconInputError(f"--frames {args.frames}, --iterations {args.iterations}: give "
                              "frames >= 2 and iterations >= 1")
    files = [args.out / "batch.png", args.out / "batch.json"]
    check_outputs(files, None, args.overwrite, directory=args.out)
    result = run(args.frames, args.iterations, chart=files[0])
    write_json(files[1], jsonable(result, nonfinite_to_none=True))
    print(batch_table(result))
    print(f"chart and figures in {args.out}")
    return 0
