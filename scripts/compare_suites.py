"""Compare two runs of the test suite, test by test (docs/architecture.md, "The test
suite before and after the move").

    python scripts/compare_suites.py BEFORE.xml AFTER.xml [--show N]

BEFORE and AFTER are JUnit XML reports, as ``pytest --junitxml=FILE`` writes them. A test
is named by its file and name as pytest gives them (``tests/recon/test_live.py::
test_cold[1]``; the report's ``classname`` with dots is turned back into the file's
path), and its outcome is one of ``passed``, ``failed``, ``error`` and ``skipped``
(a test with a failure *and* an error in teardown counts as ``failed``). Prints the
counts of each side, the tests that only one side ran, and every test whose outcome
differs. Exit status 0 when every test both sides ran has the same outcome, 1 when one
differs, 2 for a file that cannot be read.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

__all__ = ["OUTCOMES", "compare", "main", "outcomes"]

#: The outcomes a test can have, worst first (a test reported twice keeps its worst).
OUTCOMES = ("failed", "error", "skipped", "passed")


def _test_id(case: ET.Element) -> str:
    """``path/to/test_file.py::name`` of a ``<testcase>``: its dotted ``classname`` with
    the module's dots made slashes (the module is the last part that starts with
    ``test``; a class after it stays as ``::Class``), or the classname as it is where
    no part does (a doctest)."""
    parts = (case.get("classname") or "").split(".")
    modules = [k for k, part in enumerate(parts) if part.startswith("test")]
    if modules:
        k = modules[-1]
        head = ["/".join(parts[:k + 1]) + ".py", *parts[k + 1:]]
    else:
        head = [".".join(parts)]
    return "::".join([*head, case.get("name", "")])


def _outcome(case: ET.Element) -> str:
    tags = {child.tag for child in case}
    if "failure" in tags:
        return "failed"
    if "error" in tags:
        return "error"
    if "skipped" in tags:
        return "skipped"
    return "passed"


def outcomes(path: str | Path) -> dict[str, str]:
    """Every test of a JUnit XML report and its outcome.

    Parameters
    ----------
    path : str or Path
        The report (``pytest --junitxml``).

    Returns
    -------
    dict
        ``{test id: outcome}``, one of :data:`OUTCOMES`; a test listed twice (a
        teardown error after a pass) keeps its worse outcome.

    Raises
    ------
    OSError, xml.etree.ElementTree.ParseError
        The file cannot be read, or is not XML.
    """
    found: dict[str, str] = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        test, result = _test_id(case), _outcome(case)
        old = found.get(test)
        if old is None or OUTCOMES.index(result) < OUTCOMES.index(old):
            found[test] = result
    return found


def compare(before: dict[str, str], after: dict[str, str]) -> dict:
    """What differs between two suites' outcomes.

    Parameters
    ----------
    before, after : dict
        ``{test id: outcome}`` (:func:`outcomes`).

    Returns
    -------
    dict
        ``counts`` (``{"before": Counter, "after": Counter}``), ``only_before`` and
        ``only_after`` (sorted test ids), ``changed`` (sorted ``(test, before,
        after)``) and ``same`` (how many tests both ran with one outcome).
    """
    both = before.keys() & after.keys()
    changed = sorted((t, before[t], after[t]) for t in both if before[t] != after[t])
    return {"counts": {"before": Counter(before.values()), "after": Counter(after.values())},
            "only_before": sorted(before.keys() - after.keys()),
            "only_after": sorted(after.keys() - before.keys()),
            "changed": changed, "same": len(both) - len(changed)}


def _counts(counter: Counter) -> str:
    return ", ".join(f"{counter.get(o, 0)} {o}" for o in reversed(OUTCOMES))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("before")
    p.add_argument("after")
    p.add_argument("--show", type=int, default=50, help="tests listed per section")
    args = p.parse_args(argv)
    try:
        before, after = outcomes(args.before), outcomes(args.after)
    except (OSError, ET.ParseError) as exc:
        print(f"cannot read a report: {exc}", file=sys.stderr)
        return 2
    res = compare(before, after)
    print(f"before: {len(before)} tests: {_counts(res['counts']['before'])}")
    print(f"after:  {len(after)} tests: {_counts(res['counts']['after'])}")
    print(f"same outcome on both sides: {res['same']}")
    for key, label in (("only_before", "only before"), ("only_after", "only after")):
        tests = res[key]
        print(f"{label}: {len(tests)}")
        for test in tests[:args.show]:
            print(f"  {test}  ({(before if key == 'only_before' else after)[test]})")
    print(f"outcome changed: {len(res['changed'])}")
    for test, was, now in res["changed"][:args.show]:
        print(f"  {test}: {was} -> {now}")
    return 1 if res["changed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
