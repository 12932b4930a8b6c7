"""What broke in the operator's day, each caught here (offscreen; the real-window day is
tests/gui/test_operator_day.py): error messages, Results on the GUI thread, closing
mid-recording, the bench left changed by a run, refused inputs, stage jogs, stale
numbers."""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import pytest
from PySide6.QtCore import QPoint, QPointF, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtTest import QTest

# -- 2. only the project's own errors read as operator messages ---------------------------


def test_a_keyerror_is_a_bug_with_its_traceback_in_the_log(caplog):
    from gui.workers import InputError, readable_error
    from instrument.acquisition.plan import PlanError

    with caplog.at_level(logging.ERROR, logger="gui.workers"):
        text = readable_error(KeyError((1066, 80)))
    assert "bug" in text and "KeyError" in text
    assert caplog.records and caplog.records[-1].exc_info is not None  # the traceback
    for exc in (ValueError("operands could not be broadcast"), LookupError("x"),
                RuntimeError("y"), TypeError("z")):
        assert "bug" in readable_error(exc), exc
    assert readable_error(PlanError("z-max must be > z-min")) == "z-max must be > z-min"
    assert readable_error(InputError("frames 'x': give a number")) == \
        "frames 'x': give a number"


def test_library_messages_read_in_the_guis_terms():
    from gui.messages import operator_text

    assert operator_text("stage: stopped answering. Fix: check cable and power, then call "
                         "reconnect()") == ("stage: stopped answering. Fix: check cable and "
                                            "power, then press Reconnect on the device "
                                            "(Devices panel)")
    assert operator_text("led_array: simulated disconnection (faults.disconnect()). Fix: "
                         "call faults.allow_reconnect(), then reconnect()") == (
        "led_array: simulated disconnection. Fix: press Reconnect on the device "
        "(Devices panel)")
    assert operator_text("paused; resume() to continue, abort() to stop") == \
        "paused; press Continue to go on or Abort to stop"
    assert operator_text("use -inf <= x <= 60") == "use x <= 60"
    assert operator_text("use a finite number with 0 < exposure_s <= inf") == \
        "use a finite number with exposure_s > 0"
    assert operator_text("a stack needs --depth (mm)", {"--depth": "depth (mm)"}) == \
        "a stack needs 'depth (mm)' (mm)"
    assert operator_text("give --z-min") == "give 'z min'"
    assert "diffuserlab" not in operator_text("run `diffuserlab calibrate resume X`")


def test_the_dark_field_says_what_empty_means_on_the_virtual_bench(window):
    assert "simulated camera's offset" in window.live.dark.placeholderText()


def test_status_fields_leave_driver_setups_to_the_log():
    from gui.device_status import status_fields

    status = {"is_open": True, "positions": {"x": 1.0},
              "axes_setup": {"x": {"profile": "kdc101", "counts_per_unit": 34554.96}},
              "controllers": {"sn:27000001": {"port": "/dev/ttyUSB0", "model": "KDC101"}},
              "warnings": {"x": [], "y": ["FQ"]}, "dropped_frames": 0}
    fields = dict(status_fields("stage", status))
    assert "axes setup" not in fields and "controllers" not in fields
    assert fields["warnings"] == "y FQ" and fields["dropped frames"] == "0"
    status["warnings"] = {"x": [], "y": []}
    assert dict(status_fields("stage", status))["warnings"] == "none"


def test_exposure_fields_take_units():
    from gui.device_settings import parse_duration_s, parse_value, value_text
    from gui.workers import InputError

    for text, seconds in (("20 ms", 0.02), ("20ms", 0.02), ("0.02 s", 0.02), ("0.02", 0.02),
                          ("500 us", 5e-4), ("500 µs", 5e-4), ("1e-3 s", 1e-3)):
        assert parse_duration_s(text) == pytest.approx(seconds), text
    assert parse_duration_s("  ") is None
    with pytest.raises(InputError, match="20 ms"):
        parse_duration_s("20 parsecs")
    assert parse_value("20 ms", "exposure_s") == pytest.approx(0.02)
    assert parse_value('{"x": 1}', "velocity") == {"x": 1}
    assert value_text(0.02, "exposure_s") == "20 ms" and value_text(2.5, "exposure_s") == "2.5 s"


# -- 3. Results never reads a store on the GUI thread ----------------------------------------


def _video_run(path, n=40, image=lambda i: np.full((64, 80), i, np.uint16)):
    from instrument.runs.runstore import RunStore

    store = RunStore.create(path, plan_name="video", plan_params={},
                            points=[{"t": float(k)} for k in range(n)],
                            frame_tags=[["frame"]] * n, frame_shape=(64, 80),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    for i in range(n):
        store.write_frame(i, image(i), {"exposure_s": 0.01})
    store.update_attrs(status="complete")
    return store


def test_results_reads_the_store_on_workers_and_verifies_once(qapp, wait, tmp_path,
                                                             monkeypatch):
    from gui.panels.results import ResultsPanel
    from instrument.runs.runstore import RunStore

    _video_run(tmp_path / "v.zarr")
    calls: list[tuple[str, str]] = []
    frames_read: list[int] = []
    # the read of frame 1 is held until the slider has been dragged to the end, so the
    # steps made meanwhile must be skipped whatever the machine's speed (an unheld read
    # may finish between two steps on a quiet machine and nothing would be skipped)
    dragged = threading.Event()
    for name in ("frame", "done", "summary", "verify", "_read", "product", "refresh",
                 "product_info"):
        original = getattr(RunStore, name)

        def spy(self, *a, _name=name, _original=original, **k):
            calls.append((_name, threading.current_thread().name))
            if _name == "frame":
                frames_read.append(int(a[0]))
                if a[0] == 1:
                    assert dragged.wait(30), "the test never released the held read"
            return _original(self, *a, **k)

        monkeypatch.setattr(RunStore, name, spy)
    panel = ResultsPanel()
    panel.show()
    job = panel.open(str(tmp_path / "v.zarr"))
    wait(lambda: job.done and panel.problems is not None, 30, "the run and its check")
    for step in range(1, 30):  # the slider dragged across the run
        panel.frame_slider.setValue(step)
        qapp.processEvents()
    dragged.set()
    wait(lambda: panel.frame_shown == 29, 30, "the last frame asked for")
    main = threading.main_thread().name
    assert calls and all(thread != main for _, thread in calls), \
        [c for c in calls if c[1] == main][:5]
    assert sum(1 for n, _ in calls if n == "verify") == 1
    assert panel.problems == [] and "intact" in panel.verify_label.text()
    assert panel.view.image[0, 0] == 29
    # frame 0 on opening, frame 1 (held), then only the newest asked for: 2..28 skipped
    assert frames_read == [0, 1, 29], frames_read
    # the newest frame's levels, whatever the stepping skipped, and its coordinates
    # beside the slider; the run's summary text is not rewritten on every step
    wait(lambda: not panel.view._catch_up.isActive(), 2.0, "the levels to follow")
    lo, hi = panel.view.levels()
    assert lo <= 29 <= hi
    assert panel.frame_info.text().startswith("frame index 29")
    assert panel.text.toPlainText() == panel.summary_text
    panel.deleteLater()


def test_results_verification_reports_damage(qapp, wait, tmp_path):
    from gui.panels.results import ResultsPanel

    _video_run(tmp_path / "v.zarr")
    (tmp_path / "v.zarr/frames/c/5/0/0").unlink()
    panel = ResultsPanel()
    job = panel.open(str(tmp_path / "v.zarr"))
    wait(lambda: job.done and panel.problems is not None, 30, "the check")
    assert len(panel.problems) == 1 and "frame 5" in panel.problems[0]
    assert "1 problem" in panel.verify_label.text()
    assert "frame 5" in panel.text.toPlainText()


# -- 6. refused inputs say so, and nothing pretends to have started ---------------------------


def test_batch_without_a_psf_says_to_give_one(window, wait, tmp_path):
    _video_run(tmp_path / "v.zarr")
    panel = window.record
    panel.run_path.setText(str(tmp_path / "v.zarr"))
    panel.batch_fields["--psf"].setText("")
    job = panel.start_batch()
    wait(lambda: job.done, 30, "the refusal")
    text = panel.batch_error.text()
    assert "give the PSF" in text and "bug" not in text and "TypeError" not in text


def test_batch_runs_in_a_child_process_not_in_the_guis(window, wait, tmp_path, monkeypatch):
    """dask's scheduler and client never live in the GUI's process (each batch there kept
    ~230 references to None and threads): the batch runs in a child process, so the
    GUI's own ``reconstruct_run`` is never called, and the frames are stored."""
    import instrument.processing.batch
    from instrument.runs.runstore import RunStore

    def in_the_gui(*args, **kwargs):
        raise AssertionError("the batch ran in the GUI's process")

    monkeypatch.setattr(instrument.processing.batch, "reconstruct_run", in_the_gui)
    rng = np.random.default_rng(0)  # frames with structure (a constant frame is refused)
    _video_run(tmp_path / "v.zarr", n=2,
               image=lambda i: rng.integers(100, 4000, (64, 80)).astype(np.uint16))
    psf = np.zeros((64, 80), np.float32)
    psf[30:34, 38:42] = 100.0
    np.save(tmp_path / "psf.npy", psf)
    panel = window.record
    panel.run_path.setText(str(tmp_path / "v.zarr"))
    fields = panel.batch_fields
    for flag, text in (("--psf", str(tmp_path / "psf.npy")), ("--frames", "0:2"),
                       ("--workers", "1"), ("--dark", "0")):
        fields[flag].setText(text)
    fields["--method"].setCurrentText("wiener")
    job = panel.start_batch()
    wait(lambda: job.done, 120, "the batch reconstruction")
    assert panel.batch_result is not None, panel.batch_error.text()
    assert panel.batch_result["reconstructed"] == 2
    assert RunStore.open(tmp_path / "v.zarr").product_frames_done("recon_wiener").sum() == 2


def test_live_reconstruction_without_a_psf_says_to_give_one(window, wait):
    live = window.live
    live.psf.setText("")
    live.depth.setEditText("")
    job = live.start_reconstruction()
    wait(lambda: job.done, 30, "the refusal")
    assert "give the PSF" in live.error.text() and "No run store at ." not in live.error.text()
    assert live.live is None


def test_a_refused_recording_neither_says_recording_nor_becomes_the_last(window, wait,
                                                                         tmp_path):
    panel = window.record
    last = panel.last_run
    (tmp_path / "taken.zarr").mkdir()  # an existing folder: the run cannot be created
    panel.out.setText(str(tmp_path / "taken.zarr"))
    panel.frames.setText("5")
    job = panel.start_recording()
    wait(lambda: job.done, 30, "the refusal")
    assert panel.last_run == last
    assert "recording into" not in panel.counters.text()
    assert "not started" in panel.record_error.text()
    assert window.session.camera_user is None
    panel.out.setText("")


# -- 7. stage jogs add to the target; the wheel needs the focus; Enter moves ------------------


def test_quick_jog_clicks_add_to_the_target_not_the_position(window, wait):
    box = window.devices.boxes["source_stage"]
    service = window.session.service
    service.apply_settings("source_stage", {"velocity": {"x": 2.0, "y": 2.0, "z": 2.0}})
    try:  # 0.5 s per mm
        x0 = service.positions("source_stage")["x"]
        box.stage.jog_steps["x"].setValue(1.0)
        plus = box.findChild(type(box.reconnect_button), "source_stage.jog.x+")
        for _ in range(3):
            QTest.mouseClick(plus, Qt.MouseButton.LeftButton)
            QTest.qWait(60)  # mid-move
        wait(lambda: not box.queue.busy, 20, "the jogs")
        assert service.positions("source_stage")["x"] == pytest.approx(x0 + 3.0, abs=1e-6)
    finally:
        service.apply_settings("source_stage", {"velocity": dict.fromkeys("xyz", 50.0)})
        service.move("source_stage", {"x": 0.0})


def test_jobs_that_wait_on_hardware_run_at_the_process_priority(window, wait, monkeypatch):
    """A device's reply timeout counts wall time: its jobs (moves, device commands and
    polls, the bench's opening, streaming, recording, calibration, alignment) are not
    lowered, as compute jobs are (the emulated day beside three busy loops failed to
    open the bench: a Zaber reply past the 1 s timeout)."""
    import os

    import instrument.acquisition.live
    from gui.workers import BACKGROUND_NICE, Job

    ran: dict[str, int] = {}
    lower = instrument.acquisition.live.lower_thread_priority

    def recording(increment):
        changed = lower(increment)
        ran[threading.current_thread().name] = os.getpriority(os.PRIO_PROCESS,
                                                              threading.get_native_id())
        return changed

    monkeypatch.setattr(instrument.acquisition.live, "lower_thread_priority", recording)
    process = os.getpriority(os.PRIO_PROCESS, os.getpid())
    box = window.devices.boxes["source_stage"]
    box.stage.jog_steps["x"].setValue(0.5)
    QTest.mouseClick(box.findChild(type(box.reconnect_button), "source_stage.jog.x+"),
                     Qt.MouseButton.LeftButton)
    wait(lambda: not box.queue.busy, 20, "the jog")
    window.session.service.move("source_stage", {"x": 0.0})
    compute = Job(lambda job: None, name="compute").start()
    wait(lambda: compute.done and "motion-source_stage" in ran, 20, "the jobs")
    assert ran["motion-source_stage"] == process
    assert ran["compute"] == min(19, process + BACKGROUND_NICE)


def test_the_wheel_changes_a_jog_step_only_when_it_has_the_focus(window):
    box = window.devices.boxes["source_stage"]
    step = box.stage.jog_steps["x"]
    step.setValue(1.0)
    step.clearFocus()

    def wheel() -> None:
        centre = QPointF(step.width() / 2, step.height() / 2)
        event = QWheelEvent(centre, QPointF(step.mapToGlobal(centre.toPoint())), QPoint(0, 0),
                            QPoint(0, -120 * 5), Qt.MouseButton.NoButton,
                            Qt.KeyboardModifier.NoModifier, Qt.ScrollPhase.NoScrollPhase,
                            False)
        from PySide6.QtWidgets import QApplication

        QApplication.sendEvent(step, event)

    wheel()
    assert step.value() == 1.0
    window.activateWindow()  # focus is given once the window is active (later under load)
    step.setFocus()
    from PySide6.QtWidgets import QApplication as _App

    from tests.gui.conftest import wait_for

    wait_for(_App.instance(), step.hasFocus, 10, "the jog step's focus")
    wheel()
    assert step.value() != 1.0
    step.setValue(1.0)


def test_the_wheel_over_the_led_map_scrolls_the_devices_panel(window, qapp):
    """Scrolling the Devices panel over the LED map scrolled nothing and zoomed the map
    out (to "y (kmm)"); the map zooms only once it was clicked."""
    from PySide6.QtWidgets import QApplication

    panel = window.devices
    box = panel.boxes["led_array"]
    plot = box.led_plot
    port = plot.viewport()
    bar = panel.area.verticalScrollBar()
    for _ in range(50):  # the panel laid out (the map's size settles)
        qapp.processEvents()
    panel.area.ensureWidgetVisible(plot, 0, 0)
    bar.setValue(min(bar.value(), bar.maximum() - 50))
    qapp.processEvents()
    plot.clearFocus()
    view = plot.getViewBox()
    view.disableAutoRange()
    ranges = view.viewRange()
    before = bar.value()

    def wheel() -> None:
        centre = QPointF(port.width() / 2, port.height() / 2)
        QApplication.sendEvent(port, QWheelEvent(
            centre, QPointF(port.mapToGlobal(centre.toPoint())), QPoint(0, 0),
            QPoint(0, -120 * 3), Qt.MouseButton.NoButton, Qt.KeyboardModifier.NoModifier,
            Qt.ScrollPhase.NoScrollPhase, False))
        qapp.processEvents()

    wheel()
    assert view.viewRange() == ranges  # no zoom
    assert bar.value() > before  # the panel scrolled
    window.activateWindow()  # focus is given once the window is active (later under load)
    plot.setFocus()
    from tests.gui.conftest import wait_for

    wait_for(qapp, plot.hasFocus, 10, "the map's focus")
    wheel()
    assert view.viewRange() != ranges  # clicked (focused): the wheel zooms the map
    view.autoRange()


def test_enter_in_a_go_to_field_moves(window, wait):
    box = window.devices.boxes["source_stage"]
    field = box.stage.targets["z"]
    field.setText("42")
    QTest.keyClick(field, Qt.Key.Key_Return)
    wait(lambda: not box.queue.busy, 10, "the move")
    assert window.session.service.positions("source_stage")["z"] == pytest.approx(42.0)


# -- 8. numbers that follow what happens now --------------------------------------------------


def test_camera_fps_follows_a_change_of_rate_within_seconds(monkeypatch):
    """The rate shown is the last 2 s's (a rate since the stream started showed 11 fps
    while the camera delivered 30). The clock is the test's: frames arrive at 30 fps
    for 4 s, then at 3 fps for 3 s, and the GUI's 10 Hz poll reads the rate; a host's
    load cannot change what is delivered when (it did: 6 fps where 30 were asked)."""
    import gui.session as gui_session

    now = [1000.0]
    monkeypatch.setattr(gui_session.time, "monotonic", lambda: now[0])
    session = gui_session.Session(None, simulate=True, scene="none")
    session._streaming = True  # what start_stream sets; the frames are the test's

    def deliver(fps: float, seconds: float) -> float:
        shown, due = 0.0, 0.0
        for _ in range(round(seconds * 10)):  # the GUI's 100 ms poll
            now[0] += 0.1
            due += fps * 0.1
            while due >= 1.0:
                session.frames_seen += 1
                due -= 1.0
            shown = session.stream_counters()["fps"]
        return shown

    fast = deliver(30.0, 4.0)
    slow = deliver(3.0, 3.0)
    assert fast == pytest.approx(30.0, rel=0.1), (fast, slow)
    assert slow == pytest.approx(3.0, rel=0.2), (fast, slow)  # since the start: 18


def test_camera_fps_is_shown_while_streaming(window, wait):
    """The streaming window shows the rate of the frames it received (waited for: a
    loaded host delivers fewer and later frames than asked)."""
    session = window.session
    session.start_stream()
    try:
        wait(lambda: session.frames_seen >= 3 and session.stream_counters()["fps"] > 0,
             60, "a rate shown for the frames received")
    finally:
        session.stop_stream()
    assert session.stream_counters().get("fps", 0.0) == 0.0  # stopped: no rate


def test_job_progress_ticks_between_reports():
    from gui.panels.common import JobProgress

    p = JobProgress("frames")
    p.start(10)
    p.report(2, 10, eta_s=100.0)
    first, text = p.eta_s(), p.label.text()
    QTest.qWait(2200)
    assert "elapsed" in p.label.text() and "ETA" in p.label.text()
    assert p.eta_s() < first - 2.0  # counted down without a new report
    assert p.label.text() != text  # and shown so
    p.report(5, 10)  # no estimate given: from the rate so far
    assert p.eta_s() == pytest.approx(p.elapsed_s(), rel=0.2)
    p.finish()
    assert not p.timer.isActive()


def test_one_alignment_step_shows_running_at_a_time(window):
    panel = window.alignment
    for label in panel.step_labels.values():
        label.setText("waiting")
    panel.on_progress({"kind": "reading", "eta": 0.1, "pose": {}, "step": "coarse"})
    panel.on_progress({"kind": "reading", "eta": 0.1, "pose": {}, "step": "translation"})
    panel.on_progress({"kind": "event", "step": "focus_check", "message": "checking",
                       "done": ["preflight"], "steps": {}})
    running = [n for n, lab in panel.step_labels.items() if lab.text() == "running"]
    assert running == ["focus"]
    assert panel.step_labels["coarse"].text() == "done"


def test_reconstruction_stats_say_when_no_result_arrives(window, wait):
    live = window.live
    live.live = _FrozenLive()
    try:
        live._recon_count = (-1, time.monotonic(), live.session.frames_seen)
        live._show_live_stats()
        assert "fps" in live.recon_stats.text()
        live._recon_count = (5, time.monotonic() - 10, live.session.frames_seen)
        live._show_live_stats()
        assert "no new result for 10 s" in live.recon_stats.text()
    finally:
        live.live = None


class _FrozenLive:
    def stats(self):
        return {"reconstructed": 5, "skipped": 0, "errors": 0, "last_error": None,
                "method": "wiener", "iterations": 1, "fps": 30.0, "latency_median_s": 0.01}


# -- a job's end: released on the GUI thread, no cycle left behind -----------------------------


def test_finished_jobs_are_released_on_the_gui_thread(qapp, wait):
    """A job whose closures hold the job itself (a cycle through Qt the collector cannot
    see) is freed, and on the GUI thread: the window crashed (SIGSEGV in the event
    loop) when a job's last reference went on its worker thread."""
    import gc
    import weakref

    from gui.workers import _LIVE_JOBS, Job

    freed_on: list[str] = []
    refs = []
    for i in range(30):
        job = Job(lambda job, i=i: i, name=f"t{i}")
        job.succeeded.connect(lambda r, job=job: job.name)  # the job in its own slot
        weakref.finalize(job, lambda: freed_on.append(threading.current_thread().name))
        refs.append(weakref.ref(job))
        job.start()
        del job
    wait(lambda: not _LIVE_JOBS, 20, "the jobs to be released")
    qapp.processEvents()
    gc.collect()
    assert all(r() is None for r in refs)
    assert freed_on and set(freed_on) == {threading.main_thread().name}


def test_starting_a_job_never_waits_for_a_thread_on_the_gui_thread(qapp, wait, monkeypatch):
    """``Thread.start`` waits until the new thread has run its first step; on a loaded
    machine that held the event loop up to 5 s in the operator's day (the GUI thread in
    ``threading.Thread.start``). Jobs are started by the launcher thread instead."""
    from gui.workers import Job

    first = Job(lambda job: None, name="first").start()  # the launcher is up
    wait(lambda: first.done, 20, "the first job")
    starters: list[str] = []
    start = threading.Thread.start

    def recording_start(self):
        starters.append(threading.current_thread().name)
        return start(self)

    monkeypatch.setattr(threading.Thread, "start", recording_start)
    gate = threading.Event()
    jobs = [Job(lambda job: gate.wait(10), name=f"gated{i}").start() for i in range(5)]
    assert all(j.running for j in jobs)  # running from start(), before its thread runs
    gate.set()
    wait(lambda: all(j.done for j in jobs), 20, "the gated jobs")
    assert not any(j.running for j in jobs)
    assert starters and threading.main_thread().name not in starters, starters
