"""Parsing and loading bench files into BenchConfig (every problem at once).

Part of :mod:`instrument.config` (see its docstring).
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from pydantic import (
    ValidationError,
)

from .base import SIMULATED_DRIVERS
from .defaults import with_simulated_drivers
from .models import BenchConfig, bench_rule_problems
from .problems import (
    BenchConfigError,
    Problem,
    _dotted,
    _line_index,
    _locate,
    _problems_from_validation,
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


def parse_bench(
    text: str,
    *,
    source: str | None = None,
    check_drivers: bool = True,
    simulate: bool = False,
    construct: bool = False,
) -> BenchConfig:
    """Validate TOML text as a bench; raises :class:`BenchConfigError` with every problem.

    Parameters
    ----------
    text : str
        The TOML document.
    source : str, optional
        Name used in messages (a file path).
    check_drivers : bool
        Also check every driver name in the registry and its kind (imports the
        drivers).
    simulate : bool
        Return the bench with every device swapped for its simulated twin
        (:func:`with_simulated_drivers`); the drivers checked are then the twins, so a
        lab file validates on a machine without its hardware drivers.
    construct : bool
        Also construct every device (without opening it), so parameter values the
        driver refuses are reported here rather than at open (``validate`` does).
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BenchConfigError([_syntax_problem(exc, text)], source) from None
    problems: list[Problem] = []
    config = None
    try:
        config = BenchConfig.model_validate(raw)
    except ValidationError as exc:
        problems = _problems_from_validation(exc)
        if not any(
            p.message.startswith(("duplicate device id", "a lensless bench", "a holography"))
            for p in problems
        ):
            problems += [
                Problem(_dotted(loc), msg, fix)
                for loc, msg, fix in bench_rule_problems(
                    raw.get("devices"), raw.get("branches", ["lensless"])
                )
            ]
    if check_drivers:
        from instrument.registry import driver_problems

        devices = raw.get("devices")
        if simulate and config is not None:  # the twins, with their translated params
            devices = [d.model_dump() for d in with_simulated_drivers(config).devices]
        elif simulate and isinstance(devices, list):  # invalid file: check the twins' names
            devices = [
                {"id": d.get("id"), "kind": d["kind"], "driver": SIMULATED_DRIVERS[d["kind"]]}
                if isinstance(d, dict) and d.get("kind") in SIMULATED_DRIVERS
                else d
                for d in devices
            ]
        problems += driver_problems(devices)
    if construct and config is not None and not problems:
        from instrument.registry import construction_problems

        problems += construction_problems(with_simulated_drivers(config) if simulate else config)
    if problems:
        index = _line_index(text)
        located = [_locate(p, index) for p in problems]
        located.sort(key=lambda p: (p.line is None, p.line or 0))
        raise BenchConfigError(located, source)
    assert config is not None
    return with_simulated_drivers(config) if simulate else config


def load_bench(
    path: str | Path,
    *,
    check_drivers: bool = True,
    simulate: bool = False,
    construct: bool = False,
) -> BenchConfig:
    """Read and validate a bench TOML file (options as in :func:`parse_bench`).

    Raises
    ------
    BenchConfigError
        Unreadable file, TOML syntax error (line and column), missing keys, unknown
        keys, wrong units or ranges, duplicate ids, bench rules, unknown drivers or a
        driver of another kind: every problem found, each with location and fix.
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
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise BenchConfigError(
            [Problem("(file)", "not UTF-8 text", "save the file as UTF-8 TOML", line)], str(path)
        ) from None
    return parse_bench(
        text,
        source=str(path),
        check_drivers=check_drivers,
        simulate=simulate,
        construct=construct,
    )
