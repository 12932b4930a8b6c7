"""``diffuserlab benchmark design``: the mask design comparison of Sec. 6.3 (Fig. 6.2-6.3).

Runs :func:`recon.benchmarks.design.run_design` (objective lens, smooth diffuser,
regular microlens array and random microlens diffuser on the microscope's
numbers: PSNR against collected photons and against Gaussian noise, 2D and
depth-resolved, and the regular array's periodic ghosts), prints its table and the
ordering it found, and writes ``OUT/design.json`` and ``OUT/design.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_parser", "run_design_benchmark"]


def add_parser(bsub: argparse._SubParsersAction) -> None:
    """Add ``design`` to the ``benchmark`` subparsers (called by :mod:`.benchmark`)."""
    p = bsub.add_parser(
        "design", help="mask designs of the diffuser microscope (Sec. 6.3): PSNR vs photons "
        "and vs Gaussian noise, 2D and 3D, for objective, smooth diffuser, regular and random "
        "microlenses",
        description="Reconstruct sparse fluorescent objects (2D, and 3 depths) imaged by an "
        "objective lens, a smooth diffuser, a regular microlens array and a random microlens "
        "diffuser over sweeps of collected photons (shot noise) and Gaussian noise; print "
        "the PSNR table and the ordering, write design.json and design.png.")
    p.add_argument("--out", type=Path, default=Path("out/benchmark-design"),
                   help="directory for design.json and design.png (default "
                   "out/benchmark-design)")
    p.add_argument("--quick", action="store_true",
                   help="64 x 64 patch, 2 levels per sweep, 40 iterations (tests, ~30 s)")
    p.add_argument("--overwrite", action="store_true", help="replace earlier results in --out")
    p.set_defaults(handler=run_design_benchmark)


def run_design_benchmark(args: argparse.Namespace) -> int:
    """Run ``benchmark design``; returns 0 (bad input exits 2 through the boundary)."""
    from recon.benchmarks.design import design_table, run_design

    from ..output_safety import check_outputs

    files = [args.out / "design.json", args.out / "design.png"]
    check_outputs(files, None, args.overwrite, directory=args.out)
    result = run_design(args.quick, args.out)
    print(design_table(result))
    print(f"({result['seconds']:.0f} s) results in {args.out}")
    return 0
