"""The plan runner on the virtual bench: progress, pause/resume, abort/resume,
disconnects, timeouts, prompts and malformed plans."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from instrument.acquisition.plan import (
    Capture,
    Expose,
    Light,
    Move,
    Plan,
    PlanError,
    PlanPoint,
    Prompt,
    register_plan,
)
from instrument.acquisition.runner import RunControl, Runner
from instrument.devices.bench import Bench
from instrument.devices.virtual_bench import VirtualBench
from instrument.runs.runstore import RunStore, RunStoreError


@register_plan
class ZStepPlan(Plan):
    """Test plan: pinhole at a few depths, backlit, fixed exposure, 2 lit + 1 dark."""

    name = "test-zstep"

    def __init__(self, depths=(30.0, 40.0, 50.0, 60.0), settle_s=0.5, prompt=None,
                 wrong_count=False):
        super().__init__(depths=list(depths), settle_s=settle_s, prompt=prompt,
                         wrong_count=wrong_count)

    def points(self):
        return [PlanPoint({"z_mm": z}, ("psf", "psf", "dark")) for z in self.params["depths"]]

    def setup(self):
        if self.params["prompt"]:
            yield Prompt(self.params["prompt"], "do the thing")

    def steps(self, index, point):
        yield Move("source_stage", {"x": 0.0, "y": 0.0, "z": point.coords["z_mm"]},
                   settle_s=self.params["settle_s"])
        yield Light("all")
        yield Expose(exposure_s=0.002)
        yield Capture(1 if self.params["wrong_count"] else 2, "psf")
        yield Light(())
        yield Capture(1, "dark")


def _frames(path):
    store = RunStore.open(path)
    return np.stack([store.frame(i).image for i in range(store.n_frames)])


@pytest.fixture
def reference(tmp_path):
    """An uninterrupted run of ZStepPlan (seed 3)."""
    with VirtualBench(seed=3) as vb:
        result = Runner(vb).run(ZStepPlan(), tmp_path / "ref.zarr")
    assert result.status == "complete"
    return _frames(tmp_path / "ref.zarr")


def test_run_stores_every_frame_with_coordinates_and_emits_progress(tmp_path):
    events = []
    with VirtualBench(seed=3) as vb:
        t0 = vb.clock.now_s
        result = Runner(vb, on_event=events.append).run(ZStepPlan(), tmp_path / "r.zarr",
                                                        note="first sweep")
        assert vb.led_array.lit() == {}
        assert vb.clock.now_s - t0 >= 4 * 0.5  # settle after each move on the sim clock
    assert result.status == "complete" and result.points_done == 4
    kinds = [e.kind for e in events]
    assert kinds[0] == "started" and kinds[-1] == "completed"
    assert kinds.count("frame") == 12 and kinds.count("point_done") == 4
    frames = [e for e in events if e.kind == "frame"]
    assert frames[0].last_frame is not None and frames[-1].eta_s == pytest.approx(0.0)
    assert all(e.eta_s is not None for e in frames)
    assert [e.frames_done for e in frames] == list(range(1, 13))
    store = RunStore.open(tmp_path / "r.zarr")
    assert store.status == "complete" and store.attrs["note"] == "first sweep"
    assert store.attrs["bench_config"]["name"] == "simulated"
    assert store.attrs["device_settings"]["camera"]["settings"]["exposure_s"] > 0
    coords = store.coords_table()
    np.testing.assert_allclose(coords["source_stage.z"], np.repeat([30, 40, 50, 60], 3))
    np.testing.assert_allclose(coords["exposure_s"], 0.002)
    assert list(coords["led_array.n_lit"]) == [1024, 1024, 0] * 4
    psf, _ = store.point_frames(0, "psf")
    dark, _ = store.point_frames(0, "dark")
    assert psf.mean() > dark.mean() + 10


def test_pause_holds_the_run_until_resumed(tmp_path):
    control = RunControl()
    events, paused = [], threading.Event()

    def on_event(e):
        events.append(e.kind)
        if e.kind == "frame" and e.frames_done == 4:
            control.pause()
        if e.kind == "paused":
            paused.set()

    def resume_later():
        assert paused.wait(30)
        control.resume()

    thread = threading.Thread(target=resume_later)
    thread.start()
    with VirtualBench(seed=3) as vb:
        result = Runner(vb, on_event=on_event, control=control).run(ZStepPlan(),
                                                                    tmp_path / "p.zarr")
    thread.join()
    assert result.status == "complete"
    i = events.index("paused")
    assert events[i + 1] == "resumed" and events[:i].count("frame") == 4


def test_abort_makes_the_bench_safe_keeps_data_and_resume_equals_uninterrupted(
        tmp_path, reference):
    control = RunControl()

    def on_event(e):
        if e.kind == "frame" and e.frames_done == 5:
            control.abort("operator pressed stop")

    path = tmp_path / "a.zarr"
    with VirtualBench(seed=3) as vb:
        result = Runner(vb, on_event=on_event, control=control).run(ZStepPlan(), path)
        assert vb.led_array.lit() == {}  # LEDs off after the abort
        assert not vb.source_stage.is_moving()
    assert result.status == "aborted" and "operator pressed stop" in result.error
    assert result.points_done == 1 and "resume" in result.resume_hint
    store = RunStore.open(path)
    assert store.status == "aborted" and store.done().sum() == 5
    assert store.first_incomplete_point() == 1
    with VirtualBench(seed=3) as vb:  # a fresh process's view of the bench
        resumed = Runner(vb).resume(path)
    assert resumed.status == "complete"
    np.testing.assert_array_equal(_frames(path), reference)
    assert RunStore.open(path).attrs["resumes"][0]["point"] == 1


def test_ctrl_c_aborts_cleanly(tmp_path):
    def on_event(e):
        if e.kind == "frame" and e.frames_done == 2:
            raise KeyboardInterrupt

    with VirtualBench(seed=3) as vb:
        result = Runner(vb, on_event=on_event).run(ZStepPlan(), tmp_path / "k.zarr")
        assert vb.led_array.lit() == {}
    assert result.status == "aborted" and "Ctrl-C" in result.error


def test_disconnect_mid_run_is_survived_without_losing_a_point(tmp_path, reference):
    events = []

    def on_event(e):
        events.append(e)
        if e.kind == "frame" and e.frames_done == 7 and "reconnecting" not in kinds():
            vb.camera.faults.disconnect()
            vb.camera.faults.allow_reconnect(after_attempts=2)

    def kinds():
        return [e.kind for e in events]

    with VirtualBench(seed=3) as vb:
        result = Runner(vb, on_event=on_event, reconnect_interval_s=0.5).run(
            ZStepPlan(), tmp_path / "d.zarr")
    assert result.status == "complete"
    assert "reconnecting" in kinds() and "reconnected" in kinds()
    assert "3 attempt" in next(e.message for e in events if e.kind == "reconnected")
    np.testing.assert_array_equal(_frames(tmp_path / "d.zarr"), reference)


def test_device_that_stays_away_fails_the_run_cleanly(tmp_path):
    def on_event(e):
        if e.kind == "frame" and e.frames_done == 4:
            vb.camera.faults.disconnect()

    with VirtualBench(seed=3) as vb:
        t0 = vb.clock.now_s
        result = Runner(vb, on_event=on_event, reconnect_timeout_s=5.0,
                        reconnect_interval_s=1.0).run(ZStepPlan(), tmp_path / "f.zarr")
        assert vb.led_array.lit() == {}
        assert vb.clock.now_s - t0 < 60  # gave up after the reconnect timeout
    assert result.status == "failed" and "still disconnected" in result.error
    store = RunStore.open(tmp_path / "f.zarr")
    # every frame captured is kept (point 1's first one too); resume redoes point 1
    assert store.status == "failed" and store.done().sum() == 4
    assert store.first_incomplete_point() == 1


def test_timeout_redoes_the_point(tmp_path, reference):
    events = []

    def on_event(e):
        events.append(e.kind)
        if e.kind == "frame" and e.frames_done == 2 and "retrying" not in events:
            vb.camera.faults.timeout_next(1)

    with VirtualBench(seed=3) as vb:
        result = Runner(vb, on_event=on_event).run(ZStepPlan(), tmp_path / "t.zarr")
    assert result.status == "complete" and "retrying" in events
    np.testing.assert_array_equal(_frames(tmp_path / "t.zarr"), reference)


def test_prompts_go_to_the_operator_or_fail_the_run(tmp_path):
    with VirtualBench(seed=3) as vb:
        during = []
        Runner(vb, on_event=lambda e: during.append(vb.state["diffuser_installed"])
               if e.kind == "frame" else None).run(
            ZStepPlan(depths=(30.0,), prompt="remove_diffuser"), tmp_path / "v.zarr")
        assert during and not any(during)  # the frames were taken without the diffuser
        # ... and the runner put it back at the end (instrument.acquisition.plan.RESTORES)
        assert vb.state["diffuser_installed"] is True
        assert RunStore.open(tmp_path / "v.zarr").attrs["bench_changes"] == []
        plain = Bench(vb.devices, config=vb.config)  # no operator callback
        result = Runner(plain).run(ZStepPlan(depths=(30.0,), prompt="remove_diffuser"),
                                   tmp_path / "n.zarr")
        assert result.status == "failed" and "remove" in result.error.lower() or \
            "do the thing" in result.error
        asked = []
        ok = Bench(vb.devices, config=vb.config,
                   on_prompt=lambda action, msg: asked.append(action) or True)
        assert Runner(ok).run(ZStepPlan(depths=(30.0,), prompt="x"),
                              tmp_path / "o.zarr").status == "complete"
        assert asked == ["x"]


def test_malformed_plan_and_wrong_resume_are_refused(tmp_path):
    with VirtualBench(seed=3) as vb:
        result = Runner(vb).run(ZStepPlan(wrong_count=True), tmp_path / "w.zarr")
        assert result.status == "failed" and "declared" in result.error
        Runner(vb).run(ZStepPlan(depths=(30.0,)), tmp_path / "s.zarr")
        with pytest.raises(RunStoreError, match="other parameters or points"):
            Runner(vb).resume(tmp_path / "s.zarr", ZStepPlan(depths=(31.0,)))
        with pytest.raises(RunStoreError, match="already exists"):
            Runner(vb).run(ZStepPlan(depths=(30.0,)), tmp_path / "s.zarr")


def test_every_stage_target_is_checked_before_the_first_move(tmp_path):
    with VirtualBench(seed=3) as vb:
        start = vb.source_stage.positions()
        with pytest.raises(PlanError, match=r"point 4 of 4 \{'z_mm': 300.0\}.*z=300"):
            Runner(vb).run(ZStepPlan(depths=(30.0, 40.0, 50.0, 300.0)), tmp_path / "p.zarr")
        assert vb.source_stage.positions() == start  # nothing moved
    assert not (tmp_path / "p.zarr").exists()  # no run created


def test_backlash_overshoot_is_checked_along_the_sequence(tmp_path):
    with VirtualBench(seed=3) as vb:
        vb.source_stage.backlash = {"z": 5.0}  # every move ends travelling towards +z
        vb.source_stage.limits = {"z": (0.0, 250.0)}
        vb.source_stage.move_to({"z": 0.0})
        # 120 -> 3 approaches from above: its overshoot at -2 mm is beyond the limit
        with pytest.raises(PlanError, match="point 2 of 2.*overshoot point z=-2"):
            Runner(vb).run(ZStepPlan(depths=(120.0, 3.0)), tmp_path / "b.zarr")
        # increasing depths never overshoot: accepted
        assert Runner(vb).run(ZStepPlan(depths=(3.0, 120.0)), tmp_path / "ok.zarr").status \
            == "complete"


def test_resume_checks_the_remaining_points_before_moving(tmp_path):
    control = RunControl()

    def on_event(e):
        if e.kind == "point_done":
            control.abort("stop after the first point")

    path = tmp_path / "r.zarr"
    with VirtualBench(seed=3) as vb:
        assert Runner(vb, on_event=on_event, control=control).run(
            ZStepPlan(), path).status == "aborted"
    before = RunStore.open(path).attrs
    with VirtualBench(seed=3) as vb:
        vb.source_stage.limits = {"z": (0.0, 45.0)}  # the 50 and 60 mm points no longer fit
        here = vb.source_stage.positions()
        with pytest.raises(PlanError, match=r"point 3 of 4 \{'z_mm': 50.0\}"):
            Runner(vb).resume(path)
        assert vb.source_stage.positions() == here
    after = RunStore.open(path).attrs
    assert after["resumes"] == before["resumes"] and after["status"] == "aborted"
    assert RunStore.open(path).lock_owner() is None  # the lock is released


@register_plan
class LitPlan(Plan):
    """Test plan: light the given LEDs at a fixed exposure and capture one frame."""

    name = "test-lit"

    def __init__(self, leds=((0,),), exposure_s=0.002, brightness=1.0):
        super().__init__(leds=[list(v) for v in leds], exposure_s=exposure_s,
                         brightness=brightness)

    def points(self):
        return [PlanPoint({"leds": v}, ("lit",)) for v in self.params["leds"]]

    def steps(self, index, point):
        yield Light(point.coords["leds"], self.params["brightness"])
        yield Expose(exposure_s=self.params["exposure_s"])
        yield Capture(1, "lit")


@pytest.mark.parametrize("plan, message", [
    (LitPlan(leds=[[0], [5, 1024]]),
     r"point 2 of 2 .*led_array: LED\(s\) \[1024\] outside 0-1023"),
    (LitPlan(brightness=1.5), "brightness 1.5 is outside"),
    (LitPlan(exposure_s=1000.0),
     "point 1 of 1 .*camera: exposure_s=1000.0 is not a number in range"),
])
def test_exposures_and_leds_are_checked_before_the_run(tmp_path, plan, message):
    with VirtualBench(seed=3) as vb:
        with pytest.raises(PlanError, match=message):
            Runner(vb).run(plan, tmp_path / "l.zarr")
        assert vb.led_array.lit() == {}
    assert not (tmp_path / "l.zarr").exists()
