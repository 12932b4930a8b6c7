"""``python -m benchmarks``: every reconstruction benchmark and study, with tables.

Runs :func:`benchmarks.run.run_benchmarks` (the package's speed benchmarks, then the
accuracy and method studies), prints each table as it finishes and the summary at
the end. Refuses an ``--out`` that holds an earlier run unless ``--overwrite``. Errors
are reported as by the ``diffuserlab`` command (bad input, an OS error: exit 2 and
one line naming the problem).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from .run import BENCHMARKS, format_result, run_benchmarks


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks``."""
    p = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="Speed, accuracy, stability and erasure benchmarks and the method "
        "studies of the reconstruction layer, 2D and 3D.")
    p.add_argument("--out", type=Path, default=Path("out/benchmark"),
                   help="output directory (default out/benchmark)")
    p.add_argument("--quick", action="store_true",
                   help="fewer iterations and sweep points, small 3D problems (tests/CI)")
    p.add_argument("--only", choices=BENCHMARKS, help="run a single benchmark")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results of an earlier run in --out")
    p.add_argument("--debug", action="store_true", help="show a bug's traceback")
    p.set_defaults(handler=run_studies)
    return p


def run_studies(args: argparse.Namespace) -> int:
    """Run the benchmarks and studies ``args`` ask for, printing each table; returns 0."""
    from instrument.writer.guards import check_outputs

    def show(name: str, result: dict, seconds: float) -> None:
        print(format_result(name, result))
        print(f"({name}: {seconds:.1f} s)", flush=True)

    # summary.json is written by every run: an --out holding one holds earlier results
    check_outputs([args.out / "summary.json"], None, args.overwrite, directory=args.out)
    _, text = run_benchmarks(args.out, quick=args.quick, only=args.only, on_result=show)
    print(text)
    print(f"results in {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the command inside the ``diffuserlab`` error boundary
    (:func:`instrument.cli.run_handler`: 2 and one line for bad input, an OS error or
    an ``--out`` holding earlier results); returns the exit status."""
    from instrument.cli import run_handler

    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    return run_handler(args)


if __name__ == "__main__":
    sys.exit(main())
