"""The Qt binding does not leak references to None or True (PySide6 6.12.0 on Python 3.11
did: the GUI aborted with 'Fatal Python error: none_dealloc' after ~80 s of live view).

The check runs in a subprocess, since a leaking binding can abort the interpreter
(``bool_dealloc``). ``DIFFUSERLAB_BINDING_PYTHON`` runs it under another interpreter,
e.g. a throwaway environment holding a version under suspicion::

    python -m venv /tmp/venv612 && /tmp/venv612/bin/pip install PySide6-Essentials==6.12.0
    DIFFUSERLAB_BINDING_PYTHON=/tmp/venv612/bin/python python -m pytest tests/gui/test_binding.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _drift(calls: int) -> tuple[subprocess.CompletedProcess, dict | None]:
    python = os.environ.get("DIFFUSERLAB_BINDING_PYTHON") or sys.executable
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "PYTHONPATH": str(ROOT)}
    run = subprocess.run([python, "-m", "gui.binding", str(calls)], capture_output=True,
                         text=True, timeout=120, env=env, cwd=ROOT)
    lines = run.stdout.strip().splitlines()
    return run, (json.loads(lines[-1]) if run.returncode == 0 and lines else None)


def test_qt_calls_and_signal_emits_keep_none_and_true_alive():
    from gui.binding import LEAK_LIMIT

    run, drift = _drift(2000)
    assert run.returncode == 0, (
        f"the binding check died (status {run.returncode}): {run.stderr[-800:]}")
    assert abs(drift["none"]) <= LEAK_LIMIT, (
        f"PySide6 {drift['binding']} on Python {drift['python']} moved the reference count "
        f"of None by {drift['none']} over {drift['calls']} QLabel.setText calls")
    assert abs(drift["true"]) <= LEAK_LIMIT, (
        f"PySide6 {drift['binding']} moved True's count by {drift['true']} over "
        f"{drift['calls']} Signal(bool).emit calls")


def test_objects_destroyed_with_a_connection_keep_no_reference_to_none():
    """PySide6 6.10 and 6.11 kept one per connection (pyqtgraph's items: the operator's
    day drifted by thousands a minute)."""
    from gui.binding import LEAK_LIMIT

    run, drift = _drift(2000)
    assert run.returncode == 0, run.stderr[-800:]
    assert abs(drift["destroyed"]) <= LEAK_LIMIT, (
        f"PySide6 {drift['binding']} on Python {drift['python']} moved the reference count "
        f"of None by {drift['destroyed']} over {drift['calls']} QObjects destroyed with a "
        "signal connected")


def test_a_leaking_binding_is_refused_before_the_window_opens(monkeypatch):
    import gui.binding as binding

    monkeypatch.setattr(binding, "reference_drift", lambda calls, emit_bools: {
        "none": -calls, "true": 0, "calls": calls, "binding": "6.12.0", "python": "3.11.7"})
    with pytest.raises(binding.BindingLeakError) as refused:
        binding.check_binding()
    text = str(refused.value)
    assert "6.12.0" in text and "none_dealloc" in text and "pip install" in text


def test_the_gui_extra_excludes_the_leaking_releases():
    import tomllib

    from packaging.requirements import Requirement
    from packaging.version import Version

    extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]["gui"]
    pyside = [Requirement(r) for r in extra if r.startswith("PySide6")]
    assert len(pyside) == 1 and pyside[0].marker is None, extra
    for leaking in ("6.12.0", "6.11.3", "6.10.0", "6.10.3"):
        assert not pyside[0].specifier.contains(Version(leaking)), leaking
    assert pyside[0].specifier.contains(Version("6.9.3"))
