"""``diffuserlab recon``: one image from a PSF and a raw measurement (files in, files out).

The work is :func:`instrument.processing.reconstruct_files.run_recon`; this module parses the
options and prints the one-line summary.
"""

from __future__ import annotations

import argparse

__all__ = ["add_subcommands", "choice_lines", "run", "summary_line"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``recon`` to the ``diffuserlab`` subparsers (``handler=run``)."""
    from .recon_flags import add_recon_flags

    rp = sub.add_parser("recon", help="reconstruct an image from a PSF and a raw measurement")
    rp.add_argument("--psf", default=None,
                    help="PSF image (TIFF, PNG/JPEG or .npy), or a PSF stack: a run store "
                    "(RUN.zarr from `calibrate psf-sweep`) or a TIFF stack, with --depth "
                    "(or --psf-grid instead)")
    rp.add_argument("--depth", type=float, default=None, dest="depth_mm",
                    help="depth (mm) of the stack's PSF to use (nearest plane within 5%%)")
    rp.add_argument("--psf-product", default="psf_stack",
                    help="which stack of a run: psf_stack (background removed, Sec. 6.4; "
                    "default) or psf_stack_raw (dark-subtracted only: better for extended "
                    "scenes when stray light is low, see the README)")
    rp.add_argument("--raw", required=True, help="raw measurement, same shape as the PSF")
    add_recon_flags(rp, "recon")
    rp.add_argument("--out", default="out/recon.png",
                    help="output image; writes OUT.png (viewing) and OUT.tif (float32)")
    rp.add_argument("--metrics-json", default=None, help="write the metrics JSON here")
    rp.add_argument("--pitch-um", type=float, default=None,
                    help="sensor pixel pitch, um, unbinned: OUT.tif's pixel size (times "
                    "--bin); default: the PSF run's, else none")
    rp.add_argument("--overwrite", action="store_true",
                    help="replace existing output files (never an input)")
    from .grid_options import add_grid_options

    add_grid_options(rp, volume=False, solver=True)
    rp.set_defaults(handler=run)


def choice_lines(m: dict) -> list[str]:
    """What the automatic choices chose and why (first channel), for the terminal."""
    rec = (m.get("auto") or [{}])[0]
    lines = [f"method {m['method']}: {r}" for r in rec.get("method", {}).get("reasons", [])]
    if m.get("calibration"):  # a scene calibration's recipe (recon.early_stop)
        c = m["calibration"]
        lines.append(f"the PSF's scene-calibration recipe: PSF threshold {c['psf_threshold']:g}"
                     f" of its maximum, {c['iterations']} FISTA iterations, TV denoising "
                     f"{c['denoise_weight']:g}"
                     + (", then its field response (dark where the calibration scenes were "
                        "dark)" if c.get("field_response") else "")
                     + " (--early-stop off declines it)")
    w = rec.get("weight")
    if w:
        lines.append(f"{w['regulariser']} weight {w['weight']:.3g}: {w['reason']}")
    if m.get("iterations_used") is not None and m["method"] != "wiener":
        lines.append(f"iterations used: {m['iterations_used']} (maximum {m['iterations']}"
                     f"{' per phase of the automatic weight' if w else ''})")
    return lines


def summary_line(m: dict) -> str:
    """One line of a ``recon`` metrics record for the terminal."""
    return (
        f"{m['method']}: {m.get('iterations_used', m['iterations'])} it, {m['shape']} "
        f"(padded {m['padded_shape']}), "
        f"{m['seconds_total']:.2f} s total, {m['seconds_per_iteration'] * 1e3:.2f} ms/it = "
        f"{m['ratio_to_fft_floor']:.2f}x FFT floor ({m['fft_pair_seconds'] * 1e3:.2f} ms), "
        f"final relative residual {m['final_relative_residual']:.4f} -> "
        f"{m['output_png']}"
    )


def run(args: argparse.Namespace) -> int:
    """Run ``recon`` and print its summary line; returns 0 (errors go to the boundary)."""
    from ..options import check_pitch_um
    from ..processing.reconstruct_files import run_recon
    from ..writer.guards import check_outputs
    from ..writer.products import output_paths
    from .recon_flags import check_device, check_recon_flags

    if (args.psf is None) == (args.psf_grid is None):
        from recon.errors import ReconInputError

        raise ReconInputError("recon needs --psf (a PSF) or --psf-grid (a psf-grid run), "
                              "not both")
    options = check_recon_flags(args)
    check_pitch_um(args.pitch_um)
    check_device(args.device)
    if args.psf_grid:
        from .grid_options import run_grid

        return run_grid(args, volume=False)
    outputs = [*output_paths(args.out), *([args.metrics_json] if args.metrics_json else [])]
    check_outputs(outputs, {"--psf": args.psf, "--raw": args.raw}, args.overwrite)
    m = run_recon(args.psf, args.raw, options, out=args.out, metrics_json=args.metrics_json,
                  depth_mm=args.depth_mm, psf_product=args.psf_product,
                  pitch_um=args.pitch_um)
    for line in choice_lines(m):
        print(line)
    print(summary_line(m))
    return 0
