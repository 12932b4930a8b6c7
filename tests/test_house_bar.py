"""The house bar (issue 66): literal restated defaults, counted, and the options' one route.

**What is counted.** A *literal restated default* is a parameter of a function or
method in the installed packages (``recon``, ``instrument``, ``calibration_routines``,
``gui``, ``drivers``, ``diffuserlab``) that is named as one of the two declared
reconstruction options the issue names, ``iterations`` or ``bin_factor``
(:class:`recon.options.ReconOptions` declares their defaults once), and whose default
is a number written as a literal (``iterations=100``, ``bin_factor=1``). A default
that names its declaration (``iterations: int = ESTIMATE_ITERATIONS``,
``DEFAULT_ITERATIONS``) is not counted: it is stated once, where it is declared. Nor
are parameters without a default, other names (another quantity named as its own:
``power_iterations``, ``refinements``, ``steps``), or the benchmark scripts and
tests (not installed). The review at 8bd5b81 counted 42 by its own measure; the goal
is <= 20. :data:`CEILING` is the count when this test was written: it only goes down.

**One route for options.** No caller unpacks a :class:`~recon.options.ReconOptions`
into keywords of :func:`recon.reconstruct` (``reconstruct(model, raw,
**options.keywords(kind))``): it passes the object, ``reconstruct(model, raw,
options)``.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("recon", "instrument", "calibration_routines", "gui", "drivers", "diffuserlab")
#: The declared options whose literal defaults are counted.
NAMES = ("iterations", "bin_factor")
#: The issue's goal.
GOAL = 20
#: The count when the test was written (issue 66; 33 at the start of the previous
#: session by this measure, 16 at its end).
CEILING = 14


def restated_defaults(source: str) -> list[str]:
    """``"line: function name=value"`` for each counted default in ``source``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            continue
        a = node.args
        positional = a.posonlyargs + a.args
        pairs = [*zip(positional[len(positional) - len(a.defaults):], a.defaults, strict=True),
                 *((k, d) for k, d in zip(a.kwonlyargs, a.kw_defaults, strict=True)
                   if d is not None)]
        for arg, default in pairs:
            value = default.operand if (isinstance(default, ast.UnaryOp)
                                        and isinstance(default.op, ast.USub)) else default
            if (arg.arg in NAMES and isinstance(value, ast.Constant)
                    and isinstance(value.value, int | float)
                    and not isinstance(value.value, bool)):
                name = getattr(node, "name", "lambda")
                found.append(f"{node.lineno}: {name} {arg.arg}={ast.unparse(default)}")
    return found


def _count() -> dict[str, list[str]]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found = restated_defaults(path.read_text(encoding="utf-8"))
            if found:
                out[path.relative_to(ROOT).as_posix()] = found
    return out


def test_the_house_bar_reads_at_most_its_ceiling():
    found = _count()
    n = sum(len(v) for v in found.values())
    assert n <= min(CEILING, GOAL), (
        f"{n} literal restated defaults (ceiling {CEILING}, goal <= {GOAL}): name the "
        f"declared default, or give another quantity its own name: {found}")


def test_the_count_sees_each_form():
    """Each form is counted (a count that finds nothing passes whatever the code
    does), and what is not a restated literal is not."""
    counted = """
def a(x, iterations=100): ...
def b(*, bin_factor=1, other=3): ...
class C:
    def m(self, iterations: int = 5, bin_factor: float = 2.0): ...
f = lambda iterations=-1: iterations
"""
    assert len(restated_defaults(counted)) == 5, restated_defaults(counted)
    not_counted = """
def a(x, iterations=DEFAULT_ITERATIONS, power_iterations=30): ...
def b(*, bin_factor=None, refinements=2, steps=10): ...
def c(iterations, bin_factor: int): ...
def d(bin_factor=True): ...
"""
    assert restated_defaults(not_counted) == []


def unpacked_options(source: str) -> list[str]:
    """``"line: call"`` for each ``reconstruct(...)`` call given ``**`` of an expression
    calling ``.keywords(...)`` (an options object unpacked into keywords)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.Call) and (
                getattr(node.func, "id", None) == "reconstruct"
                or getattr(node.func, "attr", None) == "reconstruct")):
            continue
        for kw in node.keywords:
            if kw.arg is None and any(
                    isinstance(n, ast.Call) and getattr(n.func, "attr", None) == "keywords"
                    for n in ast.walk(kw.value)):
                found.append(f"{node.lineno}: {ast.unparse(node)[:80]}")
    return found


def test_callers_pass_the_options_object():
    calls = {}
    for package in ("instrument", "calibration_routines", "gui"):
        for path in sorted((ROOT / package).rglob("*.py")):
            found = unpacked_options(path.read_text(encoding="utf-8"))
            if found:
                calls[path.relative_to(ROOT).as_posix()] = found
    assert not calls, ("pass the ReconOptions itself, reconstruct(model, raw, options), "
                       f"instead of unpacking it: {calls}")


def test_the_unpacking_scan_sees_both_forms():
    source = """
reconstruct(psf, raw, **{**options.keywords("image"), "dark": dark})
recon.reconstruct(psf, raw, **opts.keywords(kind), bayer=b)
reconstruct(psf, raw, options, dark=dark)
reconstruct(psf, raw, **extra)
"""
    assert len(unpacked_options(source)) == 2, unpacked_options(source)
