"""Run this machine's reconstruction speed benchmarks (:func:`run_benchmarks`).

``diffuserlab benchmark recon [--out DIR] [--quick] [--only NAME]`` calls it and
prints each benchmark's table (:func:`format_result`) and the summary. It writes
``speed.json`` (2D solvers against the FFT floor, :mod:`instrument.benchmarks.speed`),
``volume_speed.json`` (3D solvers against the 3D FFT floor and their memory,
:mod:`instrument.benchmarks.volume`) and ``summary.json`` under ``out``, and returns a
compact summary: can this computer reconstruct at the rates the docs state.

The accuracy and method studies that chose the defaults (accuracy, stability,
erasure, the automatic weights, failure maps, spatially varying models, blind
calibration, mask designs) are not part of the installed package: they run from a
checkout with ``python -m benchmarks`` (the repository's ``benchmarks/``), which
calls these two first.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable
from pathlib import Path

from recon.errors import ReconInputError
from recon.options import BENCHMARKS  # the benchmarks, in the order they run

from . import METHODS, machine_record, write_json

__all__ = ["BENCHMARKS", "TABLES", "format_result", "run_benchmarks", "run_each", "run_one",
           "summarise"]

log = logging.getLogger(__name__)

#: (module, function) of each benchmark's text table.
TABLES = {"speed": ("instrument.benchmarks.speed", "speed_table"),
          "volume_speed": ("instrument.benchmarks.volume", "volume_speed_table")}


def format_result(name: str, result: dict) -> str:
    """The text table of one benchmark's result (e.g. :func:`.speed.speed_table`).

    Parameters
    ----------
    name : str
        One of :data:`BENCHMARKS`.
    result : dict
        What its ``run_*`` function returned.

    Returns
    -------
    str
    """
    module, function = TABLES[name]
    return getattr(importlib.import_module(module), function)(result)


def summarise(results: dict) -> tuple[dict, str]:
    """Compact figures and their text from the speed results present in ``results``
    (other keys are left to the caller)."""
    summary: dict = {}
    lines = ["== summary =="]
    if "speed" in results:
        sp = {}
        for bf, r in results["speed"]["bins"].items():
            sp[bf] = {m: d["ratio"] for m, d in r["methods"].items()}
            lines.append(f"speed bin {bf} (x FFT floor {r['fft_floor_seconds'] * 1e3:.2f} ms): "
                         + ", ".join(f"{m} {d['ratio']:.2f}"
                                     + ("" if d["goal"] is None else
                                        (" ok" if d["meets_goal"] else " MISSED"))
                                     for m, d in r["methods"].items()))
        summary["speed_ratio"] = sp
    if "volume_speed" in results:
        v = results["volume_speed"]
        summary["volume_speed_ratio"] = {"x".join(map(str, r["shape"])): {
            m: d["ratio"] for m, d in r["methods"].items()} for r in v["sizes"]}
        summary["volume_memory_max_rss_bytes"] = {
            f"{m['method']} {'x'.join(map(str, m['shape']))}": m["max_rss_bytes"]
            for m in v["memory"]}
        for r in v["sizes"]:
            lines.append(f"3D speed {'x'.join(map(str, r['shape']))} (x FFT floor "
                         f"{r['fft_floor_seconds'] * 1e3:.1f} ms, goal {v['goal']}): " + ", ".join(
                             f"{m} {d['ratio']:.2f}" + (" ok" if d["meets_goal"] else " MISSED")
                             for m, d in r["methods"].items()))
        lines.append("3D memory alone (max RSS, budget 4 GB): " + ", ".join(
            f"{m['method']} {'x'.join(map(str, m['shape']))} {m['max_rss_bytes'] / 2**30:.2f} GiB"
            for m in v["memory"]))
    return summary, "\n".join(lines)


def run_each(names: list[str], run: Callable[[str], dict],
             on_result: Callable[[str, dict, float], None] | None = None
             ) -> tuple[dict, dict]:
    """``run(name)`` for each of ``names`` in turn, logged (``-- NAME --`` at INFO,
    seconds at DEBUG) and timed; ``on_result(name, result, seconds)`` after each.

    Returns
    -------
    results, seconds : dict, dict
        By name.
    """
    results: dict = {}
    timings: dict = {}
    for name in names:
        t0 = time.perf_counter()
        log.info("-- %s --", name)
        results[name] = run(name)
        timings[name] = time.perf_counter() - t0
        log.debug("(%s: %.1f s)", name, timings[name])
        if on_result is not None:
            on_result(name, results[name], timings[name])
    return results, timings


def run_one(name: str, quick: bool, out: Path) -> dict:
    """Run one benchmark of :data:`BENCHMARKS` (writing its files under ``out``)."""
    if name == "speed":
        from .speed import run_speed

        return run_speed(quick, out)
    from .volume import run_volume_speed

    return run_volume_speed(quick, out)


def run_benchmarks(out: Path, *, quick: bool = False, only: str | None = None,
                   on_result: Callable[[str, dict, float], None] | None = None
                   ) -> tuple[dict, str]:
    """Run the selected speed benchmarks and write their files and ``summary.json``.

    Progress is logged (``-- NAME --`` at INFO, seconds at DEBUG).

    Parameters
    ----------
    out : Path
        Output directory (created).
    quick : bool
        Fewer sizes and repeats (tests/CI).
    only : str, optional
        One name of :data:`BENCHMARKS`; default both.
    on_result : callable, optional
        Called as ``on_result(name, result, seconds)`` after each benchmark (the CLI
        prints ``format_result(name, result)``).

    Returns
    -------
    summary : dict
        What ``summary.json`` holds: :func:`summarise`'s figures plus ``quick``,
        ``seconds`` per benchmark, ``methods`` and ``machine``.
    text : str
        The summary lines.

    Raises
    ------
    ReconInputError
        ``only`` is not a benchmark, or a benchmark refused its input (e.g. the
        DiffuserCam sample is missing).
    """
    if only is not None and only not in BENCHMARKS:
        raise ReconInputError(f"unknown benchmark {only!r}; choose one of "
                              f"{', '.join(BENCHMARKS)} (the accuracy and method studies "
                              "run from a checkout: python -m benchmarks --only NAME)")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    machine = machine_record()
    results, timings = run_each([only] if only else list(BENCHMARKS),
                                lambda name: run_one(name, quick, out), on_result)
    summary, text = summarise(results)
    summary.update(quick=quick, seconds=timings, methods=list(METHODS), machine=machine)
    write_json(out / "summary.json", summary)
    return summary, text
