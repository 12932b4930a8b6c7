"""Third-party clients drive our emulators (the ``interop`` extra installs them).

Each test module imports its client with :func:`client`: missing, the module is
skipped with the command that installs it, unless ``DIFFUSERLAB_REQUIRE_INTEROP=1``
(set by ``.ci/run``), where a missing client is an error: CI must run these.
"""

from __future__ import annotations

import importlib
import os

import pytest

EXTRA = "pip install -e '.[interop]'"


def client(module: str, package: str):
    """Import a third-party client ``module`` (PyPI ``package``) or skip/fail."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        if os.environ.get("DIFFUSERLAB_REQUIRE_INTEROP") == "1":
            raise RuntimeError(f"{package} is not installed ({exc}); {EXTRA}") from exc
        pytest.skip(f"{package} is not installed: {EXTRA}", allow_module_level=True)
