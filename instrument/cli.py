"""The ``diffuserlab`` command line.

Subcommands: ``recon`` (one reconstruction from files; the PSF may be one depth of
a run's PSF stack or of a TIFF stack), ``demo`` (the main job: a bench session on
the built-in simulated bench; ``--real-sample`` reconstructs the real DiffuserCam
sample instead), ``recon3d`` (a volume from one image and a PSF stack),
``analyze`` (resolution, similarity, conditioning, grid, field of view of a PSF
stack), ``validate`` / ``devices`` (bench files), ``runs`` (show, export, import
run stores), ``benchmark recon`` (speed vs FFT floor, accuracy, stability,
compressed sensing; 3D speed, memory and accuracy), plus the commands other layers
register under the entry-point group ``diffuserlab.commands`` (``calibrate`` from
calibration_routines). Bad input exits with status 2 and a one-line reason; a
diverging solver exits with status 3.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

log = logging.getLogger("diffuserlab")


def _output_paths(out: str) -> tuple[Path, Path]:
    """(png, tif) paths for ``--out``: an extension picks the stem, none adds both."""
    p = Path(out)
    stem = p.with_suffix("") if p.suffix.lower() in (".png", ".tif", ".tiff") else p
    return stem.with_suffix(".png"), stem.with_suffix(".tif")


def _load_psf(psf_path: str, depth_mm: float | None,
              product: str = "psf_stack") -> tuple[np.ndarray, float | None]:
    """A 2D PSF from an image, or one depth of a stack (run store, TIFF or .npy stack).

    Raises
    ------
    recon.errors.ReconInputError
        Unreadable input, or a stack without a matching depth.
    """
    from recon.errors import ReconInputError
    from recon.io import load_image

    from .runstore import RunStoreError
    from .stacks import load_psf_stack, pick_depth

    path = Path(psf_path)
    if not path.is_dir() and depth_mm is None:
        return load_image(psf_path), None
    try:
        stack, depths, _ = load_psf_stack(path, product=product)
        psf, depth = pick_depth(stack, depths, depth_mm)
    except RunStoreError as exc:
        raise ReconInputError(str(exc)) from exc
    return psf, depth


def run_recon(
    psf_path: str,
    raw_path: str,
    *,
    method: str,
    iterations: int,
    bin_factor: int,
    tv: float | None,
    erase: float,
    seed: int,
    full_scale: float | None = None,
    out: str,
    metrics_json: str | None,
    depth_mm: float | None = None,
    psf_product: str = "psf_stack",
) -> dict:
    """Load, reconstruct, write PNG + float32 TIFF (+ metrics JSON); return metrics.

    Raises
    ------
    recon.errors.ReconInputError
        Bad files or parameters.
    recon.errors.DivergenceError
        The solver diverged.
    """
    from recon import reconstruct
    from recon.fft import fft_pair_seconds
    from recon.io import load_image, save_image

    psf, depth = _load_psf(psf_path, depth_mm, psf_product)
    raw = load_image(raw_path)
    result = reconstruct(
        psf,
        raw,
        method,
        iterations,
        tv=tv,
        bin_factor=bin_factor,
        erase=erase,
        seed=seed,
        full_scale=full_scale,
    )
    floor = float(np.median([fft_pair_seconds(result.operator.padded_shape) for _ in range(3)]))
    metrics = result.metrics(floor)
    metrics.update(psf=str(psf_path), raw=str(raw_path), seed=seed, psf_depth_mm=depth)
    png, tif = _output_paths(out)
    save_image(png, result.image)
    save_image(tif, result.image)
    metrics.update(output_png=str(png), output_tiff=str(tif))
    if metrics_json:
        Path(metrics_json).parent.mkdir(parents=True, exist_ok=True)
        Path(metrics_json).write_text(json.dumps(metrics, indent=1))
    return metrics


def _summary(m: dict) -> str:
    return (
        f"{m['method']}: {m['iterations']} it, {m['shape']} (padded {m['padded_shape']}), "
        f"{m['seconds_total']:.2f} s total, {m['seconds_per_iteration'] * 1e3:.2f} ms/it = "
        f"{m['ratio_to_fft_floor']:.2f}x FFT floor ({m['fft_pair_seconds'] * 1e3:.2f} ms), "
        f"final relative residual {m['final_relative_residual']:.4f} -> "
        f"{m['output_png']}"
    )


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of ``diffuserlab`` (documented in the README)."""
    from recon.solvers import METHODS

    parser = argparse.ArgumentParser(prog="diffuserlab", description=__doc__.split("\n")[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    rp = sub.add_parser("recon", help="reconstruct an image from a PSF and a raw measurement")
    rp.add_argument("--psf", required=True,
                    help="PSF image (TIFF, PNG/JPEG or .npy), or a PSF stack: a run store "
                    "(RUN.zarr from `calibrate psf-sweep`) or a TIFF stack, with --depth")
    rp.add_argument("--depth", type=float, default=None, dest="depth_mm",
                    help="depth (mm) of the stack's PSF to use (nearest plane within 5%%)")
    rp.add_argument("--psf-product", default="psf_stack",
                    help="which stack of a run: psf_stack (background removed, Sec. 6.4; "
                    "default) or psf_stack_raw (dark-subtracted only: better for extended "
                    "scenes when stray light is low, see the README)")
    rp.add_argument("--raw", required=True, help="raw measurement, same shape as the PSF")
    rp.add_argument("--method", choices=METHODS, default="admm")
    rp.add_argument("--iterations", type=int, default=100)
    rp.add_argument(
        "--bin",
        type=int,
        default=1,
        dest="bin_factor",
        help="box-binning factor (4: 1200x1600 -> 300x400)",
    )
    rp.add_argument(
        "--tv",
        type=float,
        default=None,
        help="TV weight in the scaled problem (default per method)",
    )
    rp.add_argument(
        "--erase",
        type=float,
        default=0.0,
        help="fraction of raw pixels to erase at random (compressed sensing)",
    )
    rp.add_argument("--seed", type=int, default=0, help="seed of the erasure mask")
    rp.add_argument(
        "--full-scale",
        type=float,
        default=None,
        help="saturation level if below the dtype max (65520: 12-bit in uint16)",
    )
    rp.add_argument(
        "--out",
        default="out/recon.png",
        help="output image; writes OUT.png (viewing) and OUT.tif (float32)",
    )
    rp.add_argument("--metrics-json", default=None, help="write the metrics JSON here")

    dp = sub.add_parser(
        "demo", help="main job: a bench session on the built-in simulated bench"
    )
    dp.add_argument("--out", default="out/demo", help="output directory")
    dp.add_argument("--method", choices=METHODS, default="admm")
    dp.add_argument("--iterations", type=int, default=200)
    dp.add_argument("--seed", type=int, default=0, help="seed of the simulated bench")
    dp.add_argument(
        "--real-sample",
        action="store_true",
        help="instead, reconstruct the real DiffuserCam tutorial sample (bin 4)",
    )

    bp = sub.add_parser("benchmark", help="benchmarks (speed vs FFT floor, accuracy, ...)")
    bp.add_argument("suite", choices=["recon"])
    bp.add_argument(
        "rest",
        nargs=argparse.REMAINDER,
        help="options of the suite (--quick, --out DIR, --only ...)",
    )
    hp = sub.add_parser("holo", help="holographic display: Table 7.1 evaluation, speed "
                        "benchmark (options after the action, e.g. --size 480)")
    hp.add_argument("action", choices=["evaluate", "benchmark"])
    hp.add_argument("rest", nargs=argparse.REMAINDER,
                    help="options of the action (--quick, --size N, --images DIR, --out DIR)")
    from instrument import analysis_cli, bench_cli, recon3d_cli, runs_cli

    bench_cli.add_subcommands(sub)
    runs_cli.add_subcommands(sub)
    recon3d_cli.add_subcommands(sub)
    analysis_cli.add_subcommands(sub)
    for add in _plugin_commands():
        add(sub)
    return parser


def _plugin_commands():
    """``add_subcommands(sub)`` functions registered under ``diffuserlab.commands``
    (packages above this layer, e.g. calibration_routines, add their commands so)."""
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group="diffuserlab.commands"), key=lambda e: e.name):
        try:
            yield ep.load()
        except ImportError as exc:  # a broken plugin must not take the CLI down
            log.warning("command plugin %s not loaded: %s", ep.name, exc)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``diffuserlab`` console script; returns the exit status."""
    from recon.errors import DivergenceError, ReconInputError

    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        if args.command == "recon":
            m = run_recon(
                args.psf,
                args.raw,
                method=args.method,
                iterations=args.iterations,
                bin_factor=args.bin_factor,
                tv=args.tv,
                erase=args.erase,
                seed=args.seed,
                full_scale=args.full_scale,
                out=args.out,
                metrics_json=args.metrics_json,
                depth_mm=args.depth_mm,
                psf_product=args.psf_product,
            )
            print(_summary(m))
        elif getattr(args, "handler", None) is not None:
            return int(args.handler(args) or 0)
        elif args.command == "runs":
            from instrument import runs_cli

            return runs_cli.run(args)
        elif args.command == "demo" and not args.real_sample:
            from .demo import run_demo

            run_demo(args.out, seed=args.seed, method=args.method, iterations=args.iterations)
        elif args.command == "demo":
            from recon.sample import data_dir

            data = data_dir()
            out = Path(args.out)
            m = run_recon(
                str(data / "psf_sample.tif"),
                str(data / "rawdata_hand_sample.tif"),
                method=args.method,
                iterations=args.iterations,
                bin_factor=4,
                tv=None,
                erase=0.0,
                seed=0,
                full_scale=65520.0,
                out=str(out / "hand.png"),
                metrics_json=str(out / "metrics.json"),
            )
            print(_summary(m))
        elif args.command == "benchmark":
            from recon.benchmarks.run import main as bench_main

            return int(bench_main(args.rest) or 0)
        elif args.command == "holo" and args.action == "evaluate":
            from recon.cgh.evaluate import main as holo_evaluate

            return int(holo_evaluate(args.rest) or 0)
        elif args.command == "holo":
            from recon.cgh.benchmark import main as holo_benchmark

            return int(holo_benchmark(args.rest) or 0)
        elif args.command in {"validate", "devices"}:
            from instrument import bench_cli

            return bench_cli.run(args)
    except ReconInputError as exc:
        print(f"diffuserlab: error: {exc}", file=sys.stderr)
        return 2
    except DivergenceError as exc:
        print(f"diffuserlab: diverged: {exc}", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
