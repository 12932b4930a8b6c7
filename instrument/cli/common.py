"""Helpers shared by the ``diffuserlab`` command modules (and the layer-4 commands).

Which bench a command's ``BENCH.toml`` argument opens is :mod:`instrument.devices.bench_file`'s
(:func:`~instrument.devices.bench_file.bench_config`), which the GUI shares.
"""

from __future__ import annotations

import argparse
import math
import sys

from diffuserlab.errors import InputError

__all__ = ["check_memory", "error", "floats", "size_bytes"]

def error(line: str) -> None:
    """Print ``diffuserlab: error: LINE`` on stderr."""
    print(f"diffuserlab: error: {line}", file=sys.stderr)


def floats(text: str, option: str) -> list[float]:
    """Finite numbers of a comma-separated option value.

    Raises
    ------
    ValueError
        Not numbers, none, or a non-finite one (the message names ``option``).
    """
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise InputError(f"{option} {text!r} is not a comma-separated list of numbers") from exc
    if not values or not all(math.isfinite(v) for v in values):
        raise InputError(f"{option} {text!r} needs finite numbers")
    return values


def size_bytes(text: str, option: str = "--memory-limit") -> int:
    """A size option as bytes (``16GB``, ``500MB``, ``2GiB``, ``1.5e9``, a number of bytes):
    a number (with its digits: ``.GB``, ``GB`` and ``''`` are none, though dask reads
    them as 1 GB, 1 GB and 1 B) and an optional unit.

    Raises
    ------
    diffuserlab.errors.InputError
        No number, an unknown unit, or a size that is not > 0.
    """
    import re

    from dask.utils import parse_bytes

    t = str(text).strip()
    n = 0
    if re.fullmatch(r"(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\s*[A-Za-z]*", t):
        try:
            n = parse_bytes(t)
        except (ValueError, TypeError):
            n = 0
    if not n > 0:
        raise InputError(f"{option} {text!r}: give a positive size such as 16GB or 500MB")
    return int(n)


def check_memory(need_bytes: float, what: str) -> None:
    """Refuse, before any work, a job whose arrays alone exceed the machine's memory.

    Parameters
    ----------
    need_bytes : float
        An estimate of what the job allocates, bytes.
    what : str
        The options that ask for it (for the message).

    Raises
    ------
    recon.errors.ReconInputError
        ``need_bytes`` above the physical memory (both in GiB in the message).
    """
    import os

    from recon.errors import ReconInputError

    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not a POSIX system: not checked
        return
    if need_bytes > total:
        raise ReconInputError(f"{what} needs about {need_bytes / 2 ** 30:.3g} GiB of memory, "
                              f"this machine has {total / 2 ** 30:.3g} GiB; give smaller sizes")


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    """Add the optional ``bench`` positional, ``--simulate`` and ``--seed`` to ``p``."""
    p.add_argument("bench", nargs="?", default=None,
                   help="bench TOML file (e.g. examples/bench-simulated.toml); with "
                   "--simulate and no file: the built-in simulated bench")
    p.add_argument("--simulate", action="store_true",
                   help="run on the virtual bench built from the file (no hardware)")
    p.add_argument("--seed", type=int, default=0, help="seed of the virtual bench")
