"""An SLM's two ways to display (drivers/slm.py): a phase map and a gray image go
through one checked display, so they refuse the same things in the same order."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.errors import DeviceStateError, DeviceValueError
from drivers.simulated import SimulatedSlm


@pytest.fixture
def slm():
    with SimulatedSlm("slm0") as dev:
        yield dev


def _inputs(slm):
    rows, cols = slm.resolution
    return {"show_phase": np.zeros((rows, cols)), "show_image": np.zeros((rows, cols), np.uint8)}


@pytest.mark.parametrize("show", ["show_phase", "show_image"])
def test_both_displays_go_through_one_checked_display(slm, show, monkeypatch):
    seen = []
    real = type(slm)._show

    def spy(self, gray, timeout_s):
        seen.append(timeout_s)
        return real(self, gray, timeout_s)

    monkeypatch.setattr(type(slm), "_show", spy)
    before = slm.pattern_id
    assert getattr(slm, show)(_inputs(slm)[show], timeout_s=2.0) == before + 1
    assert seen == [2.0]


@pytest.mark.parametrize("show", ["show_phase", "show_image"])
def test_a_bad_timeout_is_named_before_a_bad_image(slm, show):
    with pytest.raises(DeviceValueError, match="timeout_s"):
        getattr(slm, show)(np.zeros((2, 2), np.uint8), timeout_s=-1.0)
    with pytest.raises(DeviceValueError, match="invalid"):
        getattr(slm, show)(np.zeros((2, 2), np.uint8))
    shown = slm.pattern_id
    slm.close()
    with pytest.raises(DeviceStateError):
        getattr(slm, show)(np.zeros((2, 2)), timeout_s=-1.0)
    assert shown == slm.pattern_id
