"""``diffuserlab recon3d``: a volume from one DiffuserCam image and a PSF stack (Kuo 2020, Ch. 4).

Loads a PSF stack (a run store ``RUN.zarr``, a TIFF stack with depths in its
metadata, or a TIFF / ``.npy`` stack with ``--depths``) and one raw measurement and
reconstructs the volume with :func:`recon.reconstruct_volume` (dark subtraction,
lateral binning, the scaling of the 2D API, the 3D forward model of Eq. 4.4, 3D
FISTA or 3D ADMM). Writes the sensor field of view of every plane as a float32
volume (TIFF or Zarr v3, depths attached), the three maximum-intensity projections
as PNG and, if asked, the metrics JSON (the 2D record plus depths and the 3D FFT
floor); see :func:`instrument.reconstruct_files.run_recon3d`.

Bad input exits with status 2 and one line; a diverging solver with status 3.
"""

from __future__ import annotations

import argparse

from diffuserlab.errors import InputError

from .common import floats

__all__ = ["add_subcommands", "run", "summary_line"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``recon3d`` to the ``diffuserlab`` subparsers.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subparsers of the ``diffuserlab`` parser. The new parser's defaults
        carry ``handler=run``, so :func:`instrument.cli.main` dispatches to
        :func:`run` without naming the command; bad option values raise
        :class:`diffuserlab.errors.InputError` (exit 2).
    """
    from recon.options import L1_DEFAULT, VOLUME_METHODS, weight_arg

    from .recon_flags import L1_HELP, add_dark_option, add_device_option

    p = sub.add_parser("recon3d", help="reconstruct a volume from one image and a PSF stack")
    p.add_argument("--psf-stack", default=None,
                   help="PSF stack: a run store (RUN.zarr from `calibrate psf-sweep` or "
                   "`runs import-psf`), a TIFF stack (depths in its metadata or --depths) or "
                   "a .npy stack (n_z, rows, cols) with --depths; or --psf-grid instead")
    p.add_argument("--psf-product", default="psf_stack",
                   help="which stack of a run store (default psf_stack)")
    p.add_argument("--depths", default=None,
                   help="comma-separated depths in mm, one per plane (unless recorded)")
    p.add_argument("--raw", required=True, help="raw measurement, same size as the PSFs")
    p.add_argument("--method", default="auto", metavar="{auto," + ",".join(VOLUME_METHODS) + "}",
                   help="auto (default: admm; with --psf-grid fista), admm or fista")
    p.add_argument("--iterations", type=int, default=200,
                   help="iterations (default 200; the automatic weight's path, each weight "
                   "settled, takes at most 3.5x as many)")
    p.add_argument("--tv", type=weight_arg, default="auto",
                   help="3D TV weight in the scaled problem (unitless; 0 disables), or auto "
                   "(default): hold-out cross-validation along a 3D ADMM path; every plane is "
                   "kept and tested for signal")
    p.add_argument("--empty-planes", choices=("keep", "drop"), default="keep",
                   help="with an automatic weight: keep every plane (default) or set those "
                   "that show no signal in the held-out pixels to zero (reported)")
    p.add_argument("--l1", type=weight_arg, default=L1_DEFAULT, help=L1_HELP)
    p.add_argument("--bin", type=int, default=1, dest="bin_factor",
                   help="lateral box binning of every plane and of the raw image, pixels per "
                   "side")
    add_dark_option(p, auto="the median of the planes' dark corners psf[5:15, 5:15], "
                    "subtracted from the stack and the raw image; with --psf-grid nothing, "
                    "--background estimate fits the offset", frame="a dark run or image is "
                    "refused (one level is subtracted from the stack and the raw)")
    p.add_argument("--planes", choices=("all", "auto"), default="all",
                   help="all (default): every plane of the stack; auto: the calibrated "
                   "planes nearest those that Nyquist-sample the measured axial "
                   "resolution (Sec. 4.4, as `analyze grid`; needs --pitch-um and --d-mm)")
    p.add_argument("--pitch-um", type=float, default=None,
                   help="sensor pixel pitch, um, unbinned (for --planes auto)")
    p.add_argument("--d-mm", type=float, default=None,
                   help="diffuser-to-sensor distance, mm (for --planes auto)")
    p.add_argument("--scene-range", default=None,
                   help="ZMIN,ZMAX: depths (mm) the scene occupies, for --planes auto")
    p.add_argument("--out", default="out/volume.tif",
                   help="volume to write: OUT.tif (float32 TIFF, depths in its metadata) or "
                   "OUT.zarr (Zarr v3 array, depths attribute); projections go to "
                   "OUT_mip_{xy,xz,yz}.png")
    p.add_argument("--metrics-json", default=None, help="write the metrics JSON here")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing output files (never an input)")
    from .common import add_range_option
    from .grid_options import add_grid_options

    add_range_option(p)
    add_grid_options(p, volume=True)
    add_device_option(p)
    p.set_defaults(handler=run)


def summary_line(m: dict) -> str:
    """One line of a recon3d metrics record for the terminal."""
    return (f"{m['method']}: {m['iterations']} it, {m['n_planes']} planes of "
            f"{m['shape'][1]}x{m['shape'][2]} (padded {m['padded_shape']}), "
            f"{m['seconds_total']:.2f} s total, {m['seconds_per_iteration'] * 1e3:.1f} ms/it = "
            f"{m['ratio_to_fft_floor']:.2f}x FFT floor ({m['fft_floor_seconds'] * 1e3:.1f} ms), "
            f"final relative residual {m['final_relative_residual']:.4f} -> "
            f"{m['output_volume']}")


def run(args: argparse.Namespace) -> int:
    """Run ``recon3d`` (:func:`instrument.reconstruct_files.run_recon3d`) and print its
    summary line; returns 0 (bad input exits 2 and divergence 3 through
    :func:`instrument.cli.main`)."""
    from recon.options import l1_given

    from ..output_safety import check_outputs
    from ..reconstruct_files import run_recon3d, volume_output_paths
    from .recon_flags import check_device, dark_for_volume

    depths = None if args.depths is None else floats(args.depths, "--depths")
    if (args.psf_stack is None) == (args.psf_grid is None):
        raise InputError("recon3d needs --psf-stack or --psf-grid (psf-grid runs), not both")
    check_device(args.device)
    if args.psf_grid:
        from .grid_options import run_grid

        return run_grid(args, volume=True, depths=depths)
    dark = dark_for_volume(args.dark)
    vol, mips = volume_output_paths(args.out)
    outputs = [vol, *mips.values(), *([args.metrics_json] if args.metrics_json else [])]
    check_outputs(outputs, {"--psf-stack": args.psf_stack, "--raw": args.raw}, args.overwrite)
    m = run_recon3d(args.psf_stack, args.raw, method=args.method, iterations=args.iterations,
                    tv=args.tv, l1=float(args.l1) if l1_given(args.l1) is None else args.l1,
                    out=args.out,
                    depths_mm=depths,
                    bin_factor=args.bin_factor, dark=dark,
                    psf_product=args.psf_product, metrics_json=args.metrics_json,
                    planes=args.planes, device=args.device, pitch_um=args.pitch_um, d_mm=args.d_mm,
                    scene_range_mm=(None if args.scene_range is None
                                    else floats(args.scene_range, "--scene-range")),
                    allow_mixed_ranges=args.allow_mixed_ranges,
                    empty_planes=args.empty_planes)
    if m.get("planes"):
        print(m["planes"]["reason"])
    auto = m.get("auto")
    if auto:
        print(f"{auto['regulariser']} weight {auto['weight']:.3g}, planes kept "
              f"{auto['planes_kept']}: {auto['reason']}")
    print(summary_line(m))
    return 0
