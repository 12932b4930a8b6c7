"""The ``--psf-grid`` options of ``recon``, ``recon3d`` and ``recon-run`` (spatially varying
models).

:func:`add_grid_options` adds ``--psf-grid``, ``--model``, ``--pca-k``,
``--background`` and (``recon`` only: one plane) ``--two-part``; the solver, its l1
weight and the frame's dark level are the commands' own ``--method``, ``--l1`` and
``--dark`` (:mod:`instrument.cli.recon_flags`), whose former twins ``--grid-method``,
``--grid-l1`` and ``--grid-dark`` remain as hidden deprecated aliases.
:func:`run_grid` checks the outputs and runs
:func:`instrument.processing.reconstruct_grid.run_recon_grid`, printing one summary line.
"""

from __future__ import annotations

import argparse

__all__ = ["add_grid_options", "run_grid"]


def add_grid_options(p: argparse.ArgumentParser, *, volume: bool,
                     grid_dark: bool = True, solver: bool = False) -> None:
    """Add the PSF-grid options to the ``recon`` (2D), ``recon3d`` or ``recon-run``
    parser, with the hidden deprecated aliases ``--grid-l1`` and (``grid_dark``)
    ``--grid-dark``; ``solver`` adds ``--two-part`` and the alias ``--grid-method``
    (``recon``, whose ``--method admm`` solves a grid with ``--tv`` and ``--l1``)."""
    from recon.options import GRID_METHODS, dark_arg

    from .recon_flags import add_deprecated, add_recon_flags

    g = p.add_argument_group(
        "spatially varying model (Ch. 5): a calibrate psf-grid run instead of a PSF")
    g.add_argument("--psf-grid", action="append", default=None, metavar="RUN.zarr",
                   help="a `calibrate psf-grid` run (registered PSFs of one depth); "
                   + ("repeat it, one run per depth, for a volume (depths between the runs "
                      "are synthesised with --depths)" if volume else "one run"))
    add_recon_flags(g, "", fields=("model", "k", "background",
                                   *(("two_part",) if solver else ())))
    add_deprecated(g, "--grid-l1", "--l1", "l1", type=float)
    if solver:
        add_deprecated(g, "--grid-method", "--method", "method", choices=GRID_METHODS)
    if grid_dark:
        add_deprecated(g, "--grid-dark", "--dark", "dark", type=dark_arg)


def run_grid(args: argparse.Namespace, *, volume: bool, depths=None) -> int:
    """Run a ``--psf-grid`` reconstruction and print its summary line."""
    from recon.options import GRID_METHODS, ReconOptions

    from ..processing.reconstruct_grid import background_output, run_recon_grid
    from ..writer.guards import check_outputs
    from ..writer.products import output_paths, volume_output_paths
    from .recon_flags import dark_for_grid, grid_method

    method = grid_method(args.method, GRID_METHODS)
    dark = dark_for_grid(args.dark)

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
    options = ReconOptions.from_namespace(args).replace(method=method, dark=dark)
    m = run_recon_grid(args.psf_grid, args.raw, options, out=args.out,
                       metrics_json=args.metrics_json, depths_mm=depths, volume=volume,
                       overwrite=args.overwrite)
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
