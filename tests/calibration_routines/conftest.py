"""Shared fixtures of the calibration-routine tests."""

from __future__ import annotations

import pytest

from instrument.devices.virtual_bench import VirtualBench


@pytest.fixture
def vb():
    """An open virtual bench (seed 1)."""
    with VirtualBench(seed=1) as bench:
        yield bench
