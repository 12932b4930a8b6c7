"""Jobs of the bench process held from any client: a notebook starts a recording, the
window follows and stops it, a client that disconnects leaves its job running."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from instrument.bench.bench_host import BenchHostError
from instrument.bench.bench_job_handle import without_arrays
from instrument.bench.bench_process import BenchClient
from instrument.bench.bench_service import BenchServiceError
from instrument.runs.runstore import RunStore

from .test_bench_process import OPEN, opened_bench
from .test_bench_service import HANG_S, Events


def fails(ctx, *, message: str) -> None:
    """A job that reports once (with a frame, as a calibration run does) and fails."""
    ctx.report({"step": "about to fail", "frame": np.zeros((4, 4))})
    raise ValueError(message)


def reports(ctx, *, n: int) -> int:
    """A job that reports ``n`` progress values, each with a frame (as a calibration
    run's frame events), then one without (as its point events), then waits to be
    stopped; returns ``n``."""
    for k in range(n):
        ctx.report({"k": k, "frame": np.full((4, 4), k, dtype=np.float32)})
    ctx.report({"k": n})
    ctx.stop.wait()
    return n


def recording(out, frames: int = 5000) -> dict:
    """The ``record`` job's parameters (a long recording, ended by a stop)."""
    return {"out": str(out), "frames": frames, "seconds": None, "options": {},
            "simulated": None}


def recorded(event) -> bool:
    return event.kind == "progress" and event.data["recorded"] > 0


@pytest.fixture
def window():
    """The window's client: it started the bench process and opened the simulated
    bench; its ``events`` are what it was pushed."""
    events = Events()
    with opened_bench(jobs={"fails": fails, "reports": reports}, on_event=events) as client:
        client.events = events
        client.camera_id = next(d.name for d in client.devices() if d.kind == "camera")
        yield client


def test_a_recording_a_notebook_started_is_followed_and_stopped_by_the_window(
        window, tmp_path):
    notebook = BenchClient(address=window.address, authkey=window.authkey)
    try:
        out = tmp_path / "v.zarr"
        job = notebook.start_job("record", recording(out))
        assert job.name == "record" and job.params["frames"] == 5000
        # the window is told a job started, and holds it by its id
        told = window.events.wait(lambda e: e.kind == "job" and e.data["id"] == job.id,
                                  "of the notebook's job starting")
        assert told.data == {"id": job.id, "name": "record", "state": "running",
                             "owner": notebook.name, "holds": [window.camera_id],
                             "run": str(out)}
        held = window.job(job.id)
        assert [i.state for i in window.jobs() if i.id == job.id] == ["running"]
        # both clients see the recording's progress
        for handle in (job, held):
            assert handle.wait_for(recorded, HANG_S).data["recorded"] > 0
        held.stop()  # the window stops what the notebook started
        summary = job.result(HANG_S)
        assert held.result(HANG_S) == summary
        assert summary["status"] == "stopped" and Path(summary["path"]) == out
        assert job.state == held.state == "done"
        window.events.wait(lambda e: e.kind == "job" and e.data["id"] == job.id
                           and e.data["state"] == "done", "of the notebook's job ending")
    finally:
        notebook.close()
    # the bench process closed the run properly: stopped, every frame readable, unlocked
    store = RunStore.open(out)
    assert store.status == "stopped" and store.lock_owner() is None
    assert store.done().sum() == summary["recorded"] > 0 and store.verify() == []


def test_a_job_runs_on_when_the_client_that_started_it_disconnects(window, tmp_path):
    out = tmp_path / "v.zarr"
    notebook = BenchClient(address=window.address, authkey=window.authkey)
    job = notebook.start_job("record", recording(out))
    last = job.wait_for(recorded, HANG_S).data["recorded"]
    notebook.close()
    # still recording after the notebook left: the window sees frames it could not
    held = window.job(job.id)
    later = held.wait_for(lambda e: recorded(e) and e.data["recorded"] > last, HANG_S)
    assert held.state == "running" and later.data["recorded"] > last
    # the window closes: the bench process ends the recording and closes its run
    window.close()
    store = RunStore.open(out)
    assert store.status == "stopped" and store.lock_owner() is None
    assert store.done().sum() > last and store.verify() == []


@pytest.mark.parametrize("in_process", [False, True], ids=["child-process", "in-process"])
def test_a_failed_job_raises_its_error_for_every_client(in_process):
    with opened_bench(in_process=in_process, jobs={"fails": fails}) as client:
        job = client.start_job("fails", {"message": "the fault"})
        first = job.wait_for(lambda e: True, HANG_S)  # its frame not kept in the log
        assert first.kind == "progress" and first.data == {"step": "about to fail"}
        with pytest.raises(ValueError, match="the fault"):
            job.result(HANG_S)
        assert job.ended and job.state == "failed"
        # a handle taken after the end reads the job from its first event kept
        late = client.job(job.id)
        assert [e.kind for e in late.events(HANG_S)] == ["progress", "failed"]
        with pytest.raises(BenchHostError, match="no job 'nope'"):
            client.start_job("nope")
        with pytest.raises(BenchServiceError, match="no job 12345"):
            client.job(12345)


def test_a_second_client_runs_a_job_to_its_end_but_not_the_bench_s_opening(window):
    notebook = BenchClient(address=window.address, authkey=window.authkey)
    try:
        reported: list = []
        with pytest.raises(ValueError, match="the fault"):
            notebook.run_job("fails", {"message": "the fault"}, report=reported.append)
        assert reported == [{"step": "about to fail"}]
        for name in ("open_bench", "close_bench"):
            with pytest.raises(BenchHostError, match="client that started the bench"):
                notebook.start_job(name, OPEN if name == "open_bench" else {})
        assert window.devices()  # the bench is still open
    finally:
        notebook.close()


def test_a_job_the_window_runs_is_stopped_by_a_notebook(window, tmp_path):
    import threading

    seen = Events()
    notebook = BenchClient(address=window.address, authkey=window.authkey, on_event=seen)
    try:
        ran: dict = {}
        progress: list = []

        def run() -> None:  # the window's blocking run, as gui.jobs records
            ran["summary"] = window.run_job("record", recording(tmp_path / "v.zarr"),
                                            report=progress.append)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        told = seen.wait(lambda e: e.kind == "job" and e.data["name"] == "record",
                         "of the window's recording starting")
        job = notebook.job(told.data["id"])
        job.wait_for(recorded, HANG_S)
        job.stop()
        thread.join(HANG_S)
        assert not thread.is_alive()
        assert ran["summary"]["status"] == "stopped" and progress
        assert job.result(HANG_S) == ran["summary"]
    finally:
        notebook.close()


def test_progress_in_the_log_leaves_arrays_out():
    from instrument.acquisition.runner import RunEvent

    event = RunEvent("frame", "run.zarr", 0, 1, 2, 1, 2, 0.5, None,
                     last_frame=np.ones((2, 2)))
    event.tag = "psf"  # set by the calibration job: kept
    kept = without_arrays(event)
    assert kept.last_frame is None and kept.tag == "psf" and kept.frames_done == 1
    assert event.last_frame is not None  # the window's own is not touched
    assert without_arrays({"n": 1, "image": np.ones(3)}) == {"n": 1}
    assert without_arrays("text") == "text"


def test_every_client_reads_a_job_s_events_by_one_route(window):
    """The window (the client that started the bench process) follows the job it runs
    by the job's log, as a notebook in another process does: the same events by the
    same sequence numbers, in the same order (issue 66: the window's came down its own
    pipe, a second route). Only the window asks for the frames: the newest progress
    with a frame it read carries it (also when a progress without one came after), the
    notebook's none."""
    import threading

    from .bench_clients import OtherClient, follow, stop_by_id

    read: list = []  # the job's events as the window's client read them
    host_read = window.host.job_events_after

    def spy(*args):
        got = host_read(*args)
        read.extend(got[1])
        return got

    window.host.job_events_after = spy
    notebook = OtherClient(window.address, window.authkey)
    try:
        progress = Events()
        got: list = []

        def report(value) -> None:
            got.append(value)
            progress(value)

        ran: dict = {}
        thread = threading.Thread(target=lambda: ran.update(
            n=window.run_job("reports", {"n": 5}, report=report)), daemon=True)
        thread.start()
        progress.wait(lambda v: v["k"] == 5, "of the job's last progress")
        job_id = next(j.id for j in window.jobs() if j.name == "reports")
        notebook.value(stop_by_id, job_id)
        thread.join(HANG_S)
        assert not thread.is_alive() and ran["n"] == 5
        seen = notebook.value(follow, job_id)
        assert [(e.seq, e.kind, without_arrays(e.data)) for e in read] == seen
        assert [v["k"] for v in got] == [0, 1, 2, 3, 4, 5] == [
            d["k"] for _, kind, d in seen if kind == "progress"]
        assert seen[-1][1:] == ("done", 5)
        framed = [v for v in got if "frame" in v]
        assert framed and framed[-1]["k"] == 4, got
        assert np.array_equal(framed[-1]["frame"], np.full((4, 4), 4, dtype=np.float32))
        assert not any("frame" in d for _, kind, d in seen if kind == "progress")
    finally:
        notebook.close()
