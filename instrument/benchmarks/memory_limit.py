"""``diffuserlab benchmark memory-limit``: ``recon3d --memory-limit`` against its measured peak.

A limit is the most the ``recon3d`` process's resident set may reach
(:func:`recon.volume.memory_plan.memory_plan`). For each problem size (by default 8
planes of 256 x 256 and 16 of 512 x 512: the synthetic caustic stack and bead
measurement of :func:`instrument.benchmarks.volume.synthetic_problem`, written as ``.npy``
files to a temporary directory) and each weight (the automatic one and a fixed
``--tv``), ``recon3d`` runs in fresh processes:

1. with a limit below every plan (1 MB): refused with exit status 2, the line naming
   the smallest limit that would do;
2. 10 MB under that limit (below the smallest estimate): refused again;
3. at that limit, and at every other plan's estimate rounded up to 10 MB (the
   estimates from the first solve's metrics JSON): solved by the first plan within
   the limit, whose peak resident set -- the ``recon3d`` process's ``VmHWM``, read
   as it exits, interpreter, imports and writing the outputs included -- must be
   within the limit.

The check is ``all_within``: every solve's measured peak within its limit, every
refusal exit status 2.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["memory_limit_table", "run_memory_limit"]

#: The limit that is below every plan of any problem.
BELOW_EVERY_PLAN = "1MB"

#: The smallest limit a refusal names.
NAMED_LIMIT = re.compile(r"give --memory-limit ([0-9.]+)GB or more")


def run_memory_limit(*, sizes=((256, 8), (512, 16)), weights=("auto", "1e-4"),
                     iterations: int = 10, work_dir: str | None = None,
                     announce=print) -> dict:
    """Run ``recon3d`` under limits below, at and above each plan's estimate; measure.

    Parameters
    ----------
    sizes : sequence of (side, planes)
        Square sensor side (pixels) and depth planes of each problem.
    weights : sequence of str
        ``--tv`` values (``"auto"``: the automatic weight, whose plans hold more).
    iterations : int
        ``--iterations`` of every solve.
    work_dir : str, optional
        Where the temporary problem files and outputs go (default the system's).
    announce : callable
        ``announce(line)`` after each run.

    Returns
    -------
    dict
        JSON-ready: ``machine``, ``iterations``, ``runs`` (per run: ``sensor``,
        ``planes``, ``tv``, ``limit`` (as given), ``limit_bytes``, ``exit_status``,
        ``refused`` (bool), ``named_limit`` (a refusal's smallest limit), ``plan`` and
        ``estimate_bytes`` (a solve's, from its metrics JSON), ``expected_plan``,
        ``peak_bytes`` (the process's VmHWM), ``within`` (a solve: peak <= limit; a
        refusal: exit status 2), ``seconds``) and ``all_within``.
    """
    from instrument.benchmarks import machine_record

    runs: list[dict] = []
    with tempfile.TemporaryDirectory(dir=work_dir, prefix="memory-limit-") as tmp:
        for side, planes in sizes:
            inputs = _write_problem(Path(tmp), side, planes)
            for tv in weights:
                runs.extend(_limit_runs(Path(tmp), inputs, tv, iterations, announce))
    return {"machine": machine_record(), "iterations": iterations, "runs": runs,
            "all_within": bool(runs) and all(r["within"] for r in runs)}


def _limit_runs(tmp: Path, inputs: dict, tv: str, iterations: int, announce) -> list[dict]:
    """The runs of one problem and weight: below every plan, just below the smallest
    limit named, at it, and at every other plan's estimate."""
    rows: list[dict] = []

    def run(limit: str, expected: str | None = None) -> dict:
        row = _recon3d(tmp, inputs, tv, limit, iterations)
        row.update(sensor=inputs["side"], planes=inputs["planes"], tv=tv,
                   expected_plan=expected)
        rows.append(row)
        announce(_row_line(row))
        return row

    named = run(BELOW_EVERY_PLAN)["named_limit"]
    if named is not None:
        run(f"{float(named[:-2]) - 0.01:.2f}GB")
        first = run(named)
        tried = {named}
        for p in first.pop("plans", []):
            limit = f"{math.ceil(p['estimate_bytes'] / 1e7) / 100:.2f}GB"
            if limit not in tried:  # plans within 10 MB of each other: one run
                tried.add(limit)
                run(limit, p["plan"]).pop("plans", None)
    return rows


def _write_problem(tmp: Path, side: int, planes: int) -> dict:
    """The synthetic stack (float32, normalised) and raw (scaled to 1000) as ``.npy``."""
    from instrument.benchmarks.volume import synthetic_problem
    from instrument.writer.files import save_image

    op, b = synthetic_problem(side, side, planes)
    stack, raw = tmp / f"stack_{side}_{planes}.npy", tmp / f"raw_{side}_{planes}.npy"
    save_image(stack, op.psf_stack)
    save_image(raw, (1000.0 * b).astype(np.float32))
    depths = ",".join(f"{20.0 + k:g}" for k in range(planes))
    return {"stack": str(stack), "raw": str(raw), "depths": depths, "side": side,
            "planes": planes, "tag": f"{side}_{planes}"}


def _recon3d(tmp: Path, inputs: dict, tv: str, limit: str, iterations: int) -> dict:
    """One ``recon3d`` in a fresh process under ``--memory-limit limit``: its exit status,
    its peak resident set and what it chose or named."""
    from dask.utils import parse_bytes

    peak_file, metrics = tmp / "peak.txt", tmp / f"m_{inputs['tag']}.json"
    for f in (peak_file, metrics):
        f.unlink(missing_ok=True)
    argv = ["recon3d", "--psf-stack", inputs["stack"], "--raw", inputs["raw"], "--depths",
            inputs["depths"], "--dark", "none", "--tv", tv, "--iterations", str(iterations),
            "--memory-limit", limit, "--out", str(tmp / f"v_{inputs['tag']}.tif"),
            "--metrics-json", str(metrics), "--overwrite"]
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD_CODE, str(peak_file), *argv],
                          capture_output=True, text=True, check=False)
    row = {"limit": limit, "limit_bytes": int(parse_bytes(limit)),
           "exit_status": done.returncode, "seconds": time.perf_counter() - t0,
           "peak_bytes": int(peak_file.read_text()) if peak_file.exists() else None}
    row["refused"] = done.returncode == 2
    found = NAMED_LIMIT.search(done.stderr)
    row["named_limit"] = f"{found.group(1)}GB" if found else None
    if row["refused"]:
        row["message"] = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else ""
        row["within"] = found is not None
        return row
    if done.returncode != 0 or not metrics.exists():
        row.update(within=False, message=(done.stderr.strip().splitlines() or [""])[-1])
        return row
    plan = json.loads(metrics.read_text())["memory_plan"]
    row.update(plan=plan["plan"], estimate_bytes=plan["estimate_bytes"], plans=plan["plans"],
               within=row["peak_bytes"] is not None and row["peak_bytes"] <= row["limit_bytes"])
    return row


#: What the ``recon3d`` process runs: ``diffuserlab`` with ``sys.argv[2:]``, then its
#: peak resident set written to ``sys.argv[1]`` (bytes,
#: :func:`instrument.benchmarks.volume.peak_rss_bytes`: ``VmHWM``, which starts afresh with
#: the process, unlike a child's ``ru_maxrss``, which carries its parent's).
CHILD_CODE = """
import sys
from pathlib import Path
from instrument.cli import main
from instrument.benchmarks.volume import peak_rss_bytes
status = 1
try:
    status = main(sys.argv[2:])
finally:
    Path(sys.argv[1]).write_text(str(peak_rss_bytes()[0]))
sys.exit(status)
"""


def _row_line(r: dict) -> str:
    """One run as a line of text."""
    head = (f"{r['planes']} planes of {r['sensor']}x{r['sensor']}, --tv {r['tv']}, "
            f"--memory-limit {r['limit']}: ")
    peak = "" if r["peak_bytes"] is None else f"peak {r['peak_bytes'] / 1e9:.3f} GB"
    if r["refused"]:
        return (head + f"refused (exit 2), names {r['named_limit']}; {peak} (no solve)"
                + ("" if r["within"] else " -- NO LIMIT NAMED"))
    if "plan" not in r:
        return head + f"FAILED (exit {r['exit_status']}): {r.get('message', '')}"
    expected = ("" if r["expected_plan"] in (None, r["plan"])
                else f" (the {r['expected_plan']} plan asked for)")
    return (head + f"{r['plan']}{expected}, estimate {r['estimate_bytes'] / 1e9:.3f} GB, "
            f"{peak} {'within' if r['within'] else 'OVER'} the limit "
            f"({r['seconds']:.0f} s)")


def memory_limit_table(result: dict) -> str:
    """The runs of :func:`run_memory_limit` as lines of text, and the verdict."""
    lines = [_row_line(r) for r in result["runs"]]
    solved = [r for r in result["runs"] if "plan" in r]
    lines.append(f"{'all within' if result['all_within'] else 'NOT ALL WITHIN'}: "
                 f"{sum(r['within'] for r in solved)} of {len(solved)} solves peaked "
                 "within their limit; "
                 f"{sum(r['refused'] for r in result['runs'])} limits below every plan "
                 "refused with exit status 2")
    return "\n".join(lines)
