"""Helpers shared by the ``diffuserlab`` command modules (and the layer-4 commands).

:func:`bench_config` is the one place where a command that takes a bench file falls
back to the built-in simulated bench (:func:`instrument.config.default_bench`, what
``examples/bench-simulated.toml`` holds) when it is given ``--simulate`` and no file.
"""

from __future__ import annotations

import math
import sys

from diffuserlab.errors import InputError

__all__ = ["BUILT_IN_BENCH", "MissingBenchFile", "bench_config",
           "bench_label", "check_memory", "error", "floats"]

#: How messages name the built-in simulated bench.
BUILT_IN_BENCH = "built-in simulated bench"


class MissingBenchFile(InputError):
    """A command that needs a bench file got neither a file nor ``--simulate``."""


def bench_config(path: str | None, *, simulate: bool, command: str = "this command",
                 **load_options):
    """The bench configuration of a command's ``BENCH.toml`` argument.

    Parameters
    ----------
    path : str or None
        The bench file, or None when the command line gave none.
    simulate : bool
        ``--simulate``: the file's devices are swapped for their simulated twins; with
        no file, the built-in simulated bench is used.
    command : str
        The command's name, for the error message.
    **load_options
        Passed to :func:`instrument.bench_setup.load_bench` (``construct``,
        ``check_drivers``).

    Returns
    -------
    instrument.config.BenchConfig

    Raises
    ------
    MissingBenchFile
        No file and no ``--simulate``.
    instrument.config.BenchConfigError
        The file has problems (every one listed).
    """
    from ..config import default_bench

    if path is None:
        if not simulate:
            raise MissingBenchFile(f"{command} needs a bench file (BENCH.toml), or --simulate "
                                   f"for the {BUILT_IN_BENCH}")
        return default_bench()
    from ..bench_setup import load_bench

    return load_bench(path, simulate=simulate, **load_options)


def bench_label(path: str | None) -> str:
    """The bench file's path, or :data:`BUILT_IN_BENCH` without one."""
    return BUILT_IN_BENCH if path is None else str(path)


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
