"""The bench process's connection file (as a Jupyter kernel's) and ``diffuserlab bench
serve``: a notebook attaches with ``BenchClient.connect()`` and no address to copy."""

from __future__ import annotations

import json
import os
import queue
import signal
import stat
import subprocess
import sys
import threading

import pytest

from instrument.bench.bench_connection import connection_files, runtime_dir
from instrument.bench.bench_process import BenchClient
from instrument.bench.bench_service import BenchGoneError

from . import bench_clients as other
from .bench_clients import OtherClient
from .test_bench_process import opened_bench
from .test_bench_service import HANG_S


@pytest.fixture
def runtime(tmp_path, monkeypatch):
    """A runtime directory of this test's own (the bench processes inherit it)."""
    folder = tmp_path / "runtime"
    monkeypatch.setenv("DIFFUSERLAB_RUNTIME_DIR", str(folder))
    return folder


def test_the_bench_process_writes_a_private_connection_file_a_notebook_connects_by(
        runtime, tmp_path):
    with opened_bench(name="the window") as window:
        path = window.connection_file
        assert path is not None and os.path.dirname(path) == str(runtime) == str(runtime_dir())
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
        assert stat.S_IMODE(os.stat(runtime).st_mode) == 0o700
        info = json.loads(open(path).read())
        assert info["pid"] == window._manager._process.pid
        assert info["address"] == window.address and info["bench"] == "simulated"
        assert bytes.fromhex(info["authkey"]) == window.authkey
        # a notebook in a process of its own finds it with no argument
        notebook = OtherClient(None, None, "the notebook", connect=True)
        try:
            listed = notebook.value(other.jobs)
            assert [j["owner"] for j in listed] == [window.name]  # the window's opening
        finally:
            notebook.close()
    assert not os.path.exists(path)  # the bench process ended: nothing to connect to
    with pytest.raises(BenchGoneError, match="no bench process runs for this user"):
        BenchClient.connect()


def test_a_killed_bench_process_s_file_is_passed_over(runtime):
    window = BenchClient()
    try:
        path = window.connection_file
        process = window._manager._process
        os.kill(process.pid, signal.SIGKILL)
        process.join(HANG_S)
        assert os.path.exists(path) and connection_files() == []
        with pytest.raises(BenchGoneError, match="no bench process runs"):
            BenchClient.connect()
    finally:
        window.close()
    assert not os.path.exists(path)


def _lines(proc: subprocess.Popen) -> queue.SimpleQueue:
    lines: queue.SimpleQueue = queue.SimpleQueue()

    def read() -> None:
        for line in proc.stdout:
            lines.put(line.rstrip("\n"))
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    return lines


def _until(lines: queue.SimpleQueue, prefix: str) -> str:
    while True:
        try:
            line = lines.get(timeout=HANG_S)
        except queue.Empty:
            pytest.fail(f"no line {prefix!r} within {HANG_S:.0f} s")
        assert line is not None, f"the output ended before {prefix!r}"
        if line.startswith(prefix):
            return line


def test_bench_serve_gives_a_notebook_a_bench_without_a_window(runtime, tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "instrument.cli", "bench", "serve",
                             "--simulate"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        lines = _lines(proc)
        served = _until(lines, "serving")
        assert "built-in simulated bench (simulated): camera" in served
        assert _until(lines, "address ")
        path = _until(lines, "connection file ").removeprefix("connection file ")
        assert os.path.dirname(path) == str(runtime)
        notebook = BenchClient.connect(name="the notebook")
        try:
            job = notebook.start_job("record", {"out": str(tmp_path / "v.zarr"),
                                                "frames": 3})
            assert job.result(HANG_S)["recorded"] == 3
        finally:
            notebook.close()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(HANG_S) == 0, proc.stderr.read()
        assert not os.path.exists(path)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_bench_serve_refuses_a_missing_bench_file_in_one_line(runtime, tmp_path):
    done = subprocess.run([sys.executable, "-m", "instrument.cli", "bench", "serve",
                           str(tmp_path / "nope.toml")], capture_output=True, text=True,
                          timeout=HANG_S)
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1 and "nope.toml" in done.stderr
    assert not runtime.exists() or connection_files() == []
