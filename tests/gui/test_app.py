"""The window's persistence, the command's registration and the error messages."""

from __future__ import annotations

import os

import pytest


def test_dock_layout_geometry_and_bench_file_persist_between_sessions(qapp, tmp_path, monkeypatch):
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    from gui.app import MainWindow, settings
    from gui.session import Session

    bench = os.path.join(os.path.dirname(__file__), "..", "..", "examples",
                         "bench-simulated.toml")
    first = MainWindow(Session(bench, simulate=True))
    first.show()
    first.docks["Results"].setFloating(True)
    first.docks["Alignment"].close()
    first.save()
    first.deleteLater()
    assert settings().value("bench/last_file") == bench
    second = MainWindow(Session(bench, simulate=True))
    second.show()
    assert second.docks["Results"].isFloating()
    assert second.docks["Alignment"].isHidden() and not second.docks["Record"].isHidden()
    second.deleteLater()


def test_gui_command_is_registered():
    from instrument.cli import build_parser

    args = build_parser().parse_args(["gui", "--simulate", "--scene", "none", "--no-connect"])
    assert args.simulate and args.scene == "none" and args.no_connect
    assert args.handler.__module__ == "gui.cli"


def test_errors_read_as_the_library_wrote_them():
    from gui.workers import readable_error
    from instrument.acquisition.runner import RunAborted
    from instrument.config import BenchConfigError
    from instrument.devices.bench_setup import parse_bench

    with pytest.raises(BenchConfigError) as bad:
        parse_bench("[[devices]]\nid = 3\n")
    text = readable_error(bad.value)
    assert text.splitlines() == bad.value.lines() and "Traceback" not in text
    assert readable_error(RunAborted("aborted by the operator")) == "aborted by the operator"
    assert readable_error(FileNotFoundError(2, "No such file or directory", "x.toml")) == \
        "No such file or directory: x.toml"
    bug = readable_error(ZeroDivisionError("division by zero"))
    assert "ZeroDivisionError" in bug and "bug" in bug
