"""One JSON writer: every JSON file the project writes goes through
:func:`instrument.atomic.write_json` (text from :func:`diffuserlab.jsonio.json_text`), every
conversion through :func:`diffuserlab.jsonio.jsonable`; no package defines its own."""

import ast
import json
from pathlib import Path

import numpy as np

from diffuserlab.jsonio import json_line, json_text, jsonable
from instrument.atomic import write_json

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("diffuserlab", "recon", "drivers", "instrument", "calibration_routines", "gui")


def _sources():
    for package in PACKAGES:
        yield from sorted((ROOT / package).rglob("*.py"))


def test_jsonable_is_defined_once():
    """One conversion: no module keeps its own (the writer's snapshot had ``_jsonable``)."""
    owners = [str(p.relative_to(ROOT)) for p in _sources()
              if any(isinstance(n, ast.FunctionDef) and n.name.lstrip("_") == "jsonable"
                     for n in ast.walk(ast.parse(p.read_text())))]
    assert owners == ["diffuserlab/jsonio.py"]


def test_no_file_is_written_from_raw_json_dumps():
    """``write_text(json.dumps(...))`` and ``json.dump(obj, file)`` skip the atomic
    write and the standard-JSON conversion; ``json.dumps`` for a message, a protocol
    line or a settings value is fine."""
    found = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
                continue
            inner = [a for a in node.args if isinstance(a, ast.Call)
                     and isinstance(a.func, ast.Attribute) and a.func.attr == "dumps"]
            if node.func.attr == "write_text" and inner:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
            if (node.func.attr == "dump" and isinstance(node.func.value, ast.Name)
                    and node.func.value.id == "json"):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert found == []


def test_writer_and_line_are_standard_json(tmp_path):
    data = {"psnr_db": np.float32(21.5), "shape": (2, 3), "bad": np.inf, "p": tmp_path}
    written = json.loads(write_json(tmp_path / "m.json", data).read_text())
    assert written == json.loads(json_text(data)) == json.loads(json_line(data))
    assert written == {"psnr_db": 21.5, "shape": [2, 3], "bad": None, "p": str(tmp_path)}
    assert "\n" not in json_line(data)[:-1]
    assert jsonable({1: np.int64(2)}) == {"1": 2}


def test_default_writes_what_json_has_no_type_for(tmp_path):
    text = write_json(tmp_path / "r.json", {"error": ValueError("x")}, default=str).read_text()
    assert json.loads(text) == {"error": "x"}
