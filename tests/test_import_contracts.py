"""The import contracts of pyproject.toml (``[tool.importlinter]``) hold: the layers
gui > calibration_routines > instrument > drivers | recon, and no import cycle inside
any package (what ``lint-imports`` checks in .ci/run; about a second)."""

from __future__ import annotations

from pathlib import Path

import pytest

cli = pytest.importorskip("importlinter.cli", reason="import-linter (the dev extra) not installed")

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_hold(monkeypatch):
    monkeypatch.chdir(ROOT)
    status = cli.lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True,
                              no_logo=True)
    assert status == cli.EXIT_STATUS_SUCCESS, "lint-imports: a contract is broken (see output)"
