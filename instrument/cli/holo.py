"""``diffuserlab holo {evaluate,benchmark}``: the holographic display's evaluations.

``holo evaluate`` reproduces Table 7.1 (:func:`recon.cgh.evaluate.run_evaluation`,
written by :func:`instrument.writer.evaluation.write_evaluation`: ``records.csv``,
``summary.json``, ``table.md``, ``psnr_vs_seconds.png`` under ``--out``; prints the
table); exit 1 with ``--strict`` when an acceptance rule
fails. ``holo benchmark`` times one full-size hologram against the FFT floor
(:func:`instrument.benchmarks.hologram.run_benchmark`) and prints the report. Both take
``--device cpu|cuda|auto`` (the optimiser on the CPU's NumPy path or a GPU's generic
path); an unusable device, or a hologram too large for the GPU's free memory, exits 2
before anything is read or written.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_subcommands", "run_benchmark", "run_evaluate"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``holo`` with ``evaluate`` and ``benchmark`` to the ``diffuserlab`` subparsers."""
    from recon.options import HOLOGRAM_METHODS as METHODS

    from .recon_flags import add_device_option

    hp = sub.add_parser("holo", help="holographic display: Table 7.1 evaluation, speed "
                        "benchmark")
    hsub = hp.add_subparsers(dest="action", required=True)
    ep = hsub.add_parser("evaluate", help="Table 7.1 reproduction (PSNR/SSIM per expansion "
                         "factor and method)",
                         description="The evaluation reproducing Table 7.1; writes "
                         "records.csv, summary.json, table.md and psnr_vs_seconds.png.")
    ep.add_argument("--size", type=int, default=None, help="target grid N (default 480)")
    ep.add_argument("--factors", default=None, help="expansion factors (default 4,16,36)")
    ep.add_argument("--seeds", default=None, help="mask seeds (default 0,1,2)")
    ep.add_argument("--iterations", type=int, default=None,
                    help="optimiser iterations (200)")
    ep.add_argument("--methods", default=",".join(METHODS),
                    help="comma-separated from one-step,l2,frequency,spatial,no-mask")
    ep.add_argument("--images", default=None,
                    help="folder of PNG/JPEG/TIFF/.npy images (default: the 10 bundled photos)")
    ep.add_argument("--out", default="holo_eval", help="output folder (default holo_eval)")
    ep.add_argument("--quick", action="store_true",
                    help="smoke run: N = 48, 3 images, factors 4,16, seed 0, 15 iterations")
    ep.add_argument("--strict", action="store_true", help="exit 1 when a rule fails")
    add_device_option(ep)
    ep.add_argument("--overwrite", action="store_true",
                    help="replace the files of an earlier evaluation in --out")
    ep.set_defaults(handler=run_evaluate)

    bp = hsub.add_parser("benchmark", help="full-size hologram speed against the FFT floor",
                         description="Full-size hologram speed benchmark: seconds per "
                         "iteration against one FFT at the grid, FFT share, peak memory.")
    bp.add_argument("--slm", type=int, nargs=2, default=None, metavar=("ROWS", "COLS"),
                    help="SLM pixels (default 540 960)")
    bp.add_argument("--factor", type=int, default=16, help="expansion factor k^2 (16)")
    bp.add_argument("--iterations", type=int, default=None, help="iterations (200)")
    bp.add_argument("--loss", default="frequency", choices=("frequency", "l2", "spatial"))
    bp.add_argument("--fft-repeats", type=int, default=None, help="FFT timings (9)")
    bp.add_argument("--json", default=None, help="also write the report to this JSON file")
    bp.add_argument("--quick", action="store_true", help="tiny smoke run (36 x 64 SLM, 10 it.)")
    bp.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    add_device_option(bp)
    bp.set_defaults(handler=run_benchmark)


def _settings(args: argparse.Namespace, options: dict[str, str], *, full: tuple,
              quick: tuple) -> dict:
    """The values of ``options`` ({flag: attribute}): the given ones, else the full run's
    (``full``) or, with ``--quick``, the smoke run's (``quick``). ``--quick`` sets them
    all, so giving one of them with it is refused, never ignored.

    Raises
    ------
    recon.errors.ReconInputError
        ``--quick`` with one of ``options``.
    """
    from recon.errors import ReconInputError

    given = [flag for flag, attr in options.items() if getattr(args, attr) is not None]
    if args.quick and given:
        sets = ", ".join(f"{flag} {' '.join(map(str, v)) if isinstance(v, tuple) else v}"
                         for flag, v in zip(options, quick, strict=True))
        raise ReconInputError(f"--quick sets {sets}: drop {', '.join(given)} or drop --quick")
    defaults = quick if args.quick else full
    return {attr: (getattr(args, attr) if getattr(args, attr) is not None else d)
            for (flag, attr), d in zip(options.items(), defaults, strict=True)}


def _device(args: argparse.Namespace, slm_shape, k: int):
    """The backend of ``--device``, refused (exit 2 through :func:`instrument.cli.main`)
    when unusable or when the largest hologram asked for does not fit in the GPU's free
    memory; checked before anything is read or written."""
    from recon.backend import resolve_device
    from recon.cgh.xp_optimize import check_device_memory

    from .recon_flags import check_device

    check_device(args.device)
    backend = resolve_device(args.device)
    if not backend.is_numpy:
        check_device_memory(backend, slm_shape, k)
    return backend


def _ints(text: str, what: str) -> tuple[int, ...]:
    from recon.errors import ReconInputError

    try:
        vals = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ReconInputError(f"{what} must be comma-separated integers, got {text!r}") from None
    if not vals:
        raise ReconInputError(f"{what} is empty")
    return vals


def _check_evaluation(factors: tuple[int, ...], seeds: tuple[int, ...],
                      methods: tuple[str, ...]) -> None:
    """Refuse factors, seeds and methods the evaluation cannot use, before it writes
    anything (its output folder is made first)."""
    from recon.cgh.evaluation import METHODS, factor_to_k
    from recon.errors import ReconInputError

    for factor in factors:
        factor_to_k(factor)
    if any(seed < 0 for seed in seeds):
        raise ReconInputError(f"--seeds {','.join(map(str, seeds))}: a mask seed must be >= 0")
    bad = [m for m in methods if m not in (*METHODS, "no-mask")]
    if bad or not methods:
        raise ReconInputError(f"--methods: unknown {bad or 'none given'}; choose from "
                              f"{', '.join((*METHODS, 'no-mask'))}")


def run_evaluate(args: argparse.Namespace) -> int:
    """Run ``holo evaluate``; 0, or 1 when a rule failed with ``--strict`` (bad input
    exits 2 through :func:`instrument.cli.main`)."""
    from pathlib import Path

    from recon.cgh.evaluate import run_evaluation
    from recon.cgh.evaluation import factor_to_k
    from recon.cgh.protocol import BUNDLED_IMAGES, load_bundled, load_folder
    from recon.errors import ReconInputError

    from ..writer.evaluation import EVALUATION_FILES, write_evaluation
    from ..writer.guards import check_outputs
    from .common import check_memory

    settings = _settings(args, {"--size": "size", "--factors": "factors", "--seeds": "seeds",
                                "--iterations": "iterations"},
                         full=(480, "4,16,36", "0,1,2", 200), quick=(48, "4,16", "0", 15))
    size, iters = settings["size"], settings["iterations"]
    factors, seeds = _ints(settings["factors"], "--factors"), _ints(settings["seeds"], "--seeds")
    out = Path(args.out)
    check_outputs([out / n for n in EVALUATION_FILES], {"--images": args.images},
                  args.overwrite, directory=out)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    _check_evaluation(factors, seeds, methods)
    if size < 1 or iters < 1:
        raise ReconInputError("--size and --iterations must be positive")
    k_max = max(factor_to_k(f) for f in factors)
    _device(args, (max(size // k_max, 1),) * 2, k_max)
    # the optimiser holds a few complex fields on the expanded SLM grid (k N)^2
    check_memory(8 * 8 * max(factors) * size ** 2, f"--size {size} at factor {max(factors)}")
    if args.images:
        images = load_folder(args.images)
    else:
        images = [(name, load_bundled(name)) for name, _ in BUNDLED_IMAGES]
    if args.quick:
        images = images[:3]

    def progress(done, total, rec):
        print(f"[{done}/{total}] {rec['factor']}x seed {rec['seed']} {rec['image']:>18} "
              f"{rec['method']:>9}: {rec['psnr_full']:6.2f} dB {rec['ssim_full']:.3f} "
              f"({rec['seconds']:.2f} s)", file=sys.stderr, flush=True)

    ev = run_evaluation(images, size=size, factors=factors, seeds=seeds,
                        steps=iters, methods=methods,
                        source=args.images or "skimage bundled (A10)", progress=progress,
                        device=args.device)
    write_evaluation(ev, out)
    print(ev["table"])
    print(f"wrote {args.out}/records.csv, summary.json, table.md, psnr_vs_seconds.png "
          f"({ev['settings']['wall_seconds']:.0f} s)")
    return 1 if args.strict and any(r["passed"] is False for r in ev["rules"]) else 0


def run_benchmark(args: argparse.Namespace) -> int:
    """Run ``holo benchmark`` and print the report; returns 0 (bad input exits 2
    through :func:`instrument.cli.main`)."""
    from instrument.benchmarks.hologram import format_report
    from instrument.benchmarks.hologram import run_benchmark as time_hologram
    from recon.errors import ReconInputError

    from .common import check_memory

    settings = _settings(args, {"--slm": "slm", "--iterations": "iterations",
                                "--fft-repeats": "fft_repeats"},
                         full=((540, 960), 200, 9), quick=((36, 64), 10, 3))
    slm, iters, reps = tuple(settings["slm"]), settings["iterations"], settings["fft_repeats"]
    k = int(round(args.factor ** 0.5))
    if k * k != args.factor or min(slm) < 1 or iters < 1 or reps < 1:
        raise ReconInputError("--factor must be a perfect square; --slm, --iterations and "
                              "--fft-repeats must be positive")
    backend = _device(args, slm, k)
    check_memory(8 * 8 * args.factor * slm[0] * slm[1],
                 f"--slm {slm[0]} {slm[1]} at --factor {args.factor}")
    if args.json:
        from ..writer.guards import check_outputs

        check_outputs([args.json], None, args.overwrite, option="--json")
    rep = time_hologram(slm, k, iters, args.loss, reps, backend)
    print(format_report(rep, args.factor, reps, iters))
    if args.json:
        from ..atomic import write_json

        write_json(args.json, rep)
    return 0
