"""The import paths users' scripts and the docs used before instrument/ had rooms keep
working (instrument/__init__.py's finder), and give the very module of the new path;
the other old paths are gone (the rooms are the only spelling in the package)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

OLD_NEW = [
    ("bench_process", "bench.bench_process"),
    ("runstore", "runs.runstore"),
    ("runner", "acquisition.runner"),
    ("virtual_bench", "devices.virtual_bench"),
    ("stacks", "runs.stacks"),
]


@pytest.mark.parametrize(("old", "new"), OLD_NEW)
def test_an_old_path_is_the_new_module(old, new):
    assert importlib.import_module(f"instrument.{old}") is importlib.import_module(
        f"instrument.{new}")


def test_the_names_the_docs_show_import_from_their_old_paths():
    from instrument.bench_process import BenchClient
    from instrument.runner import Runner
    from instrument.runstore import RunStore
    from instrument.stacks import load_psf_stack
    from instrument.virtual_bench import PlanarScene, VirtualBench

    from instrument.acquisition import average_frames
    from instrument.acquisition.exposure import average_frames as now
    from instrument.bench.bench_process import BenchClient as client_now
    from instrument.runs.runstore import RunStore as store_now
    from recon import reconstruct

    assert average_frames is now and BenchClient is client_now and RunStore is store_now
    assert callable(reconstruct) and callable(load_psf_stack)
    assert Runner.__module__ == "instrument.acquisition.runner"
    assert VirtualBench.__module__ == PlanarScene.__module__ == "instrument.devices.virtual_bench"


def test_an_old_path_in_a_fresh_process_imports_only_what_it_names():
    """The finder imports nothing by itself: a fresh interpreter that imports
    ``instrument`` has no room loaded, and an old path loads its module."""
    code = ("import sys, instrument; assert 'instrument.runs.runstore' not in sys.modules; "
            "from instrument.runstore import RunStore; "
            "assert sys.modules['instrument.runstore'] is sys.modules['instrument.runs.runstore']")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_other_old_paths_are_gone():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("instrument.run_layout")
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("instrument.bench_host")
