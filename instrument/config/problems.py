"""Problems with locations and fixes, and the TOML line locator.

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from typing import Any

from pydantic import (
    ValidationError,
)

from diffuserlab.errors import InputError

from .base import Section, dotted, short_repr, unit_of, unit_word
from .defaults import default_bench
from .models import BenchConfig, CalibrationDefaults, DeviceConfig, GeometryConfig
from .writer import toml_value

# ------------------------------------------------------------------------ problems


@dataclass(frozen=True)
class Problem:
    """One problem in a bench file: where (dotted path, TOML line), what, and the fix."""

    location: str
    message: str
    fix: str
    line: int | None = None
    column: int | None = None

    def format(self, source: str | None = None) -> str:
        """``source:line: location: message; fix: ...`` (parts omitted when unknown)."""
        where = ""
        if source:
            where = str(source)
            if self.line is not None:
                where += f":{self.line}"
                if self.column is not None:
                    where += f":{self.column}"
            where += ": "
        elif self.line is not None:
            where = f"line {self.line}: "
        return f"{where}{self.location}: {self.message}; fix: {self.fix}"

    def __str__(self) -> str:
        return self.format()


class BenchConfigError(InputError):
    """A bench file or configuration with problems; ``problems`` lists every one of them."""

    def __init__(self, problems: list[Problem], source: str | None = None):
        self.problems = list(problems)
        self.source = source
        n = len(self.problems)
        head = f"{source}: " if source else ""
        super().__init__(
            f"{head}{n} problem{'s' if n != 1 else ''} in the bench configuration:\n"
            + "\n".join(p.format(source) for p in self.problems)
        )

    def lines(self) -> list[str]:
        """One line per problem, with the file, line, location and fix."""
        return [p.format(self.source) for p in self.problems]


_TABLE_MODELS: dict[str, type[Section]] = {
    "": BenchConfig,
    "geometry": GeometryConfig,
    "calibration": CalibrationDefaults,
    "devices": DeviceConfig,
}


def _model_for(loc: tuple) -> type[Section] | None:
    names = [p for p in loc if isinstance(p, str)]
    return _TABLE_MODELS.get(".".join(names))


def _example(loc: tuple) -> str | None:
    """An example value (TOML) for a key, taken from the default bench."""
    names = [p for p in loc if isinstance(p, str)]
    if not names:
        return None
    if names[0] == "devices":
        return {
            "id": '"camera"',
            "kind": '"camera"',
            "driver": '"simulated-camera"',
        }.get(names[-1])
    node: Any = default_bench().model_dump()
    for name in names:
        if not isinstance(node, dict) or name not in node:
            return None
        node = node[name]
    if isinstance(node, dict | list) and names[-1] in ("devices", "geometry", "calibration"):
        return None
    return toml_value(node)


def _table_hint(loc: tuple) -> str:
    parent = loc[:-1]
    names = [p for p in parent if isinstance(p, str)]
    if not names:
        return "at the top of the file"
    if names[0] == "devices":
        idx = next((p for p in parent if isinstance(p, int)), None)
        where = f"[[devices]] table number {idx + 1}" if idx is not None else "[[devices]] table"
        return f"in the {where}" if len(names) == 1 else f"under [devices.{'.'.join(names[1:])}]"
    return f"under [{'.'.join(names)}]"


def problems_from_validation(exc: ValidationError) -> list[Problem]:
    """Every error of a bench's model validation as a :class:`Problem` with a fix.

    Bench-rule errors carry their own problems and custom errors their fix; pydantic's
    built-in errors (missing or unknown key, wrong type or length, ...) are reworded
    with a fix naming the key, its unit and an example value from the default bench.

    Parameters
    ----------
    exc : pydantic.ValidationError
        From ``BenchConfig.model_validate``.

    Returns
    -------
    list of Problem
        Without TOML lines (:func:`locate` adds them).
    """
    problems: list[Problem] = []
    for err in exc.errors(include_url=False):
        loc = tuple(err["loc"])
        typ = err["type"]
        ctx = err.get("ctx") or {}
        key = next((p for p in reversed(loc) if isinstance(p, str)), "")
        got = err.get("input")
        if "problems" in ctx:
            base = loc  # () for the bench-level rules
            for sub, msg, fix in ctx["problems"]:
                problems.append(Problem(dotted(base + tuple(sub)), msg, fix))
            continue
        if "fix" in ctx:
            problems.append(Problem(dotted(loc), err["msg"], ctx["fix"]))
            continue
        # Built-in pydantic errors, reworded with a fix.
        if typ == "missing":
            if loc and isinstance(loc[-1], int):  # short tuple
                msg, fix = "too few values", f"write two values, e.g. {_example(loc[:-1])}"
                loc = loc[:-1]
            else:
                ex = _example(loc)
                if key in ("devices", "geometry", "calibration"):
                    header = "[[devices]]" if key == "devices" else f"[{key}]"
                    msg = f"missing required table {header}"
                    fix = f"add a {header} table (see examples/bench-simulated.toml)"
                else:
                    msg = "missing required key"
                    fix = f"add {key} = {ex if ex else '...'} {_table_hint(loc)}"
        elif typ == "extra_forbidden":
            model = _model_for(loc[:-1])
            known = list(model.model_fields) if model else []
            close = difflib.get_close_matches(key, known, 1)
            msg = f"unknown key {key!r}"
            fix = f"did you mean {close[0]!r}?" if close else "remove it"
            if known:
                fix += f" (known keys: {', '.join(known)})"
            if model is DeviceConfig:
                fix += "; driver parameters go under [devices.params]"
        elif typ == "literal_error":
            msg = f"expected {ctx.get('expected')}, got {short_repr(got)}"
            fix = f"write {key} = one of {ctx.get('expected')}"
        elif typ == "too_long" or typ == "too_short":
            n = ctx.get("max_length", ctx.get("min_length"))
            msg = f"expected {n} values, got {short_repr(got)}"
            fix = f"write {key} = {_example(loc) or '[a, b]'}"
        elif typ == "list_type" and loc == ("devices",):
            msg = "devices must be an array of tables"
            fix = "write each device as its own [[devices]] table (double brackets)"
        elif typ in ("model_type", "dict_type"):
            msg = f"expected a table, got {short_repr(got)}"
            fix = f"write [{dotted(loc)}] as a table with its keys below it"
        elif typ in ("string_type",):
            msg = f"expected a string, got {short_repr(got)}"
            fix = f'write {key} = "..." (in quotes)'
        elif typ.startswith(("int_", "float_")) or typ in ("tuple_type", "list_type",
                                                           "finite_number"):
            unit = unit_of(key)
            in_unit = f" in {unit_word(unit)}" if unit else ""
            msg = f"{err['msg'].lower()}, got {short_repr(got)}"
            if typ == "list_type":
                what = "an array"
            elif typ == "tuple_type":
                what = "an array of numbers"
            else:
                what = "a finite number" if typ == "finite_number" else "a number"
            fix = f"write {key} as {what}{in_unit}"
            ex = _example(loc)
            if ex:
                fix += f", e.g. {key} = {ex}"
        else:
            msg, fix = err["msg"], "see examples/bench-simulated.toml"
        problems.append(Problem(dotted(loc), msg, fix))
    return problems


def within(location: str, prefix: str) -> bool:
    """True if dotted ``location`` is ``prefix`` or lies inside it.

    ``within("devices[1].params.x", "devices[1].params")`` is True,
    ``within("devices[10]", "devices[1]")`` is False.

    Parameters
    ----------
    location, prefix : str
        Dotted locations (:func:`dotted`).

    Returns
    -------
    bool
    """
    return location == prefix or location.startswith((prefix + ".", prefix + "["))


# ------------------------------------------------------------- TOML line locator

_HEADER_RE = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY_RE = re.compile(
    r"""^\s*((?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*'))*)\s*="""
)  # noqa: E501


def _split_key(text: str) -> list[str]:
    parts = re.findall(r"""[A-Za-z0-9_-]+|"[^"]*"|'[^']*'""", text)
    return [p.strip("\"'") for p in parts]


def line_index(text: str) -> dict[str, int]:
    """Best-effort map from dotted paths (``devices[1].driver``) to 1-based line numbers.

    Parameters
    ----------
    text : str
        The TOML document.

    Returns
    -------
    dict
        ``{dotted path: line}`` for every table header and key found.
    """
    index: dict[str, int] = {}
    counts: dict[str, int] = {}
    prefix: list[str] = []

    def resolve(parts: list[str]) -> list[str]:
        out: list[str] = []
        for p in parts:
            path = _join(out + [p])
            out.append(f"{p}[{counts[path] - 1}]" if path in counts else p)
        return out

    for n, line in enumerate(text.splitlines(), 1):
        m = _HEADER_RE.match(line)
        if m and not _KEY_RE.match(line):
            parts = _split_key(m.group(2))
            if m.group(1) == "[[":
                parent = resolve(parts[:-1])
                path = _join(parent + [parts[-1]])
                counts[path] = counts.get(path, 0) + 1
                index.setdefault(path, n)
                prefix = parent + [f"{parts[-1]}[{counts[path] - 1}]"]
            else:
                prefix = resolve(parts)
            index.setdefault(_join(prefix), n)
            continue
        k = _KEY_RE.match(line)
        if k:
            index.setdefault(_join(prefix + _split_key(k.group(1))), n)
    return index


def _join(parts: list[str]) -> str:
    return ".".join(parts).replace(".[", "[")


def locate(problem: Problem, index: dict[str, int]) -> Problem:
    """The problem with the TOML line of its location, or of the nearest enclosing
    table or key that has one.

    Parameters
    ----------
    problem : Problem
    index : dict
        From :func:`line_index`.

    Returns
    -------
    Problem
        ``problem`` itself if it already has a line or nothing encloses it.
    """
    if problem.line is not None:
        return problem
    path = problem.location
    while path:
        if path in index:
            return Problem(problem.location, problem.message, problem.fix, index[path])
        cut = max(path.rfind("."), path.rfind("["))
        path = path[:cut] if cut > 0 else ""
    return problem
