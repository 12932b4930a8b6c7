"""``diffuserlab recon3d``: a volume from one DiffuserCam image and a PSF stack (Kuo 2020, Ch. 4).

Loads a PSF stack (a run store ``RUN.zarr``, a TIFF stack with depths in its
metadata, or a TIFF / ``.npy`` stack with ``--depths``) and one raw measurement and
reconstructs the volume with :func:`recon.reconstruct_volume` (dark subtraction,
lateral binning, the scaling of the 2D API, the 3D forward model of Eq. 4.4, 3D
FISTA or 3D ADMM). Writes the sensor field of view of every plane as a float32
volume (TIFF or Zarr v3, depths attached), the three maximum-intensity projections
as PNG and, if asked, the metrics JSON (the 2D record plus depths and the 3D FFT
floor); see :func:`instrument.processing.reconstruct_files.run_recon3d`.

Bad input exits with status 2 and one line; a diverging solver with status 3.
"""

from __future__ import annotations

import argparse

from diffuserlab.errors import InputError

from ..options import check_pitch_um
from .common import floats, size_bytes

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
    from .recon_flags import add_recon_flags

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
    add_recon_flags(p, "recon3d")
    p.add_argument("--planes", choices=("all", "auto"), default="all",
                   help="all (default): every plane of the stack; auto: the calibrated "
                   "planes nearest those that Nyquist-sample the measured axial "
                   "resolution (Sec. 4.4, as `analyze grid`; needs --pitch-um and --d-mm)")
    p.add_argument("--pitch-um", type=float, default=None,
                   help="sensor pixel pitch, um, unbinned: the volume's pixel size "
                   "(times --bin; default the PSF run's) and for --planes auto")
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
    p.add_argument("--memory-limit", default=None, metavar="SIZE",
                   help="the most this process's memory may reach, e.g. 16GB (default: what "
                   "it holds plus what the machine has available); when the in-memory solve "
                   "needs more, streamed 3D FISTA runs (planes transformed a chunk or one at "
                   "a time, the volume on the sensor's field of view) and says so; below "
                   "every plan, refused before any work with the smallest limit that would "
                   "do")
    p.add_argument("--scheduler", default=None,
                   help="address of a dask.distributed scheduler (tcp://host:8786): streamed "
                   "3D FISTA with the planes split into slabs over its workers")
    from .grid_options import add_grid_options

    add_grid_options(p, volume=True)
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
    """Run ``recon3d`` (:func:`instrument.processing.reconstruct_files.run_recon3d`) and print its
    summary line; returns 0 (bad input exits 2 and divergence 3 through
    :func:`instrument.cli.main`)."""
    from ..processing.reconstruct_files import run_recon3d
    from ..processing.volume_shards import slab_workers
    from ..writer.guards import check_outputs
    from ..writer.products import volume_output_paths
    from .recon_flags import check_device, check_recon_flags

    depths = None if args.depths is None else floats(args.depths, "--depths")
    if (args.psf_stack is None) == (args.psf_grid is None):
        raise InputError("recon3d needs --psf-stack or --psf-grid (psf-grid runs), not both")
    options = check_recon_flags(args)
    check_device(args.device)
    check_pitch_um(args.pitch_um)
    memory_limit = None if args.memory_limit is None else size_bytes(args.memory_limit)
    if args.psf_grid:
        from .grid_options import run_grid

        return run_grid(args, volume=True, depths=depths)
    vol, mips = volume_output_paths(args.out)
    outputs = [vol, *mips.values(), *([args.metrics_json] if args.metrics_json else [])]
    check_outputs(outputs, {"--psf-stack": args.psf_stack, "--raw": args.raw}, args.overwrite)
    with slab_workers(args.scheduler) as slab_group:
        m = run_recon3d(args.psf_stack, args.raw, options, out=args.out, depths_mm=depths,
                        psf_product=args.psf_product, metrics_json=args.metrics_json,
                        planes=args.planes, pitch_um=args.pitch_um, d_mm=args.d_mm,
                        scene_range_mm=(None if args.scene_range is None
                                        else floats(args.scene_range, "--scene-range")),
                        memory_limit_bytes=memory_limit, slab_group=slab_group,
                        overwrite=args.overwrite)
    if m.get("planes"):
        print(m["planes"]["reason"])
    auto = m.get("auto")
    if auto:
        print(f"{auto['regulariser']} weight {auto['weight']:.3g}, planes kept "
              f"{auto['planes_kept']}: {auto['reason']}")
    print(summary_line(m))
    mem = m.get("memory")
    if mem:
        print(f"peak memory {mem['peak_rss_bytes'] / 1e9:.2f} GB measured (this process), "
              f"{mem['estimate_bytes'] / 1e9:.2f} GB estimated "
              f"({100 * (mem['peak_over_estimate'] - 1):+.0f} %)")
    return 0
