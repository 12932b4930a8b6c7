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

#: The GPU backends and the array-API layers: loaded only when a device other than the
#: CPU is asked for (``--device cuda|auto``, ``device=``), never by the CPU path.
GPU = ("cupy", "torch", "array_api_compat", "array_api_strict")

#: Libraries no parser, no ``--help`` may load (seconds of start-up between them).
HEAVY = ("numba", "scipy", "zarr", "dask", "pydantic", "PySide6", "matplotlib", "numpy",
         "tifffile", "cv2", "skimage", "tqdm", *GPU)

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
    assert _run(code).strip() == ("['diffuserlab', 'diffuserlab.errors', 'diffuserlab.lazy', "
                                  "'diffuserlab.options', 'recon', 'recon.options']")


def test_the_calibration_package_loads_its_plans_on_demand():
    code = ("import sys, calibration_routines as c; first = sorted({m.split('.')[0] for m in "
            "sys.modules} & {'scipy', 'numpy', 'zarr'}); c.register_plans(); "
            "from instrument.acquisition.plan import PLAN_TYPES; print(first, sorted(PLAN_TYPES), "
            "c.DarkFlatPlan.name)")
    assert _run(code).strip() == ("[] ['angular-response', 'dark-flat', 'psf-blind', "
                                  "'psf-grid', 'psf-sweep', 'slm-lut'] dark-flat")


def test_a_cpu_reconstruction_loads_no_gpu_library(tmp_path):
    """``recon`` and ``recon3d`` on the CPU (the default device) run the NumPy path and
    never import CuPy, PyTorch or the array-API layers."""
    code = f"""
import sys
import numpy as np
from instrument.cli import main
rng = np.random.default_rng(0)
psf = np.full((32, 40), 4.0, np.float32)
psf[rng.integers(0, 32, 30), rng.integers(0, 40, 30)] += 900.0
np.save({str(tmp_path / "psf.npy")!r}, psf)
raw = rng.poisson(200 + 100 * rng.random((32, 40))) + 4.0
np.save({str(tmp_path / "raw.npy")!r}, raw.astype(np.float32))
stack = np.stack([psf, psf[:, ::-1]])
import tifffile
tifffile.imwrite({str(tmp_path / "stack.tif")!r}, stack)
assert main(["recon", "--psf", {str(tmp_path / "psf.npy")!r}, "--raw",
             {str(tmp_path / "raw.npy")!r}, "--iterations", "5",
             "--out", {str(tmp_path / "r")!r}]) == 0
assert main(["recon3d", "--psf-stack", {str(tmp_path / "stack.tif")!r}, "--depths", "10,20",
             "--raw", {str(tmp_path / "raw.npy")!r}, "--iterations", "3", "--tv", "1e-3",
             "--out", {str(tmp_path / "v.tif")!r}]) == 0
print(sorted({{m.split(".")[0] for m in sys.modules}} & set({GPU!r})))
"""
    assert _run(code).strip().splitlines()[-1] == "[]"
