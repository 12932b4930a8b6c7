"""``diffuserlab runs list DIR``: one line per run under a folder.

Each run store found under ``DIR`` (a directory whose own ``zarr.json`` is a run's; runs
are not looked into for more) gets one line: its path, kind (the plan: ``video``,
``psf-sweep``, ...), status (``complete``, ``recording``, ``stopped``, ``interrupted``,
...), frames stored of frames planned, and its writer lock: ``unlocked``, ``locked by
pid N on HOST (running)``, or ``stale lock: pid N is gone`` (its writer was killed: see
``runs show``), with who closed a run whose writer was killed (``closed by ...``). A
directory named ``*.zarr`` that cannot be read as a run is listed with why. Exit 0; 2
when ``DIR`` is not a folder.
"""

from __future__ import annotations

import argparse
import os
import socket
from pathlib import Path

from diffuserlab.errors import InputError

__all__ = ["add_list", "run_line", "run_list"]


def add_list(rsub: argparse._SubParsersAction) -> None:
    """Add ``runs list`` to the ``runs`` subparsers."""
    lp = rsub.add_parser("list", help="one line per run under a folder: path, kind, status, "
                         "frames, lock (held or not, and by whom)")
    lp.add_argument("dir", help="folder to look for runs in (with its subfolders)")
    lp.set_defaults(handler=run_list)


def _runs_under(folder: Path):
    """The run stores under ``folder`` (not inside a run), sorted by path."""
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        here = Path(root)
        if "zarr.json" in files and here != folder or here.suffix == ".zarr":
            dirs[:] = []  # a run's own arrays are not runs
            yield here
        elif "zarr.json" in files:  # DIR itself a run
            dirs[:] = []
            yield here


def _lock_text(path: Path) -> str:
    from ..runs.run_integrity import pid_alive, read_lock

    record = read_lock(path)
    if record is None:
        return "unlocked"
    pid, host = record.get("pid"), record.get("host")
    if not isinstance(pid, int) or not host:
        return "lock unreadable"
    if host == socket.gethostname() and not pid_alive(pid):
        return f"stale lock: pid {pid} is gone"
    return f"locked by pid {pid} on {host} (running)"


def run_line(path: Path) -> str:
    """The line of run ``path`` (module docstring)."""
    from ..runs.runstore import RunStore, RunStoreError

    try:
        store = RunStore.open(path)
        kind = (store.attrs.get("plan") or {}).get("name", "?")
        done, total = int(store.done().sum()), store.n_frames
        status = store.status
    except (RunStoreError, OSError, KeyError, ValueError) as exc:
        return f"{path}  not a readable run: {exc}"
    line = f"{path}  {kind}  {status}  {done}/{total} frames  {_lock_text(path)}"
    closed = store.attrs.get("closed_by")
    if isinstance(closed, dict):
        line += f"  closed by {closed.get('by')}: {closed.get('why')}"
    return line


def run_list(args: argparse.Namespace) -> int:
    """Run ``runs list``; returns the exit status (module docstring).

    Raises
    ------
    diffuserlab.errors.InputError
        ``DIR`` is not a folder.
    """
    folder = Path(args.dir)
    if not folder.is_dir():
        raise InputError(f"runs list {args.dir}: no such folder; give the folder the runs "
                         "are in")
    found = 0
    for path in _runs_under(folder):
        print(run_line(path), flush=True)
        found += 1
    if not found:
        print(f"no runs under {folder}")
    return 0
