"""Plan steps and hooks added for the holography routines: ShowSlm (gray or phase,
pattern id per frame), AutoExposure.headroom, and Plan.session held around a run."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from instrument.acquisition.plan import (
    AutoExposure,
    Capture,
    Check,
    CheckFailed,
    Expose,
    Light,
    Move,
    Plan,
    PlanError,
    PlanPoint,
    ShowSlm,
    register_plan,
)
from instrument.acquisition.runner import RunControl, Runner
from instrument.devices.virtual_bench import VirtualBench
from instrument.runs.runstore import RunStore


@register_plan
class SlmStepsPlan(Plan):
    """Test plan: per point one SLM pattern (a gray level, or a phase), one frame;
    a session that logs its entry and exit; optionally a failing check."""

    name = "test-slm-steps"

    def __init__(self, levels=(10, 200), phase=False, fail_at=None, headroom=1.0):
        super().__init__(levels=list(levels), phase=phase, fail_at=fail_at, headroom=headroom)
        self.log: list[str] = []

    def points(self):
        return [PlanPoint({"gray": g}, ("frame",)) for g in self.params["levels"]]

    @contextlib.contextmanager
    def _session(self, bench):
        self.log.append("enter")
        try:
            yield
        finally:
            self.log.append("exit")

    def session(self, bench):
        return self._session(bench)

    def steps(self, index, point):
        # logged when the runner executes the point (the preflight walks steps() ahead)
        yield Check("log", lambda bench, store, i: self.log.append(f"point {i}"))
        shape = (96, 120)  # the default bench's SLM
        g = point.coords["gray"]
        if self.params["phase"]:
            yield ShowSlm(phase_rad=np.full(shape, 2 * np.pi * g / 256), label=f"p{g}")
        else:
            yield ShowSlm(gray=np.full(shape, g, np.uint8), label=f"g{g}")
        yield Move("source_stage", {"z": 40.0}, settle_s=0.0)
        yield Light("all")
        yield Expose(auto=AutoExposure(target=0.5, tolerance=0.1,
                                       headroom=self.params["headroom"]))
        if index == self.params["fail_at"]:
            yield Check("always fails", _fail)
        yield Capture(1, "frame")

    def reduce(self, store):
        self.log.append("reduce")
        return {}


def _fail(bench, store, index):
    raise CheckFailed("test check failed", "nothing to fix")


def test_show_slm_needs_exactly_one_pattern():
    with pytest.raises(PlanError, match="exactly one"):
        ShowSlm()
    with pytest.raises(PlanError, match="exactly one"):
        ShowSlm(gray=np.zeros((2, 2), np.uint8), phase_rad=np.zeros((2, 2)))
    with pytest.raises(PlanError, match="timeout_s"):
        ShowSlm(gray=np.zeros((2, 2), np.uint8), timeout_s=0)
    with pytest.raises(PlanError, match="headroom"):
        AutoExposure(headroom=0.0)


@pytest.mark.parametrize("phase", [False, True])
def test_show_slm_displays_and_frames_record_the_pattern_id(tmp_path, phase):
    events = []
    with VirtualBench(seed=4) as vb:
        plan = SlmStepsPlan(phase=phase)
        result = Runner(vb, on_event=events.append).run(plan, tmp_path / "s.zarr")
        assert result.status == "complete", result.error
        expected = vb.slm.phase_to_gray(np.full((96, 120), 2 * np.pi * 200 / 256)) if phase \
            else np.full((96, 120), 200, np.uint8)
        np.testing.assert_array_equal(vb.slm.current_image(), expected)
        last_id = vb.slm.pattern_id
    ids = RunStore.open(tmp_path / "s.zarr").coords_table()["slm.pattern_id"]
    assert ids.tolist() == [last_id - 1, last_id]
    labels = [e.message for e in events if e.step == "showslm"]
    assert labels == (["p10", "p200"] if phase else ["g10", "g200"])


def test_headroom_scales_the_exposure_auto_exposure_reached(tmp_path):
    exposures = []
    for headroom in (1.0, 0.5):
        with VirtualBench(seed=4) as vb:
            Runner(vb).run(SlmStepsPlan(levels=(10,), headroom=headroom),
                           tmp_path / f"h{headroom}.zarr")
        exposures.append(RunStore.open(tmp_path / f"h{headroom}.zarr")
                         .coords_table()["exposure_s"][0])
    assert exposures[1] == pytest.approx(0.5 * exposures[0], rel=1e-9)


def test_session_is_held_around_the_points_and_left_before_reduce(tmp_path):
    with VirtualBench(seed=4) as vb:
        plan = SlmStepsPlan()
        assert Runner(vb).run(plan, tmp_path / "a.zarr").status == "complete"
    assert plan.log == ["enter", "point 0", "point 1", "exit", "reduce"]


def test_session_is_left_on_failure_and_on_abort_and_entered_again_on_resume(tmp_path):
    with VirtualBench(seed=4) as vb:
        plan = SlmStepsPlan(fail_at=1)
        result = Runner(vb).run(plan, tmp_path / "f.zarr")
        assert result.status == "failed" and "test check failed" in result.error
        assert plan.log == ["enter", "point 0", "point 1", "exit"]

        control = RunControl()
        plan = SlmStepsPlan()

        def abort_after_first_frame(event):
            if event.kind == "frame":
                control.abort("test abort")

        result = Runner(vb, on_event=abort_after_first_frame, control=control).run(
            plan, tmp_path / "b.zarr")
        assert result.status == "aborted" and plan.log == ["enter", "point 0", "exit"]
        again = SlmStepsPlan()
        assert Runner(vb).resume(tmp_path / "b.zarr", plan=again).status == "complete"
        assert again.log == ["enter", "point 1", "exit", "reduce"]
