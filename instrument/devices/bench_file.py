"""Which bench a command opens: the bench file it was given, or with ``--simulate`` and
no file the built-in simulated bench (:func:`instrument.config.default_bench`, what
``examples/bench-simulated.toml`` holds).

:func:`bench_config` is the one place where that fallback is decided, for the
``diffuserlab`` commands, the layer-4 commands and the GUI's command alike. Standard
library and layer 0 only at import (the command line's start imports this module); the
configuration and the loader are imported when called.
"""

from __future__ import annotations

from diffuserlab.errors import InputError

__all__ = ["BUILT_IN_BENCH", "MissingBenchFile", "bench_config", "bench_label"]

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
        Passed to :func:`instrument.devices.bench_setup.load_bench` (``construct``,
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
    from .bench_setup import load_bench

    return load_bench(path, simulate=simulate, **load_options)


def bench_label(path: str | None) -> str:
    """The bench file's path, or :data:`BUILT_IN_BENCH` without one."""
    return BUILT_IN_BENCH if path is None else str(path)
