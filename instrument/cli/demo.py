"""``diffuserlab demo``: a bench session on the built-in simulated bench, or
(``--real-sample``) a reconstruction of the real DiffuserCam tutorial sample."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_subcommands", "run"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``diffuserlab`` subparsers (``handler=run``)."""
    from recon.options import METHODS

    dp = sub.add_parser("demo", help="main job: a bench session on the built-in simulated bench")
    dp.add_argument("--out", default="out/demo", help="output directory")
    dp.add_argument("--method", choices=("auto", *METHODS), default="auto",
                    help="auto (default): the model the PSF grid calls for, ADMM and the "
                    "TV weight chosen from the data; a method: the on-axis PSF alone with "
                    "that method (the brightness divided out likewise)")
    dp.add_argument("--iterations", type=int, default=200)
    dp.add_argument("--seed", type=int, default=0, help="seed of the simulated bench")
    dp.add_argument("--real-sample", action="store_true",
                    help="instead, reconstruct the real DiffuserCam tutorial sample (bin 4)")
    dp.add_argument("--overwrite", action="store_true",
                    help="replace the files of an earlier demo in --out")
    dp.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo (:func:`instrument.acquisition.demo.run_demo`) or the real sample; returns 0."""
    from recon.errors import ReconInputError

    from ..writer.guards import check_outputs

    if args.seed < 0:
        raise ReconInputError(f"--seed {args.seed}: give a seed >= 0")
    if args.iterations < 1:
        raise ReconInputError(f"--iterations {args.iterations}: give a count >= 1")
    out = Path(args.out)
    if not args.real_sample:
        from ..acquisition.demo import OUTPUT_FILES, run_demo

        check_outputs([out / name for name in OUTPUT_FILES], None, args.overwrite,
                      directory=out)
        run_demo(args.out, seed=args.seed, method=args.method, iterations=args.iterations)
        return 0
    from recon.options import ReconOptions
    from recon.sample import data_dir

    from ..processing.reconstruct_files import run_recon
    from .recon import summary_line

    data = data_dir()
    check_outputs([out / "hand.png", out / "hand.tif", out / "metrics.json"], None,
                  args.overwrite, directory=out)
    options = ReconOptions.validated({"method": args.method, "iterations": args.iterations,
                                      "bin_factor": 4, "tv": None, "full_scale": 65520.0})
    m = run_recon(str(data / "psf_sample.tif"), str(data / "rawdata_hand_sample.tif"),
                  options, out=str(out / "hand.png"), metrics_json=str(out / "metrics.json"))
    print(summary_line(m))
    return 0
