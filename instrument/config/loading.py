"""Reading bench files and validating them into BenchConfig (every problem at once).

Part of :mod:`instrument.config` (see its docstring). These are the checks that need
no driver; :func:`instrument.devices.bench_setup.parse_bench` and
:func:`instrument.devices.bench_setup.load_bench` add the driver checks and simulated twins.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from .models import BenchConfig, bench_rule_problems
from .problems import (
    BenchConfigError,
    Problem,
    dotted,
    line_index,
    locate,
    problems_from_validation,
    within,
)

# ---------------------------------------------------------------------- loading

_TOML_POS_RE = re.compile(r"\(at line (\d+), column (\d+)\)")


_NUMBER_WITH_UNIT_RE = re.compile(r"=\s*[-+]?\d[\d._eE+-]*\s*[A-Za-zµμ]+\s*(#.*)?$")


def _syntax_fix(msg: str, line_text: str = "") -> str:
    low = msg.lower()
    if _NUMBER_WITH_UNIT_RE.search(line_text):
        return "write the number without its unit: the unit is in the key name (e.g. _mm, _s)"
    if "expected newline" in low or "end of line" in low:
        return "one key = value per line; put comments after #"
    if "invalid value" in low:
        return (
            'quote strings ("..."), write numbers without units (the unit is in the key '
            "name), arrays as [a, b]"
        )
    if "cannot overwrite" in low or "cannot declare" in low or "duplicate" in low:
        return "a key or table is defined twice: keep one (repeated devices use [[devices]])"
    if "expected '=' after a key" in low:
        return "write key = value"
    if "unclosed" in low or "end of" in low:
        return "close the string, array or table header"
    return "correct the TOML syntax at that position"


def _syntax_problem(exc: tomllib.TOMLDecodeError, text: str) -> Problem:
    msg = str(exc)
    m = _TOML_POS_RE.search(msg)
    line = col = None
    if m:
        line, col = int(m.group(1)), int(m.group(2))
        msg = msg[: m.start()].strip()
    elif msg.endswith("(at end of document)"):
        line = max(1, len(text.splitlines()))
        msg = msg[: -len("(at end of document)")].strip() + " (at the end of the file)"
    snippet = line_text = ""
    lines = text.splitlines()
    if line is not None and 1 <= line <= len(lines):
        line_text = lines[line - 1]
        snippet = f": {line_text.strip()!r}"
    where = f"line {line}" + (f", column {col}" if col is not None else "")
    if line is None:
        where = "unknown position"
    return Problem(
        "(TOML syntax)", f"{msg} at {where}{snippet}", _syntax_fix(msg, line_text), line, col
    )


def validate_bench_text(text: str, *, source: str | None = None
                        ) -> tuple[Any, BenchConfig | None, list[Problem]]:
    """TOML text checked against the bench models and rules (no driver is looked at).

    Parameters
    ----------
    text : str
        The TOML document.
    source : str, optional
        Name used in messages (a file path).

    Returns
    -------
    raw : dict
        The parsed TOML document.
    config : BenchConfig or None
        The validated bench, None if the models refused it.
    problems : list of Problem
        What the models and the bench rules refused (empty with a config); not yet
        located on TOML lines (:func:`raise_problems` does that).

    Raises
    ------
    BenchConfigError
        A TOML syntax error (with its line and column), or an empty document or one
        with none of the bench keys (:data:`BENCH_KEYS`): nothing else can be checked.
    """
    raw = _parse_toml(text, source)
    if not set(raw) & BENCH_KEYS:  # not one problem per missing key: one line
        what = f"it holds {', '.join(sorted(raw)[:5])}" if raw else "it is empty"
        raise BenchConfigError([Problem(
            "(file)", f"not a bench file ({what}; a bench file has "
            f"{', '.join(sorted(BENCH_KEYS))})",
            "give a bench file; start from examples/bench-simulated.toml")], source)
    deep = _cut_too_deep(raw)
    problems: list[Problem] = []
    config = None
    try:
        config = BenchConfig.model_validate(raw)
    except ValidationError as exc:
        problems = [
            p for p in problems_from_validation(exc)
            if not any(within(p.location, loc) for loc in deep)  # said once, below
        ]
        if not any(
            p.message.startswith(("duplicate device id", "a lensless bench", "a holography"))
            for p in problems
        ):
            problems += [
                Problem(dotted(loc), msg, fix)
                for loc, msg, fix in bench_rule_problems(
                    raw.get("devices"), raw.get("branches", ["lensless"]),
                    None if any(within(p.location, "geometry") for p in problems)
                    else raw.get("geometry"),  # a geometry with problems is said once
                )
            ]
    problems += [
        Problem(
            loc,
            f"tables and arrays nested more than {MAX_DEPTH} levels deep",
            "a bench file needs only a few levels: write this value as a number, a string, "
            "an array of those or a table of those",
        )
        for loc in deep
    ]
    return raw, config, problems


#: Top-level keys of which a bench file has at least one (anything else is another
#: kind of TOML file, refused in one line rather than one line per missing key).
BENCH_KEYS = frozenset({"name", "devices", "geometry", "branches", "calibration"})

#: How deep tables and arrays may nest in a bench file (the deepest the models use is 5:
#: ``devices[0].params.axes.x``); deeper values are refused before validation.
MAX_DEPTH = 16



def _parse_toml(text: str, source: str | None) -> dict[str, Any]:
    """``tomllib.loads``, every failure a :class:`BenchConfigError` with the line where known."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        problem = _syntax_problem(exc, text)
    except RecursionError:  # tomllib recurses once per level of nesting
        problem = Problem(
            "(TOML syntax)",
            "arrays or inline tables nested too deeply to read",
            f"a bench file needs at most {MAX_DEPTH} levels of nesting; close the brackets",
        )
    except ValueError:  # an integer too long for int() (sys.get_int_max_str_digits)
        limit = sys.get_int_max_str_digits()
        m = re.search(r"\d{%d,}" % (limit + 1), text) if limit else None  # noqa: UP031
        problem = Problem(
            "(TOML syntax)",
            f"a number with more than {limit} digits, too long to read",
            "write numbers with a few digits (an exponent for large values: 1e30)",
            text[: m.start()].count("\n") + 1 if m else None,
        )
    raise BenchConfigError([problem], source) from None


def _cut_too_deep(raw: dict[str, Any]) -> list[str]:
    """Replace every value nested deeper than :data:`MAX_DEPTH` by None (so that nothing
    downstream recurses into it); returns their dotted locations."""
    cut: list[str] = []
    stack: list[tuple[Any, tuple]] = [(raw, ())]
    while stack:
        node, loc = stack.pop()
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        for key in keys:
            value = node[key]
            if not isinstance(value, dict | list):
                continue
            if len(loc) + 1 >= MAX_DEPTH:
                node[key] = None
                cut.append(dotted((*loc, key)))
            else:
                stack.append((value, (*loc, key)))
    return cut


def raise_problems(problems: list[Problem], text: str, source: str | None = None) -> None:
    """Raise every problem at once, each located on its TOML line, in line order, each
    once (two errors of one value, e.g. both elements of an empty pair missing, are one
    problem).

    Parameters
    ----------
    problems : list of Problem
        Nothing happens if empty.
    text : str
        The TOML document the problems are about.
    source : str, optional
        Name used in messages (a file path).

    Raises
    ------
    BenchConfigError
        If there is any problem.
    """
    if not problems:
        return
    index = line_index(text)
    located = list(dict.fromkeys(locate(p, index) for p in problems))  # each said once
    located.sort(key=lambda p: (p.line is None, p.line or 0))
    raise BenchConfigError(located, source)


def read_bench_text(path: str | Path) -> str:
    """The text of a bench file.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    str

    Raises
    ------
    BenchConfigError
        Unreadable file (missing, a directory, no permission) or not UTF-8, with the fix.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        fix = "check the path" if isinstance(exc, FileNotFoundError) else "check the file"
        if isinstance(exc, IsADirectoryError):
            fix = "give the path of a .toml file, not a directory"
        elif isinstance(exc, PermissionError):
            fix = "make the file readable (chmod) or copy it"
        problem = Problem("(file)", f"cannot read: {reason}", fix)
        raise BenchConfigError([problem], str(path)) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise BenchConfigError(
            [Problem("(file)", "not UTF-8 text", "save the file as UTF-8 TOML", line)], str(path)
        ) from None
