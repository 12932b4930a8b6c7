"""Benchmark results as documentation pages (:func:`markdown_page`).

The documentation's benchmark pages are generated from the files a benchmark run
wrote (``diffuserlab benchmark recon --out DIR``), never typed by hand: each
result JSON is rendered by the same table function the command prints
(:func:`instrument.benchmarks.run.format_result`), with the run's machine record and its
charts.
"""

from __future__ import annotations

import json
from pathlib import Path

from recon.errors import ReconInputError

from .run import BENCHMARKS, format_result

__all__ = ["markdown_page"]

_TITLES = {"speed": "Speed (seconds per iteration over the FFT floor)",
           "accuracy": "Accuracy against ground truth",
           "stability": "Stability: where methods fail as light drops",
           "erasure": "Pixel erasure", "volume_speed": "3D speed",
           "volume_accuracy": "3D accuracy", "spatial_speed": "Spatially varying models: speed",
           "spatial_accuracy": "Spatially varying models: accuracy",
           "spatial_far": "A far scene through the spatially varying camera",
           "blind_calibration": "Compressive (blind) calibration",
           "auto": "Automatic weight against the oracle",
           "failure_maps": "Failure maps", "failure_map_3d": "3D failure map"}


def _machine_lines(machine: dict | None) -> list[str]:
    if not machine:
        return ["The run recorded no machine description."]
    load = machine.get("load_average_start")
    lines = [f"Measured {machine.get('date_utc', '?')} on {machine.get('platform', '?')}, "
             f"{machine.get('cpu_count', '?')} CPUs, Python {machine.get('python', '?')}, "
             f"NumPy {machine.get('numpy', '?')}"]
    if load is not None:
        lines.append(f"(load average at the start {load[0]:.1f}; the machine may have "
                     "been shared, so speed is stated as a ratio to a floor measured in "
                     "the same run).")
    return [" ".join(lines)]


def markdown_page(results_dir: str | Path, title: str, *, figures_prefix: str = "") -> str:
    """A Markdown page of every benchmark result in one run's output directory.

    Parameters
    ----------
    results_dir : str or Path
        What ``diffuserlab benchmark recon --out DIR`` wrote: ``summary.json`` and
        one ``NAME.json`` per benchmark of :data:`instrument.benchmarks.run.BENCHMARKS`,
        and its PNG charts.
    title : str
        The page's first heading.
    figures_prefix : str
        Path from the page to ``results_dir`` for the charts' links.

    Returns
    -------
    str
        Markdown: the machine record, then per benchmark (in the order they run) its
        table as the command printed it and the charts it wrote.

    Raises
    ------
    ReconInputError
        ``results_dir`` has no ``summary.json`` or no benchmark result.

    Examples
    --------
    >>> import tempfile, json, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / "summary.json").write_text(json.dumps({"quick": True}))
    >>> markdown_page(d, "Benchmarks")
    Traceback (most recent call last):
    ...
    recon.errors.ReconInputError: no benchmark result (NAME.json) in ...
    """
    results_dir = Path(results_dir)
    summary_path = results_dir / "summary.json"
    if not summary_path.is_file():
        raise ReconInputError(f"{results_dir} holds no summary.json: pass the --out "
                              "directory of a `diffuserlab benchmark recon` run")
    summary = json.loads(summary_path.read_text())
    names = [n for n in BENCHMARKS if (results_dir / f"{n}.json").is_file()]
    if not names:
        raise ReconInputError(f"no benchmark result (NAME.json) in {results_dir}: run "
                              "`diffuserlab benchmark recon --out` into it first")
    kind = "quick run (small problems)" if summary.get("quick") else "full run"
    lines = [f"# {title}", "", f"One {kind} of `diffuserlab benchmark recon`. "
             + " ".join(_machine_lines(summary.get("machine"))), ""]
    pngs = sorted(p.name for p in results_dir.glob("*.png"))
    shown: set[str] = set()
    for name in names:
        result = json.loads((results_dir / f"{name}.json").read_text())
        seconds = summary.get("seconds", {}).get(name)
        lines += [f"## {_TITLES.get(name, name)}", ""]
        if seconds is not None:
            lines += [f"`--only {name}` ran {seconds:.0f} s.", ""]
        lines += ["```text", format_result(name, result).rstrip(), "```", ""]
        for png in pngs:
            if png.startswith(name.split("_")[0]) and png not in shown:
                shown.add(png)
                lines += [f"![{png}]({figures_prefix}{png})", ""]
    for png in pngs:
        if png not in shown:
            lines += [f"![{png}]({figures_prefix}{png})", ""]
    return "\n".join(lines)
