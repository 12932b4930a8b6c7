"""``diffuserlab bench serve [BENCH.toml] [--simulate]``: a bench process without a window.

Opens the bench (``--simulate``: every device swapped for its simulated twin; no file
and ``--simulate``: the built-in simulated bench) in a bench process
(:class:`instrument.bench.bench_process.BenchClient`), prints its address and connection
file (:mod:`instrument.bench.bench_connection`) and serves until Ctrl-C or SIGTERM, then
ends its jobs (a recording stopped, its run closed) and closes the devices. A
notebook attaches with ``BenchClient.connect()``. A real bench's prompts (homing,
an operator action) are asked here on the terminal. Exit 0 after Ctrl-C, 1 when the
bench process ended by itself, 2 on a bad bench file.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading

from ..devices.bench_file import bench_config, bench_label
from .common import add_bench_arguments

__all__ = ["add_serve", "run_serve"]


def add_serve(sub: argparse._SubParsersAction) -> None:
    """Add ``bench serve`` to the ``diffuserlab`` subparsers."""
    bp = sub.add_parser("bench", help="serve a bench to notebooks without a window")
    bsub = bp.add_subparsers(dest="bench_command", required=True)
    sp = bsub.add_parser(
        "serve", help="open the bench in a bench process and serve it until Ctrl-C",
        description="Open the bench in a bench process of its own, write its connection "
        "file and serve it to notebooks (BenchClient.connect()) until Ctrl-C.")
    add_bench_arguments(sp)
    sp.set_defaults(handler=run_serve)


def _ask(action: str, message: str, reply) -> None:
    """A real bench's prompt, asked on the terminal."""
    try:
        answer = input(f"{message} ({action}) - Enter when done, n to refuse: ")
    except EOFError:
        answer = "n"
    reply(answer.strip().lower() not in ("n", "no"))


def run_serve(args: argparse.Namespace) -> int:
    """Run ``bench serve``; returns the exit status (module docstring)."""
    from ..bench.bench_process import BenchClient

    bench_config(args.bench, simulate=args.simulate, command="bench serve")  # its problems
    path = None if args.bench is None else os.path.abspath(args.bench)
    client = BenchClient(name="bench serve", on_prompt=_ask,
                         on_message=lambda text: print(text, flush=True))
    ended = threading.Event()
    try:
        client.run_job("open_bench", {"bench_path": path, "simulate": args.simulate,
                                      "seed": args.seed, "scene": "none"})
        devices = ", ".join(d.name for d in client.devices())
        print(f"serving {bench_label(args.bench)}{' (simulated)' if args.simulate else ''}"
              f": {devices}", flush=True)
        print(f"address {client.address}\nconnection file {client.connection_file}",
              flush=True)
        print("attach from a notebook: from instrument.bench.bench_process import BenchClient; "
              "bench = BenchClient.connect()\nCtrl-C ends it (its jobs and devices "
              "closed)", flush=True)
        while not ended.wait(0.5):
            if not client.alive():
                from diffuserlab.processes import how_it_ended

                print(f"diffuserlab: the bench process ended: "
                      f"{how_it_ended(client.exit_status())}", file=sys.stderr)
                return 1
    except KeyboardInterrupt:
        print("closing the bench (its jobs ended, its runs closed)", flush=True)
        return 0
    finally:
        client.close()
    return 0
