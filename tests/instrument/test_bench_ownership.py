"""One bench, two clients at once, each in a process of its own (the window that started
the bench process here, a notebook in a spawned process): a job holds its devices, a
job that needs a held one is refused in one line naming the holder, and the refusal
never touches the holder's device; the window's live view yields the camera to a job
and takes it back."""

from __future__ import annotations

import queue
import re

import pytest

from instrument.bench.bench_host import BenchHostError
from instrument.runs.runstore import RunStore

from . import bench_clients as other
from .bench_clients import OtherClient
from .test_bench_job_handle import recorded, recording
from .test_bench_process import opened_bench
from .test_bench_service import HANG_S, Events


class Messages:
    """The window's ``on_message`` lines, waited on by what they say."""

    def __init__(self) -> None:
        self.queue: queue.SimpleQueue = queue.SimpleQueue()

    def __call__(self, text: str) -> None:
        self.queue.put(text)

    def wait(self, pattern: str) -> str:
        while True:
            try:
                text = self.queue.get(timeout=HANG_S)
            except queue.Empty:
                pytest.fail(f"no message like {pattern!r} within {HANG_S:.0f} s")
            if re.search(pattern, text):
                return text


class Frames:
    """The window's frames: how many came, and a wait for more."""

    def __init__(self) -> None:
        self.queue: queue.SimpleQueue = queue.SimpleQueue()

    def __call__(self, frame, meta) -> None:
        self.queue.put(meta["published"])

    def wait(self, n: int = 1) -> None:
        for _ in range(n):
            try:
                self.queue.get(timeout=HANG_S)
            except queue.Empty:
                pytest.fail(f"no frame within {HANG_S:.0f} s")

    def drain(self) -> None:
        while True:
            try:
                self.queue.get_nowait()
            except queue.Empty:
                return


@pytest.fixture
def window():
    """The window's client (named so), the simulated bench open, its frames, messages
    and events kept; and a notebook in a process of its own, connected to it."""
    messages, frames, events = Messages(), Frames(), Events()
    with opened_bench(name="the window", on_message=messages, on_frame=frames,
                      on_event=events) as client:
        client.messages, client.frames, client.events = messages, frames, events
        client.camera_id = next(d.name for d in client.devices() if d.kind == "camera")
        notebook = OtherClient(client.address, client.authkey)
        client.notebook = notebook
        try:
            yield client
        finally:
            notebook.close()


def test_a_notebook_s_record_is_refused_while_the_window_records_and_the_window_s_run_goes_on(
        window, tmp_path):
    job = window.start_job("record", recording(tmp_path / "window.zarr"))
    before = job.wait_for(recorded, HANG_S).data["recorded"]
    kind, text = window.notebook.call(other.start, "record",
                                      recording(tmp_path / "notebook.zarr"))
    # one line naming the device, the holding job and its owner
    assert kind == "error" and "\n" not in text
    assert f"camera is held by job {job.id} (record) of {window.name}" in text
    assert not (tmp_path / "notebook.zarr").exists()
    # the window's recording was not touched: it records on, then stops as asked
    job.wait_for(lambda e: recorded(e) and e.data["recorded"] > before + 5, HANG_S)
    job.stop()
    summary = job.result(HANG_S)
    assert summary["status"] == "stopped" and summary["recorded"] > before + 5
    store = RunStore.open(tmp_path / "window.zarr")
    assert store.status == "stopped" and store.lock_owner() is None


def test_the_window_s_record_is_refused_while_a_notebook_records(window, tmp_path):
    notebook = window.notebook
    job_id = notebook.value(other.start, "record", recording(tmp_path / "notebook.zarr"))
    before = notebook.value(other.wait_recorded, job_id, 0)
    with pytest.raises(BenchHostError, match=rf"camera is held by job {job_id} \(record\) of "
                                        rf"{re.escape(notebook.name)}"):
        window.start_job("record", recording(tmp_path / "window.zarr"))
    # the window presses Start stream meanwhile: the camera is not taken from the job
    window.start_stream(16)
    window.messages.wait(rf"held by job {job_id} \(record\).*starts when it ends")
    later = notebook.value(other.wait_recorded, job_id, before + 5)
    assert later > before + 5
    notebook.value(other.stop, job_id)
    summary = notebook.value(other.result, job_id)
    assert summary["status"] == "stopped"
    # the camera back: the live view the window asked for starts
    window.messages.wait(rf"camera is back from job {job_id}")
    window.frames.drain()
    window.frames.wait(3)
    window.stop_stream()


def test_the_live_view_yields_the_camera_to_a_notebook_s_recording_and_takes_it_back(
        window, tmp_path):
    window.start_stream(16)
    window.frames.wait(2)
    job_id = window.notebook.value(other.start, "record",
                                   {**recording(tmp_path / "notebook.zarr"), "frames": 12})
    said = window.messages.wait(r"live view: the camera was taken by")
    assert f"job {job_id} (record) of {window.notebook.name}" in said
    summary = window.notebook.value(other.result, job_id)
    assert summary["status"] == "complete" and summary["recorded"] == 12
    window.messages.wait(rf"camera is back from job {job_id}")
    # frames of the stream again, after the job's end
    window.frames.drain()
    window.frames.wait(3)
    assert window.holders()[window.camera_id]["name"] == "live stream"
    window.stop_stream()
    assert window.holders() == {}


def test_every_client_sees_every_job_with_its_owner_and_stops_it(window, tmp_path):
    job = window.start_job("record", recording(tmp_path / "window.zarr"))
    job.wait_for(recorded, HANG_S)
    listed = window.notebook.value(other.jobs)
    mine = [j for j in listed if j["id"] == job.id]
    assert mine == [{"id": job.id, "name": "record", "state": "running",
                     "owner": window.name, "holds": [window.camera_id]}]
    info = next(i for i in window.jobs() if i.id == job.id)
    assert info.progress["recorded"] > 0 and info.describe().endswith(window.name)
    window.notebook.value(other.stop_by_id, job.id)
    assert job.result(HANG_S)["status"] == "stopped"


def test_a_killed_bench_process_s_recording_is_closed_by_the_client_that_started_it(
        tmp_path):
    """SIGKILL under a notebook's recording: the window (which started the bench
    process) closes the run, interrupted, saying who and why, its frames kept and its
    lock gone; the window's own recording says so, naming no Connect button."""
    import os
    import signal

    events = Events()
    window = opened_bench(name="the window", on_event=events)
    client = window.__enter__()
    notebook = OtherClient(client.address, client.authkey)
    try:
        theirs = tmp_path / "notebook.zarr"
        job_id = notebook.value(other.start, "record", recording(theirs))
        notebook.value(other.wait_recorded, job_id, 2)
        process = client._manager._process
        bench_pid = process.pid
        assert RunStore.open(theirs).lock_owner()["pid"] == bench_pid
        # the window knows what the bench process writes (noted before it is told)
        events.wait(lambda e: e.kind == "job" and e.data["run"] == str(theirs),
                    "of the notebook's recording")
        assert str(theirs) in client.writing.values()
        os.kill(bench_pid, signal.SIGKILL)
        process.join(HANG_S)
    finally:
        window.__exit__(None, None, None)  # the window notices and closes its client
        notebook.close()
    store = RunStore.open(theirs)
    assert store.status == "interrupted" and store.lock_owner() is None
    closed = store.attrs["closed_by"]
    assert closed["by"] == client.name and f"pid {bench_pid}" in closed["why"]
    assert "SIGKILL" in closed["why"] and closed["frames_kept"] == store.done().sum() > 0


def test_the_window_s_own_recording_says_its_run_is_closed_when_the_bench_is_killed(
        tmp_path):
    import os
    import signal
    import threading

    events = Events()
    with opened_bench(name="the window", on_event=events) as client:
        out = tmp_path / "window.zarr"
        outcome: dict = {}
        progress = threading.Event()

        def run() -> None:
            try:
                client.run_job("record", recording(out), report=lambda p: progress.set())
            except Exception as exc:  # noqa: BLE001 (read below)
                outcome["error"] = str(exc)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        assert progress.wait(HANG_S)
        events.wait(lambda e: e.kind == "job" and e.data["run"] == str(out),
                    "of the window's recording")
        os.kill(client._manager._process.pid, signal.SIGKILL)
        thread.join(HANG_S)
    said = outcome["error"]
    assert f"its run {out} is closed (interrupted)" in said and "kept" in said
    assert "connect" not in said.lower()
    assert RunStore.open(out).status == "interrupted"


def optics(ctx) -> dict:
    """The virtual bench's optics: the camera capped, the diffuser and pinhole in."""
    return {k: ctx.bench.state[k]
            for k in ("camera_capped", "diffuser_installed", "pinhole_installed")}


def test_a_notebook_s_dark_run_aborted_from_the_window_uncaps_the_camera(tmp_path):
    from calibration_routines.bench_jobs import JOBS as CALIBRATION

    working = {"camera_capped": False, "diffuser_installed": True,
               "pinhole_installed": True}
    with opened_bench(name="the window", jobs={**CALIBRATION, "optics": optics}) as window:
        notebook = OtherClient(window.address, window.authkey)
        try:
            # long dark frames: the abort lands while the camera is capped
            job_id = notebook.value(other.start, "run_plan", {
                "routine": "dark", "values": {"--frames": "3", "--exposure-s": "1.0"},
                "path": str(tmp_path / "dark.zarr")})
            held = window.job(job_id)
            first = held.wait_for(lambda e: e.kind == "progress"
                                  and getattr(e.data, "kind", None) == "frame", HANG_S)
            assert first.data.point == 0 and window.run_job("optics")["camera_capped"]
            # the window's record is refused meanwhile: the run holds every device
            with pytest.raises(BenchHostError, match=rf"held by job {job_id} \(run_plan\)"):
                window.start_job("record", recording(tmp_path / "v.zarr"))
            held.abort("aborted from the window")
            put_back = held.wait_for(lambda e: e.kind == "progress"
                                     and getattr(e.data, "message", "") == "Uncap the camera",
                                     HANG_S)
            assert put_back.data.point is None  # the runner's put-back, not the flat point
            result = notebook.value(other.result, job_id)
            assert result.status == "aborted" and result.pending_actions == []
            assert window.run_job("optics") == working
        finally:
            notebook.close()
