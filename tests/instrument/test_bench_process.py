"""The bench host in a process of its own (and in this one): devices, stream, jobs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from contextlib import contextmanager

import pytest

from instrument.acquisition.runner import RunAborted, RunControl
from instrument.bench.bench_process import BenchClient

OPEN = {"bench_path": None, "simulate": True, "seed": 0, "scene": "none"}


# -- jobs the host runs in these tests (imported there by name) ---------------------------
def whose_process(ctx) -> dict:
    """Where the job runs, and whether the camera's grab thread is there."""
    return {"pid": os.getpid(), "threads": [t.name for t in threading.enumerate()]}


def counting(ctx, *, n: int) -> int:
    """Report 0..n-1, waiting for pause/abort between (a pause seen is reported as
    ``("paused", i)`` before the wait); returns n."""
    for i in range(n):
        if ctx.control.paused:
            ctx.report(("paused", i))
        ctx.control.wait_while_paused()
        ctx.report(i)
        time.sleep(0.05)
    return n


def until_stopped(ctx) -> str:
    """Wait for the client's stop or cancel event (at most 20 s)."""
    for _ in range(400):
        if ctx.stop.is_set():
            return "stopped"
        if ctx.cancel.is_set():
            return "cancelled"
        time.sleep(0.05)
    return "timed out"


def failing(ctx) -> None:
    from drivers.errors import StageLimitError

    raise StageLimitError("source_stage", "x=99 mm is outside 0..25 mm", "move within them")


#: The jobs of these tests, handed to the bench process by reference.
JOBS = {"whose_process": whose_process, "counting": counting,
        "until_stopped": until_stopped, "failing": failing}


@contextmanager
def opened_bench(**options):
    """A :class:`BenchClient` made with ``options``, the simulated bench open in it."""
    c = BenchClient(**options)
    try:
        c.run_job("open_bench", OPEN)
        yield c
    finally:
        c.close()


@pytest.fixture(params=[False, True], ids=["child-process", "in-process"])
def client(request):
    frames: list = []
    with opened_bench(in_process=request.param, jobs=JOBS,
                      on_frame=lambda f, m: frames.append((f, m))) as c:
        c.frames = frames
        yield c


def test_no_device_object_comes_to_the_client(client):
    """The client holds ids and values: commands return plain data, and in a child
    process no driver object exists here however the devices were used."""
    import gc

    from drivers.base import Device

    assert client.move("source_stage", {"x": 0.5})["x"] == pytest.approx(0.5)
    assert client.camera_format().image_shape == (256, 320)
    assert client.snap().image.dtype.name == "uint16"
    if not client.in_process:  # (closed ones may be left by in-process tests before)
        assert not [o for o in gc.get_objects() if isinstance(o, Device) and o.is_open]


def test_a_device_error_comes_back_with_its_type(client):
    from drivers.errors import StageLimitError
    from instrument.bench.bench_service import BenchServiceError

    with pytest.raises(StageLimitError):
        client.move("source_stage", {"x": 1e6})
    with pytest.raises(BenchServiceError, match="no_such_device"):
        client.positions("no_such_device")


def test_the_stream_runs_in_the_bench_process_and_its_frames_arrive_here(client):
    client.start_stream(16)
    try:
        deadline = time.monotonic() + 20
        while len(client.frames) < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        client.stop_stream(2.0)
    assert len(client.frames) >= 5
    indices = [f.index for f, _ in client.frames]
    assert indices == sorted(indices) and len(set(indices)) == len(indices)
    frame, meta = client.frames[-1]
    assert frame.image.shape == (256, 320) and meta["bit_depth"] == 12
    assert meta["acquired"] >= meta["read"] >= 1
    where = client.run_job("whose_process")
    if not client.in_process:
        assert where["pid"] != os.getpid()
        assert not any("bench-stream" in t for t in
                       (t.name for t in threading.enumerate()))


def test_a_job_reports_pauses_and_aborts(client):
    seen: list = []
    assert client.run_job("counting", {"n": 4}, report=seen.append) == 4
    assert seen == [0, 1, 2, 3]

    control, seen = RunControl(), []

    def pause_then_abort() -> None:
        """Pause after the first step; once the job reports the pause (waited for up
        to a 60 s hang guard: a loaded host passes it on late), hold it at least
        0.5 s, then abort."""
        for _ in range(6000):
            if seen:
                break
            time.sleep(0.01)
        control.pause()
        for _ in range(6000):
            if any(isinstance(s, tuple) for s in seen):
                break
            time.sleep(0.01)
        time.sleep(0.5)  # a lower bound: the paused job makes no step meanwhile
        control.abort("stop here")

    helper = threading.Thread(target=pause_then_abort)
    helper.start()
    with pytest.raises(RunAborted, match="stop here"):
        client.run_job("counting", {"n": 100_000}, report=seen.append,
                       control=control)
    helper.join()
    paused = [s for s in seen if isinstance(s, tuple)]
    assert len(paused) == 1, seen  # it paused (and an abort, not a resume, ended it)
    after = seen[seen.index(paused[0]) + 1:]
    assert after == [], seen  # no step while paused
    assert paused[0][1] == seen[seen.index(paused[0]) - 1] + 1  # between two steps


def test_stop_and_cancel_reach_the_job(client):
    for name in ("stop", "cancel"):
        event = threading.Event()
        threading.Timer(0.3, event.set).start()
        got = client.run_job("until_stopped", **{name: event})
        assert got == ("stopped" if name == "stop" else "cancelled")


def test_a_failed_job_raises_its_error_here(client):
    from drivers.errors import StageLimitError

    with pytest.raises(StageLimitError, match="outside"):
        client.run_job("failing")


def test_the_bench_process_closes_the_bench_when_its_parent_dies(tmp_path):
    """A window killed outright leaves no bench process holding the devices."""
    script = textwrap.dedent(f"""
        import sys, time
        sys.path[:0] = {sys.path!r}
        from instrument.bench.bench_process import BenchClient
        if __name__ == "__main__":
            c = BenchClient()
            c.run_job("open_bench", {OPEN!r})
            print(c._manager._process.pid, flush=True)
            time.sleep(120)
        """)
    (tmp_path / "window.py").write_text(script)
    parent = subprocess.Popen([sys.executable, str(tmp_path / "window.py")],
                              stdout=subprocess.PIPE, text=True)
    try:
        host_pid = int(parent.stdout.readline())
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(10)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                os.kill(host_pid, 0)
            except ProcessLookupError:
                break
            if _zombie(host_pid):
                break
            time.sleep(0.1)
        else:
            os.kill(host_pid, signal.SIGKILL)
            pytest.fail("the bench process outlived its parent by 20 s")
    finally:
        if parent.poll() is None:
            parent.kill()


def _zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def test_calls_from_many_threads_leave_nothing_behind(client):
    """A window starts a thread per job (the device poll: one a second); the manager's
    per-thread connections left an entry per thread in multiprocessing's after-fork
    registry (~19000 references to None in an hour's soak)."""
    import gc

    def poll() -> None:
        client.status("source_stage")
        client.settings("source_stage")

    def polls(n: int) -> None:
        for _ in range(n):
            t = threading.Thread(target=poll)
            t.start()
            t.join()

    polls(10)
    gc.collect()
    before = sys.getrefcount(None)
    polls(200)
    gc.collect()
    assert sys.getrefcount(None) - before < 50


def test_the_client_is_a_proxy_of_every_command_of_the_service(client):
    """Each public command of BenchService is the client's, with its signature, and
    calls the service in the bench process (none written twice)."""
    import inspect

    from instrument.bench.bench_process import PROXIED
    from instrument.bench.bench_service import BenchService

    public = {n for n, _ in inspect.getmembers(BenchService, inspect.isfunction)
              if not n.startswith("_")}
    assert set(PROXIED) == public
    for name in public:
        assert (inspect.signature(getattr(client, name))
                == inspect.signature(getattr(BenchService(), name))), name
    seq, events = client.events_after(None)  # a command the old client did not forward
    assert seq >= 1 and events == []
    assert client.camera_format().bit_depth == client.host.camera_format().bit_depth
