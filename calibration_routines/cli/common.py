"""What ``calibrate`` and ``align`` share: bench arguments, opening the bench, prompts.

With ``--simulate`` and no bench file both use the built-in simulated bench
(:func:`instrument.devices.bench_file.bench_config`, as ``diffuserlab devices`` does).
"""

from __future__ import annotations

import argparse

from instrument.cli.common import add_bench_arguments

__all__ = ["add_bench_arguments", "ask", "make_bench"]


def ask(action: str, message: str) -> bool:
    """The operator prompt of a real bench (``on_prompt`` of
    :meth:`instrument.devices.bench.Bench.open`): shows ``message`` and waits.

    Returns
    -------
    bool
        True when the operator pressed Enter (done); False when they typed
        ``no``/``n``/``q`` or the input ended.
    """
    print(f"\n>>> {message}")
    try:
        answer = input("    press Enter when done, or type 'no' to stop: ")
    except EOFError:
        return False
    return answer.strip().lower() not in ("no", "n", "q")


def make_bench(args: argparse.Namespace, command: str):
    """The bench of a command line: a virtual bench (not yet opened) with
    ``--simulate``, else the real devices opened with :func:`ask` as the prompt.

    Parameters
    ----------
    args : argparse.Namespace
        With ``bench`` (path or None), ``simulate`` and ``seed``.
    command : str
        The command's name, for the message when the bench file is missing.

    Returns
    -------
    instrument.devices.virtual_bench.VirtualBench or instrument.devices.bench.Bench

    Raises
    ------
    instrument.devices.bench_file.MissingBenchFile
        No bench file and no ``--simulate``.
    instrument.config.BenchConfigError
        The bench file has problems.
    drivers.errors.DeviceError
        A real device failed to open.
    """
    from instrument.devices.bench import Bench
    from instrument.devices.bench_file import bench_config
    from instrument.devices.virtual_bench import VirtualBench

    config = bench_config(args.bench, simulate=args.simulate, command=command)
    if args.simulate:
        return VirtualBench(config, seed=args.seed)
    return Bench.open(config, on_prompt=ask)
