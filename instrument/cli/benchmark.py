"""``diffuserlab benchmark recon``: the reconstruction benchmarks, 2D and 3D.

Runs :func:`recon.benchmarks.run.run_benchmarks` (speed vs the FFT floor, accuracy,
stability, compressed sensing; 3D speed, memory and accuracy), prints each
benchmark's table as it finishes and the summary at the end.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_subcommands", "run_recon_benchmarks"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``benchmark`` (with the suite ``recon``) to the ``diffuserlab`` subparsers."""
    from recon.benchmarks.run import BENCHMARKS

    bp = sub.add_parser("benchmark", help="benchmarks (speed vs FFT floor, accuracy, ...)")
    bsub = bp.add_subparsers(dest="suite", required=True)
    rp = bsub.add_parser("recon", help="speed, accuracy, stability and erasure benchmarks of "
                         "the reconstruction layer, 2D and 3D",
                         description="Speed, accuracy, stability and erasure benchmarks of "
                         "the reconstruction layer, 2D and 3D.")
    rp.add_argument("--out", type=Path, default=Path("out/benchmark"),
                    help="output directory (default out/benchmark)")
    rp.add_argument("--quick", action="store_true",
                    help="fewer iterations and sweep points, small 3D problems (tests/CI, "
                    "about 1 min)")
    rp.add_argument("--only", choices=BENCHMARKS, help="run a single benchmark")
    rp.add_argument("--overwrite", action="store_true",
                    help="replace the results of an earlier run in --out")
    rp.set_defaults(handler=run_recon_benchmarks)


def run_recon_benchmarks(args: argparse.Namespace) -> int:
    """Run ``benchmark recon``; returns 0 (bad input exits 2 through the boundary)."""
    from recon.benchmarks.run import format_result, run_benchmarks

    from ..output_safety import check_outputs

    # summary.json is written by every run: an --out holding one holds earlier results
    check_outputs([args.out / "summary.json"], None, args.overwrite, directory=args.out)

    def show(name: str, result: dict, seconds: float) -> None:
        print(format_result(name, result))
        print(f"({name}: {seconds:.1f} s)", flush=True)

    _, text = run_benchmarks(args.out, quick=args.quick, only=args.only, on_result=show)
    print(text)
    print(f"results in {args.out}")
    return 0
