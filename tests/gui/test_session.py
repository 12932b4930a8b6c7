"""A simulated session driven through the GUI's panels (pytest-qt, offscreen platform):
connect, device settings (a refused value shows the interface's message), stage jog and
go-to, the LED picker, the live view, a PSF sweep with pause, abort and resume, live
reconstruction with the sweep's PSF, the results viewer on the run."""

from __future__ import annotations

import gc
import threading

import numpy as np
import pytest

from drivers.errors import DeviceValueError
from gui.messages import operator_text


def test_connect_opens_every_device_with_a_box(window):
    assert list(window.devices.boxes) == list(window.session.devices)
    assert window.devices.connect_button.text() == "Disconnect"
    box = window.devices.boxes["camera"]
    # units and limits come from the device interface's info
    from PySide6.QtWidgets import QLabel

    limits = [w.text() for w in box.findChildren(QLabel) if "limits:" in w.text()]
    lo, hi = window.session.devices["camera"].info["exposure_range_s"]
    assert f"limits: {lo:g} to {hi:g} s" in limits


def test_refused_setting_shows_the_interfaces_message(window, wait):
    box = window.devices.boxes["camera"]
    service = window.session.service
    before = service.settings("camera")["exposure_s"]
    with pytest.raises(DeviceValueError) as refused:
        service.apply_settings("camera", {"exposure_s": -1e-3})
    box.fields["exposure_s"].setText("-1 ms")
    job = box.apply("exposure_s")
    wait(lambda: job.done and box.error.text(), 10, "the refusal")
    # the interface's message, its open range in the GUI's words, and what the field
    # went back to (the value the device holds)
    assert operator_text(str(refused.value)) in box.error.text()
    assert "the device keeps" in box.error.text()
    assert "inf" not in box.error.text() and "exposure_s > 0" in box.error.text()
    assert service.settings("camera")["exposure_s"] == before  # nothing applied
    box.fields["exposure_s"].setText("0.02")
    job = box.apply("exposure_s")
    wait(lambda: job.done and box.error.text() == "", 10, "the setting")
    assert service.settings("camera")["exposure_s"] == pytest.approx(0.02)


def _position(window, axis: str, stage: str = "source_stage") -> float:
    return window.session.service.positions(stage)[axis]


def test_stage_jog_go_to_and_a_target_beyond_the_limits(window, wait):
    box = window.devices.boxes["source_stage"]
    controls = box.stage
    z0 = _position(window, "z")
    controls.jog_steps["z"].setValue(2.0)
    controls.jog("z", +1)
    wait(lambda: not box.queue.busy, 10, "the jog")
    assert _position(window, "z") == pytest.approx(z0 + 2.0)
    controls.targets["z"].setText("30")
    controls.go_to("z")
    wait(lambda: not box.queue.busy, 10, "the move")
    assert _position(window, "z") == pytest.approx(30.0)
    controls.targets["z"].setText("1000")
    controls.go_to("z")
    wait(lambda: not box.queue.busy and box.error.text(), 10, "the refusal")
    assert "outside the limits" in box.error.text()
    assert _position(window, "z") == pytest.approx(30)


def _light_centre_led(window, wait) -> int:
    """Light the LED nearest the axis through the LED map's panel; its index."""
    box = window.devices.boxes["led_array"]
    positions_mm = window.session.devices["led_array"].led_positions_mm
    centre = int(np.argmin(np.hypot(*positions_mm.T)))
    job = box.light_led(centre)
    wait(lambda: job.done, 10, "the LED")
    return centre


def test_led_picker_lights_the_clicked_led(window, wait):
    box = window.devices.boxes["led_array"]
    centre = _light_centre_led(window, wait)
    assert list(window.session.service.lit("led_array")) == [centre]
    brushes = box.led_points.data["brush"]
    assert brushes[centre].color().name() == "#ffb000"


def test_a_click_between_two_leds_lights_the_nearest(window, wait, qapp):
    """The map's circles are ~8 px with ~4 px between them: a click between two did
    nothing. A click a third of the way from one LED to its neighbour lights that LED;
    a click far off the array says so."""
    from PySide6.QtCore import QPoint, QPointF, Qt
    from PySide6.QtTest import QTest

    box = window.devices.boxes["led_array"]
    window.devices.area.ensureWidgetVisible(box.led_plot, 0, 0)
    for _ in range(20):
        qapp.processEvents()
    pos = np.asarray(window.session.devices["led_array"].led_positions_mm, float)
    centre = int(np.argmin(np.hypot(*pos.T)))
    d = np.hypot(*(pos - pos[centre]).T)
    d[centre] = np.inf
    neighbour = int(np.argmin(d))
    between = pos[centre] + (pos[neighbour] - pos[centre]) / 3  # off both circles
    view = box.led_plot.getPlotItem().vb

    def click(x_mm: float, y_mm: float) -> None:
        scene = view.mapViewToScene(QPointF(x_mm, y_mm))
        at = box.led_plot.mapFromScene(scene)
        QTest.mouseClick(box.led_plot.viewport(), Qt.MouseButton.LeftButton,
                         Qt.KeyboardModifier.NoModifier, QPoint(at.x(), at.y()))

    assert box.nearest_led(*between) == centre
    click(*between)
    wait(lambda: list(window.session.service.lit("led_array")) == [centre], 10,
         "the nearest LED lit")
    far = pos.max(axis=0) + 10 * (pos.max(axis=0) - pos.min(axis=0) + 1)
    assert box.nearest_led(*far) is None
    view.setRange(xRange=(far[0] - 1, far[0] + 1), yRange=(far[1] - 1, far[1] + 1))
    click(*far)
    wait(lambda: "no LED near" in box.error.text(), 10, "the line that says why")
    view.autoRange()
    box.error.setText("")


def _frame(window, wait, after: int):
    wait(lambda: window.live._shown_raw > after, 10, "a new frame")
    return window.live._shown_raw, window.live.raw_view.image.astype(float)


def test_live_view_shows_frames_that_change(window, wait):
    """With the LED behind the pinhole lit, moving the stage moves the PSF on the frames.
    The test sets its own bench (it passed only after the tests above): the source
    30 mm in front of the diffuser (at z = 0 the simulated camera refuses to render
    and the stream stops) and the centre LED lit."""
    window.session.service.move("source_stage", {"z": 30.0})
    _light_centre_led(window, wait)
    window.live.toggle_stream()
    wait(lambda: window.session.streaming, 5, "the stream")
    i1, a = _frame(window, wait, -1)
    i2, b = _frame(window, wait, i1)
    noise = np.abs(b - a).mean()
    window.session.service.move("source_stage", {"x": 3.0})
    i3, c = _frame(window, wait, i2 + 1)
    assert i1 < i2 < i3
    assert np.abs(c - b).mean() > 3 * noise  # the PSF moved
    assert "fps" in window.live.raw_stats.text() and "dropped" in window.live.raw_stats.text()
    window.session.service.move("source_stage", {"x": 0.0})
    window.live.toggle_stream()
    wait(lambda: not window.session.streaming, 5, "the stream to stop")


@pytest.fixture(scope="module")
def sweep(window, tmp_path_factory, qapp):
    """A short PSF sweep run through the calibration panel, paused, aborted and resumed."""
    from tests.gui.conftest import wait_for

    def wait(cond, t=60.0, what="the run"):
        wait_for(qapp, cond, t, what)

    panel = window.calibration
    panel.routine.setCurrentText("psf-sweep")
    fields = panel.fields["psf-sweep"]
    for flag, value in (("--z-min", "30"), ("--z-max", "60"), ("--n-depths", "3"),
                        ("--frames", "1")):
        fields[flag].setText(value)
    path = str(tmp_path_factory.mktemp("runs") / "sweep.zarr")
    panel.out.setText(path)
    record = {"path": path, "runners_here": []}
    from instrument.acquisition.runner import Runner

    init = Runner.__init__

    def noted(self, *a, **k):  # a runner made in the window's process
        record["runners_here"].append(threading.current_thread().name)
        init(self, *a, **k)

    Runner.__init__ = noted
    try:
        job = panel.start()
        assert job is not None, panel.status.text()
        wait(lambda: "frame" in panel.events, 60, "the first frame")
    finally:
        Runner.__init__ = init
    panel.toggle_pause()
    wait(lambda: "paused" in panel.events, 30, "the pause")
    done = panel.progress.value()
    record["paused_at"] = done
    record["frames_shown"] = panel.view.image is not None
    panel.abort()
    wait(lambda: job.done and panel.result is not None, 30, "the abort")
    record["aborted"] = panel.result
    record["abort_message"] = panel.status.text()
    # the frames stored when the abort ended it (the bar is emptied once it ends)
    from instrument.runs.runstore import RunStore

    record["progress_after_pause"] = int(RunStore.open(panel.result.path).done().sum())
    job = panel.resume()
    wait(lambda: job.done, 120, "the resumed run")
    record["resumed"] = panel.result
    record["final_message"] = panel.status.text()
    return record


def test_the_devices_the_stream_and_the_runs_live_in_the_bench_process(window, wait, sweep):
    """No device object, grab thread or calibration runner in the window's process."""
    from drivers.base import Device

    session = window.session
    assert not session.service.in_process and session.service.alive()
    assert sweep["runners_here"] == []  # the sweep's runner ran in the bench process
    window.live.toggle_stream()
    wait(lambda: session.streaming and session.frames_seen > 3, 10, "frames")
    try:
        assert not [o for o in gc.get_objects() if isinstance(o, Device)]
        names = {t.name for t in threading.enumerate()}
        assert "bench-frames" in names and "bench-stream" not in names
        assert session.stream_counters()["acquired"] >= 3
    finally:
        window.live.toggle_stream()
        wait(lambda: not session.streaming, 5, "the stream to stop")


def test_psf_sweep_pause_abort_resume(sweep):
    from instrument.runs.runstore import RunStore

    assert sweep["frames_shown"]
    assert sweep["progress_after_pause"] == sweep["paused_at"]  # paused: nothing taken
    assert sweep["aborted"].status == "aborted"
    assert "Resume run" in sweep["abort_message"] and "kept" in sweep["abort_message"]
    assert "--" not in sweep["abort_message"] and "diffuserlab" not in sweep["abort_message"]
    assert sweep["resumed"] is not None, sweep["final_message"]
    assert sweep["resumed"].status == "complete", sweep["final_message"]
    store = RunStore.open(sweep["path"])
    assert store.status == "complete" and "psf_stack" in store.products()


def test_live_reconstruction_with_the_sweeps_psf(window, wait, sweep):
    from instrument.runs.runstore import RunStore

    depths = RunStore.open(sweep["path"]).product("psf_stack")[1]["depths_mm"]
    live = window.live
    live.psf.setText(sweep["path"])
    live.depth.setEditText(f"{depths[0]:g}")
    live.method.setCurrentText("admm")
    live.iterations.setValue(3)
    job = live.start_reconstruction()
    try:
        wait(lambda: job.done, 60, "the PSF to load")
        assert live.live is not None, live.error.text()
        wait(lambda: live._shown_recon >= 0, 120, "a reconstruction")  # numba compiles first
        first = live._shown_recon
        wait(lambda: live._shown_recon > first, 30, "the next reconstruction")
        # the statistics line is refreshed on its own timer: it may still say "no new
        # result for 7 s" (a busy host: run L6) until its next refresh after the result
        wait(lambda: "latency" in live.recon_stats.text(), 30, "the result's statistics")
        text = live.recon_stats.text()
        assert "admm x3" in text and "skipped" in text
        assert live.recon_view.image.shape == window.session.service.camera_format().image_shape
    finally:
        live.stop_reconstruction()
        window.session.stop_stream()
    wait(lambda: not window.session.streaming and live.job.done, 15, "the stream to stop")


def test_results_viewer_shows_the_runs_frames_and_psf_stack(window, wait, sweep):
    results = window.results
    job = results.open(sweep["path"])
    wait(lambda: job.done, 30, "the run to open")
    assert results.store is not None and results.error.text() == ""
    assert "psf_stack" in [results.products.itemText(i) for i in range(results.products.count())]
    results.frame_slider.setValue(1)
    wait(lambda: results.frame_shown == 1, 10, "frame 2")
    assert results.view.image.shape == window.session.service.camera_format().image_shape
    job = results.show_product("psf_stack")
    wait(lambda: job.done, 10, "the product")
    assert results.volume is not None and len(results.volume) == 3
    results.depth_slider.setValue(2)
    assert "plane 3 of 3" in results.depth_label.text() and "mm" in results.depth_label.text()
    assert results.mip_views["xz"].image is not None


def test_calibration_refuses_bad_parameters_with_the_commands_message(window):
    panel = window.calibration
    panel.routine.setCurrentText("psf-sweep")
    panel.fields["psf-sweep"]["--n-depths"].setText("many")
    assert panel.start() is None
    text = panel.status.text()
    assert "'n depths': 'many' is not a whole number" == text, text
    panel.fields["psf-sweep"]["--n-depths"].setText("3")


@pytest.fixture(scope="module")
def video(window, tmp_path_factory, qapp):
    """A short video recorded through the record panel."""
    from tests.gui.conftest import wait_for

    panel = window.record
    path = str(tmp_path_factory.mktemp("video") / "video.zarr")
    panel.out.setText(path)
    panel.frames.setText("12")
    panel.fps.setText("20")
    job = panel.start_recording()
    assert job is not None, panel.record_error.text()
    wait_for(qapp, lambda: job.done, 60, "the recording")
    return {"path": path, "summary": panel.summary, "text": panel.counters.text(),
            "error": panel.record_error.text()}


def test_record_a_short_video(window, video):
    from instrument.runs.runstore import RunStore

    assert video["summary"] is not None, video["error"]
    assert video["summary"]["recorded"] == 12 and video["summary"]["status"] == "complete"
    assert "12 frames written" in video["text"] and "no frame lost" in video["text"]
    assert RunStore.open(video["path"]).done().sum() == 12
    assert window.session.camera_user is None  # the camera is given back


def test_batch_reconstruct_the_video_and_view_it(window, wait, video, sweep):
    from instrument.runs.runstore import RunStore

    depths = RunStore.open(sweep["path"]).product("psf_stack")[1]["depths_mm"]
    panel = window.record
    assert panel.run_path.text() == video["path"]
    fields = panel.batch_fields
    fields["--psf"].setText(sweep["path"])
    fields["--depth"].setEditText(f"{depths[0]:g}")
    fields["--method"].setCurrentText("wiener")
    fields["--frames"].setText("0:4")
    fields["--workers"].setText("1")
    job = panel.start_batch()
    wait(lambda: job.done, 120, "the batch reconstruction")
    assert panel.batch_result is not None, panel.batch_error.text()
    assert panel.batch_result["reconstructed"] == 4
    assert panel.batch_progress.value() == panel.batch_progress.maximum() == 4
    # the result opens in the results viewer: the per-frame product, frame by frame
    results = window.results
    wait(lambda: results.job is not None and results.job.done and (
        results.volume is not None or results.error.text()), 30, "the result")
    assert results.error.text() == ""
    assert len(results.volume) == 4 and results.axis == "frame"
    results.depth_slider.setValue(3)
    assert "frame 4 of 4" in results.depth_label.text()


def test_alignment_shows_readings_pose_and_steps_then_aborts(window, wait, tmp_path):
    panel = window.alignment
    panel.out.setText(str(tmp_path / "mask.align"))
    panel.frames.setValue(1)
    panel.focus.setChecked(False)
    job = panel.start()
    assert job is not None, panel.message.text()
    wait(lambda: len(panel.readings) >= 2 or job.done, 300, "spot readings")
    panel.abort()
    wait(lambda: job.done, 120, "the alignment to stop")
    assert len(panel.readings) >= 2
    assert panel.step_labels["preflight"].text() == "done"
    assert "mm" in panel.pose.text() and "deg" in panel.pose.text()
    text = panel.message.text()
    assert "aborted by the operator" in text and "bug" not in text
    assert window.session.camera_user is None
    assert (tmp_path / "mask.align" / "captures.jsonl").is_file()


@pytest.mark.parametrize("name", ["beads-flow", "neurons", "none"])
def test_every_scene_of_the_gui_shows_on_the_virtual_bench(name):
    """The GUI's scenes are `capture --simulate --scene`'s (neurons failed to prerender)."""
    from instrument.bench.bench_jobs import show_scene
    from instrument.devices.virtual_bench import VirtualBench

    vb = VirtualBench(seed=0, realtime=True).open()
    try:
        show_scene(vb, name)
        assert (vb.scene is None) == (name == "none")
        if name == "neurons":
            assert type(vb.scene).__name__ == "NeuronFieldScene"
    finally:
        vb.close()
