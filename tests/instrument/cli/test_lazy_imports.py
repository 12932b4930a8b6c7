"""The ``diffuserlab`` parser is built, and every ``--help`` shown, without the heavy
libraries: the command line starts in a fraction of a second, and a command loads only
what it runs. Checked on the modules a fresh interpreter holds, not on timings."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

#: Libraries no parser, no ``--help`` may load (seconds of start-up between them).
HEAVY = ("numba", "scipy", "zarr", "dask", "pydantic", "PySide6", "matplotlib", "numpy",
         "tifffile", "cv2", "skimage", "tqdm")

_PROBE = """
import argparse, contextlib, io, json, sys
from instrument.cli import build_parser, main

HEAVY = {heavy!r}

def loaded():
    return sorted({{m.split(".")[0] for m in sys.modules}} & set(HEAVY))

def leaves(parser, path=()):
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path
    for action in subs:
        for name, child in action.choices.items():
            yield from leaves(child, (*path, name))

report = {{"parser": None, "help": {{}}}}
paths = list(leaves(build_parser()))
report["parser"] = loaded()
for path in [(), *paths]:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        main([*path, "--help"])
    report["help"][" ".join(path)] = loaded()
report["commands"] = [" ".join(p) for p in paths]
print(json.dumps(report))
"""


def _run(code: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


@pytest.fixture(scope="module")
def report() -> dict:
    return json.loads(_run(_PROBE.format(heavy=HEAVY)).splitlines()[-1])


def test_the_parser_loads_no_heavy_library(report):
    assert report["parser"] == []


def test_every_help_loads_no_heavy_library(report):
    assert {"recon", "recon3d", "recon-run", "capture live", "validate", "runs show",
            "calibrate resume", "align mask", "gui", "emulators start"} <= set(
        report["commands"])
    assert {path: mods for path, mods in report["help"].items() if mods} == {}


def test_the_option_module_imports_only_the_standard_library():
    code = ("import sys; before = set(sys.modules); import recon.options; "
            "print(sorted(m for m in set(sys.modules) - before "
            "if m.partition('.')[0] not in sys.stdlib_module_names))")
    assert _run(code).strip() == "['diffuserlab', 'diffuserlab.lazy', 'recon', 'recon.options']"


def test_the_calibration_package_loads_its_plans_on_demand():
    code = ("import sys, calibration_routines as c; first = sorted({m.split('.')[0] for m in "
            "sys.modules} & {'scipy', 'numpy', 'zarr'}); c.register_plans(); "
            "from instrument.plan import PLAN_TYPES; print(first, sorted(PLAN_TYPES), "
            "c.DarkFlatPlan.name)")
    assert _run(code).strip() == ("[] ['angular-response', 'dark-flat', 'psf-blind', "
                                  "'psf-grid', 'psf-sweep', 'slm-lut'] dark-flat")
