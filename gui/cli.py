"""``diffuserlab gui [BENCH.toml] [--simulate]``: the operator GUI.

Registered with the ``diffuserlab`` command through the entry-point group
``diffuserlab.commands`` (``gui.cli:add_subcommands``), so the instrument layer never
imports this one. Qt is imported only when the command runs: without the ``gui`` extra
the command says which extra to install.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_subcommands", "exit_now", "run"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``gui`` to the ``diffuserlab`` subparsers."""
    p = sub.add_parser("gui", help="the operator GUI: devices, live view and reconstruction, "
                       "calibration, alignment, recording, results",
                       description="Open the operator GUI (PySide6 + pyqtgraph: pip install "
                       "'diffuserlab[gui]'). Without a bench file and without --simulate it "
                       "opens the bench file used last.")
    from calibration_routines.cli.common import add_bench_arguments

    add_bench_arguments(p)
    p.add_argument("--scene", choices=("beads-flow", "neurons", "none"), default="beads-flow",
                   help="--simulate: the moving scene in front of the camera")
    p.add_argument("--no-connect", action="store_true",
                   help="do not connect to the bench at start (press Connect)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Run the GUI until its window closes; returns its exit status.

    A bench file given on the command line is checked first, so a missing or broken
    file is the usual one-line error (every problem listed) before any window opens.
    """
    if args.bench is not None:
        from instrument.devices.bench_file import bench_config

        bench_config(args.bench, simulate=args.simulate, command="gui")
    try:
        from .app import main
    except ImportError as exc:
        raise ImportError(f"the GUI needs the gui extra ({exc}); install it with "
                          "pip install 'diffuserlab[gui]'") from None
    from .binding import BindingLeakError

    try:
        status = main(args.bench, simulate=args.simulate, seed=args.seed, scene=args.scene,
                      connect=not args.no_connect)
    except BindingLeakError as exc:  # before any window: one line, and no final collection
        print(f"diffuserlab: error: {exc}", file=sys.stderr)
        status = 2
    exit_now(status)
    return status


def exit_now(status: int) -> None:
    """End the process once the window has closed (settings saved, bench closed, runs
    finished), without the interpreter's final garbage collection.

    Nothing is left to do then, and tearing down Qt's and pyqtgraph's objects in the
    collector's order costs time and risks an abort in a destructor; output is flushed
    and logging shut down first. (The "Fatal Python error: none_dealloc" once seen
    here was not an exit problem: PySide6 6.12.0 leaks a reference to None on every
    Qt call, so the count ran out while the window was in use; the gui extra excludes
    that release and :func:`gui.binding.check_binding` refuses it at start.)
    """
    import logging
    import os

    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
