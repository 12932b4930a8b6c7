"""``diffuserlab gui [BENCH.toml] [--simulate]``: the operator GUI.

Registered with the ``diffuserlab`` command through the entry-point group
``diffuserlab.commands`` (``gui.cli:add_subcommands``), so the instrument layer never
imports this one. Qt is imported only when the command runs: without the ``gui`` extra
the command says which extra to install.
"""

from __future__ import annotations

import argparse

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
        from instrument.cli.common import bench_config

        bench_config(args.bench, simulate=args.simulate, command="gui")
    try:
        from .app import main
    except ImportError as exc:
        raise ImportError(f"the GUI needs the gui extra ({exc}); install it with "
                          "pip install 'diffuserlab[gui]'") from None
    status = main(args.bench, simulate=args.simulate, seed=args.seed, scene=args.scene,
                  connect=not args.no_connect)
    exit_now(status)
    return status


def exit_now(status: int) -> None:
    """End the process once the window has closed (settings saved, bench closed).

    PySide6 6.12 with pyqtgraph aborts in the interpreter's final garbage collection
    ("Fatal Python error: none_dealloc / bool_dealloc") after a window with hidden
    widgets was shown; nothing is left to do then, so the process ends without that
    collection (output flushed, logging shut down first).
    """
    import logging
    import os
    import sys

    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
