"""Compare the JSON results of two runs of the same benchmarks (docs/architecture.md,
"Benchmarks before and after the move").

    python scripts/compare_benchmarks.py BEFORE AFTER [--rtol R] [--atol A] [--show N]

BEFORE and AFTER are two JSON files or two folders; in folders every ``*.json`` below
them is matched by its relative path. Every scalar of the two files is compared, by its
path (dict keys, list indices). A value whose path names a quantity that depends on
timing, load or memory (:data:`TIMING`: seconds, fps, latency, ratios, CPU, resident
sets and the estimates that add them, the machine record, a live stream's counters) is
*timing*: it is expected to differ and is only counted. So is a ``meets_goal`` verdict
beside a ``ratio`` (a speed goal). Every other value (PSNR, SSIM, residuals, counts,
weights, verdicts, strings) must be equal: numbers to ``--rtol``/``--atol``, NaN equal
to NaN. Prints one line per file and each difference. Exit status 0 when the
non-timing values all agree, 1 when one differs or is missing on one side, 2 for a
path that is not there.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

#: A path component matching this names a timing-, load- or memory-dependent value.
TIMING = re.compile(
    r"(^|_)(seconds?|s|ms|wall|fps|hz|latency|time|times|timestamp|elapsed|startup|cpu|"
    r"rss|mb|ratios?|fft_floor\w*|floor_units|fft_share|fraction_of_local|samples|"
    r"peak\w*bytes|estimate_bytes|memory_estimate_bytes|peak_over_estimate|"
    r"budget_seconds|budget_overrun\w*|budgets|within_budget\w*|stats|ring|"
    r"date_utc|load_average\w*|machine|platform|python|numpy)($|_)",
    re.IGNORECASE)

__all__ = ["TIMING", "FileReport", "compare_files", "compare_values", "is_timing",
           "leaves", "main"]


def leaves(obj, path: tuple[str, ...] = ()):
    """Yield ``(path, value)`` for every scalar of a JSON value; a list index is
    ``[i]`` in the path."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from leaves(v, path + (str(k),))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from leaves(v, path + (f"[{i}]",))
    else:
        yield path, obj


def is_timing(path: tuple[str, ...], values: dict) -> bool:
    """Whether the value at ``path`` of a file whose leaves are ``values`` depends on
    timing, load or memory (:data:`TIMING`, or a ``meets_goal`` beside a ``ratio``)."""
    if any(TIMING.search(p) for p in path if not p.startswith("[")):
        return True
    return path[-1] == "meets_goal" and path[:-1] + ("ratio",) in values


def _equal(a, b, rtol: float, atol: float) -> bool:
    numbers = (int, float)
    if isinstance(a, bool) or isinstance(b, bool) or not (
            isinstance(a, numbers) and isinstance(b, numbers)):
        return a == b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=rtol, abs_tol=atol)


@dataclass
class FileReport:
    """The comparison of one file: counts, and ``(path, before, after)`` per difference."""

    values: int = 0
    equal: int = 0
    timing: int = 0
    differ: list = field(default_factory=list)
    timing_differ: list = field(default_factory=list)
    missing: list = field(default_factory=list)

    @property
    def same(self) -> bool:
        """No non-timing value differs and none is missing on one side."""
        return not (self.differ or self.missing)


def compare_values(before, after, rtol: float = 1e-9, atol: float = 1e-12) -> FileReport:
    """Compare two parsed JSON values leaf by leaf (see the module's docstring)."""
    a, b = dict(leaves(before)), dict(leaves(after))
    report = FileReport()
    for p in sorted(set(a) | set(b)):
        if p not in a or p not in b:
            report.missing.append((p, a.get(p, "<absent>"), b.get(p, "<absent>")))
            continue
        report.values += 1
        equal = _equal(a[p], b[p], rtol, atol)
        if is_timing(p, a):
            report.timing += 1
            if not equal:
                report.timing_differ.append((p, a[p], b[p]))
        elif equal:
            report.equal += 1
        else:
            report.differ.append((p, a[p], b[p]))
    return report


def _json_files(root: Path) -> dict[str, Path]:
    if root.is_file():
        return {root.name: root}
    return {p.relative_to(root).as_posix(): p for p in sorted(root.rglob("*.json"))}


def compare_files(before: Path, after: Path, rtol: float = 1e-9, atol: float = 1e-12
                  ) -> dict[str, FileReport | str]:
    """Compare two JSON files, or every JSON file of two folders by relative path.

    Returns
    -------
    dict
        Relative path -> :class:`FileReport`, or ``"only before"`` / ``"only after"``
        for a file on one side only (two files: one entry, under the first's name).

    Raises
    ------
    FileNotFoundError
        ``before`` or ``after`` is not there.
    """
    for p in (before, after):
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file or folder")
    fa, fb = _json_files(before), _json_files(after)
    if before.is_file() and after.is_file():
        fb = {before.name: after}
    out: dict[str, FileReport | str] = {}
    for name in sorted(set(fa) | set(fb)):
        if name not in fa or name not in fb:
            out[name] = "only before" if name in fa else "only after"
            continue
        out[name] = compare_values(json.loads(fa[name].read_text()),
                                   json.loads(fb[name].read_text()), rtol, atol)
    return out


def main(argv: list[str] | None = None) -> int:
    """The command line (see the module's docstring); returns the exit status."""
    ap = argparse.ArgumentParser(prog="python scripts/compare_benchmarks.py",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-9, help="relative tolerance (1e-9)")
    ap.add_argument("--atol", type=float, default=1e-12, help="absolute tolerance (1e-12)")
    ap.add_argument("--show", type=int, default=5,
                    help="timing differences shown per file (5)")
    args = ap.parse_args(argv)
    try:
        reports = compare_files(args.before, args.after, args.rtol, args.atol)
    except FileNotFoundError as e:
        print(f"compare_benchmarks: {e}; give two JSON files or two folders",
              file=sys.stderr)
        return 2
    same = True
    for name, r in reports.items():
        if isinstance(r, str):
            print(f"{name}: {r}")
            same = False
            continue
        print(f"{name}: {r.equal} of {r.values - r.timing} values equal; timing "
              f"{len(r.timing_differ)} of {r.timing} differ; {len(r.missing)} missing")
        for p, x, y in r.differ:
            print(f"  DIFFERS {'/'.join(p)}: {x!r} -> {y!r}")
        for p, x, y in r.missing:
            print(f"  MISSING {'/'.join(p)}: {x!r} -> {y!r}")
        for p, x, y in r.timing_differ[:args.show]:
            print(f"  timing  {'/'.join(p)}: {x!r} -> {y!r}")
        same &= r.same
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
