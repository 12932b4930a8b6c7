"""The window asks before it cuts a job short and then finishes it (the recording's run
summarised, its lock released, before the devices close); every run gives the bench
back as it was (camera settings, stage positions, LEDs, the live stream)."""

from __future__ import annotations

import pytest


@pytest.fixture
def own_window(qapp, tmp_path, monkeypatch):
    """A window of its own (it is closed by the test)."""
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    from gui.app import MainWindow
    from gui.session import Session
    from tests.gui.conftest import wait_for

    w = MainWindow(Session(None, simulate=True, scene="none"))
    w.show()
    w.session.connect_bench()
    wait_for(qapp, lambda: w.session.connected, 120.0, "the bench to open")
    yield w
    if w.session.connected:
        w.shutdown()
    w.deleteLater()
    qapp.processEvents()


def test_closing_mid_recording_asks_then_finishes_the_run(own_window, wait, tmp_path):
    from instrument.runs.runstore import RunStore

    w = own_window
    asked: list[str] = []
    answers = [False, True]
    w.confirm = lambda title, text: (asked.append(text), answers.pop(0))[1]
    rec = w.record
    path = str(tmp_path / "long.zarr")
    rec.out.setText(path)
    rec.frames.setText("3000")
    job = rec.start_recording()
    wait(lambda: rec.record_progress.value() >= 5, 60, "frames written")
    w.close()  # answered No: nothing stops
    assert asked and "video recording" in asked[0]
    wait(lambda: rec.record_progress.value() >= 15, 30, "more frames")
    assert w.isVisible() and rec.recording and w.session.connected
    w.close()  # answered Yes: the recording stops and is finished, then the devices close
    wait(lambda: not w.isVisible(), 60, "the window to close")
    assert job.done and not w.session.connected
    store = RunStore.open(path)
    assert store.status == "stopped"
    assert store.lock_owner() is None  # no stale lock
    assert 15 <= store.summary(verify=False)["frames_done"] < 3000
    assert store.summary()["problems"] == []


def test_closing_with_nothing_running_does_not_ask(own_window, wait):
    w = own_window
    w.confirm = lambda title, text: pytest.fail(f"asked: {text}")
    w.close()
    wait(lambda: not w.isVisible(), 30, "the window to close")
    assert not w.session.connected


def test_runs_give_the_bench_back_and_the_stream_resumes(own_window, wait, tmp_path):
    """Dark, PSF sweep and an aborted alignment each leave the camera's exposure, the
    stages, the LEDs and the live stream as they were (they used to leave the run's
    auto-exposure, the sweep's last stage point and the stream stopped)."""
    w = own_window
    service, devices = w.session.service, w.session.devices
    for name in ("source_stage", "mask_stage"):
        service.apply_settings(name, {"velocity": dict.fromkeys(devices[name].axes, 50.0)})
    service.apply_settings("camera", {"exposure_s": 0.012})
    service.move("source_stage", {"x": 1.0, "z": 40.0})
    centre = int(abs(devices["led_array"].led_positions_mm).sum(axis=1).argmin())
    service.apply_settings("led_array", {"colour": "white", "brightness": 0.5})
    lit = service.show("led_array", [centre])
    w.session.start_stream()
    before = (service.settings("camera"), service.positions("source_stage"),
              mask := service.positions("mask_stage"))

    def check(what: str) -> None:
        wait(lambda: w.session.streaming, 15, f"the stream to resume after {what}")
        assert service.settings("camera") == before[0], what
        assert service.positions("source_stage") == pytest.approx(before[1], abs=1e-6), what
        assert service.positions("mask_stage") == pytest.approx(mask, abs=1e-6), what
        assert service.lit("led_array") == lit, what
        w.live.refresh()
        assert "busy" not in w.live.raw_stats.text(), what

    cal = w.calibration
    for routine, values in (("dark", {"--frames": "2"}),
                            ("psf-sweep", {"--z-min": "30", "--z-max": "60",
                                           "--n-depths": "2", "--frames": "1"})):
        cal.routine.setCurrentText(routine)
        for flag, value in values.items():
            cal.fields[routine][flag].setText(value)
        cal.out.setText(str(tmp_path / f"{routine}.zarr"))
        job = cal.start()
        assert job is not None, cal.status.text()
        wait(lambda j=job: j.done, 180, routine)
        assert cal.result is not None and cal.result.status == "complete", cal.status.text()
        check(routine)
    al = w.alignment
    al.out.setText(str(tmp_path / "mask.align"))
    al.frames.setValue(1)
    al.focus.setChecked(False)
    job = al.start()
    wait(lambda: len(al.readings) >= 3 or job.done, 300, "spot readings")
    al.abort()
    wait(lambda: job.done, 120, "the alignment to stop")
    check("the alignment")


def test_a_job_that_takes_the_camera_while_the_stream_comes_back_gives_it_back(own_window,
                                                                                wait,
                                                                                monkeypatch):
    """A run that ends asks for the live stream back, and the next run (a Resume pressed
    at once) takes the camera before the stream has started: that run still gives the
    stream back when it ends. It used to read "not streaming" and leave the stream off
    (run A2's operator day: "the stream to resume after the sweep" never came), with a
    window message that the stream could not start because the camera was busy."""
    import threading

    from gui import workers

    session = own_window.session
    said: list[str] = []
    session.message.connect(said.append)
    session.start_stream()
    stream_jobs: list = []  # every stream start, to see each one's end
    real_job_start = workers.Job.start
    monkeypatch.setattr(workers.Job, "start", lambda job: (
        stream_jobs.append(job) if job.name == "stream-on" else None, real_job_start(job))[1])
    gate, tried = threading.Event(), threading.Event()
    real_start = session.start_stream

    def held_start(*args, **kwargs):
        gate.wait(60)  # the resumed stream starts only once the next run holds the camera
        try:
            return real_start(*args, **kwargs)
        finally:
            tried.set()

    session.start_stream = held_start
    with session.camera_claimed("the first run"):
        pass  # it ends: the stream is asked back (its start waits on the gate)
    assert not session.streaming
    with session.camera_claimed("the next run"):
        gate.set()
        wait(tried.is_set, 60, "the stream's start to be tried")
        assert not session.streaming  # refused: the next run holds the camera
    wait(lambda: session.streaming, 15, "the stream to come back after the next run")
    # the refused start's job has ended, its signals handled: it was not a failure
    wait(lambda: len(stream_jobs) == 2 and all(j.done for j in stream_jobs), 15,
         "both stream starts to end")
    assert not [s for s in said if "could not start again" in s], said
