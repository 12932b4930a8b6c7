"""The ``--psf-grid`` options of ``recon``, ``recon3d`` and ``recon-run`` (spatially varying
models).

:func:`add_grid_options` adds ``--psf-grid``, ``--model``, ``--pca-k``,
``--background``, ``--grid-l1``, (not on ``recon-run``, whose ``--dark`` serves)
``--grid-dark`` and (``recon`` only: one plane) ``--grid-method`` and ``--two-part``;
:func:`run_grid` checks the outputs and runs
:func:`instrument.reconstruct_grid.run_recon_grid`, printing one summary line.
"""

from __future__ import annotations

import argparse

__all__ = ["add_grid_options", "run_grid"]


def add_grid_options(p: argparse.ArgumentParser, *, volume: bool,
                     grid_dark: bool = True, solver: bool = False) -> None:
    """Add the PSF-grid options to the ``recon`` (2D), ``recon3d`` or ``recon-run``
    (``grid_dark=False``: its ``--dark`` gives the frames' level) parser; ``solver``
    adds ``--grid-method`` and ``--two-part`` (``recon``, whose ``--tv`` and ``--l1``
    then serve ADMM)."""
    from recon.spatial.api import GRID_METHODS
    from recon.spatial.choice import MODELS

    g = p.add_argument_group(
        "spatially varying model (Ch. 5): a calibrate psf-grid run instead of a PSF")
    g.add_argument("--psf-grid", action="append", default=None, metavar="RUN.zarr",
                   help="a `calibrate psf-grid` run (registered PSFs of one depth); "
                   + ("repeat it, one run per depth, for a volume (depths between the runs "
                      "are synthesised with --depths)" if volume else "one run"))
    g.add_argument("--model", choices=MODELS, default="auto",
                   help="forward model: auto (the cheapest whose predicted model error is "
                   "within 0.1: convolution, PCA with the smallest k, local), convolution "
                   "(central PSF), local (every grid PSF, Eq. 5.3-5.5) or pca (Eq. 5.6-5.7)")
    g.add_argument("--pca-k", type=int, default=None,
                   help="principal PSFs of --model pca (default: 99 %% explained energy)")
    g.add_argument("--background", choices=("estimate", "none"), default="estimate",
                   help="estimate a smooth background jointly (Eq. 6.2, lowest 5x5 DCT; "
                   "default) or none")
    g.add_argument("--grid-l1", type=float, default=1e-3,
                   help="l1 weight of the --psf-grid FISTA solver in the scaled problem")
    if solver:
        g.add_argument("--grid-method", choices=GRID_METHODS, default="fista",
                       help="solver of the --psf-grid model: fista (default; Eq. 6.2 with "
                       "--background and --grid-l1) or admm (TV --tv, auto by default, l1 "
                       "--l1, non-negativity; needs --background none; a few hundred "
                       "iterations where FISTA needs thousands)")
        g.add_argument("--two-part", action="store_true",
                       help="a far scene (Eq. 5.1): model each grid PSF over its brightness "
                       "(pixels the sensor missed from the nearest node) and divide the "
                       "image by the brightness map measured from the grid")
    if not grid_dark:
        return
    g.add_argument("--grid-dark", type=float, default=0.0,
                   help="level (DN) subtracted from the raw frame (the psf-grid PSFs are "
                   "dark-subtracted); with --background estimate an offset is also estimated")


def run_grid(args: argparse.Namespace, *, volume: bool, depths=None) -> int:
    """Run a ``--psf-grid`` reconstruction and print its summary line."""
    from ..output_safety import check_outputs
    from ..reconstruct_files import output_paths, volume_output_paths
    from ..reconstruct_grid import background_output, run_recon_grid

    if volume:
        vol, mips = volume_output_paths(args.out)
        outputs = [vol, *mips.values()]
    else:
        outputs = list(output_paths(args.out))
    if args.background == "estimate":
        outputs.append(background_output(args.out, volume))
    if args.metrics_json:
        outputs.append(args.metrics_json)
    inputs = {f"--psf-grid {p}": p for p in args.psf_grid}
    check_outputs(outputs, {**inputs, "--raw": args.raw}, args.overwrite)
    method = getattr(args, "grid_method", "fista")
    m = run_recon_grid(args.psf_grid, args.raw, model=args.model, k=args.pca_k,
                       background=args.background,
                       l1=args.l1 if method == "admm" else args.grid_l1,
                       iterations=args.iterations, out=args.out,
                       metrics_json=args.metrics_json, depths_mm=depths,
                       bin_factor=args.bin_factor, dark=args.grid_dark, volume=volume,
                       method=method, tv=getattr(args, "tv", "auto"),
                       two_part=getattr(args, "two_part", False))
    where = m.get("output_volume") or m["output_png"]
    weight = (m.get("auto") or {}).get("weight")
    if weight:
        print(f"{weight['regulariser']} weight {weight['weight']:.3g}: {weight['reason']}")
    solver = (f"ADMM, TV {m['tv']:.3g}, {m['iterations_used']} it" if method == "admm"
              else f"{m['iterations']} it")
    print(f"{m['model']['label']} model ({m['n_kernels']} convolutions per apply; "
          f"{m['model']['reason']}), background {m['background']}"
          f"{', two-part (brightness divided out)' if m['two_part'] else ''}: {solver}, "
          f"{m['seconds_per_iteration'] * 1e3:.1f} ms/it = {m['ratio_to_fft_floor']:.2f}x "
          f"FFT floor, final relative residual {m['final_relative_residual']:.4f} -> {where}")
    return 0
