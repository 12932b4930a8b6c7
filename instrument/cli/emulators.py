"""``diffuserlab emulators start``: run the device emulators of the emulated bench.

The emulators (Thorlabs APT x3, Zaber chain, illuminate LED array; optionally a
LEDMX array) run on pseudo-terminals until Ctrl-C or SIGTERM, with links to their
ptys in ``--dir`` (default :data:`instrument.devices.emulated_bench.DEFAULT_DIR`, the one
``examples/bench-emulated.toml`` names). ``--bench-out`` writes the bench file for
that directory. The last line printed is ``ready`` once every emulator serves.
"""

from __future__ import annotations

import argparse
import math
import signal
import threading

from .common import error

__all__ = ["add_subcommands"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``emulators`` (with ``start``) to the subparsers."""
    ep = sub.add_parser("emulators", help="run protocol emulators of the bench hardware, so "
                        "the real drivers run without it (examples/bench-emulated.toml)")
    esub = ep.add_subparsers(dest="emulators_command", required=True)
    sp = esub.add_parser("start", help="start the emulators and serve until Ctrl-C")
    sp.add_argument("--dir", default=None,
                    help="directory of the port links (default: the one "
                    "examples/bench-emulated.toml names)")
    sp.add_argument("--bench-out", default=None,
                    help="write the emulated bench file for --dir here")
    sp.add_argument("--overwrite", action="store_true", help="replace an existing --bench-out")
    sp.add_argument("--time-scale", type=float, default=20.0,
                    help="emulated seconds per real second (default 20: moves 20x faster)")
    sp.add_argument("--ledmx", action="store_true",
                    help="also run an 8x8 LEDMX (DIY Arduino) LED array")
    sp.add_argument("--duration-s", type=float, default=None,
                    help="stop after this many seconds (default: run until Ctrl-C)")
    sp.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Start the emulators, print their ports, serve until interrupted."""
    from ..devices.emulated_bench import DEFAULT_DIR, EmulatedBench, EmulatorsRunningError
    from ..writer.guards import check_outputs

    if not (args.time_scale > 0 and math.isfinite(args.time_scale)):
        error(f"--time-scale must be a finite number > 0, got {args.time_scale}")
        return 2
    if args.duration_s is not None and not (args.duration_s > 0
                                            and math.isfinite(args.duration_s)):
        error(f"--duration-s must be a finite number of seconds > 0, got {args.duration_s} "
              "(leave it out to run until Ctrl-C)")
        return 2
    if args.bench_out:
        check_outputs([args.bench_out], None, args.overwrite, option="--bench-out")
    bench = EmulatedBench(DEFAULT_DIR if args.dir is None else args.dir,
                          time_scale=args.time_scale, ledmx=args.ledmx)
    try:
        bench.start()
    except EmulatorsRunningError as exc:
        error(str(exc))
        return 2
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        print(f"emulators running in {bench.directory} (time x{args.time_scale:g}; Ctrl-C "
              "stops them):")
        for name, (link, tty) in bench.ports().items():
            print(f"  {name:<11} {link} -> {tty}")
        if args.bench_out:
            from ..atomic import write_text

            write_text(args.bench_out, bench.bench_text())  # whole or not at all
            print(f"bench file: {args.bench_out}")
        else:
            print("bench file: examples/bench-emulated.toml" + (
                "" if bench.directory == DEFAULT_DIR else
                " names the default directory: use --bench-out for this one"))
        print("ready", flush=True)
        try:
            stop.wait(args.duration_s)
        except KeyboardInterrupt:
            pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        bench.stop()
    print("emulators stopped")
    return 0
