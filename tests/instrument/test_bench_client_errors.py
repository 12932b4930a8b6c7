"""A client's mistakes and a bench process that is gone, each said in one clear line:
a job before the bench is open, parameters a job does not take, every call after the
bench process was killed."""

from __future__ import annotations

import os
import signal

import pytest

from instrument.bench.bench_host import BenchHostError
from instrument.bench.bench_jobs import RECORD_OPTIONS
from instrument.bench.bench_process import BenchClient
from instrument.bench.bench_service import BenchGoneError, BenchServiceError

from .test_bench_job_handle import recording
from .test_bench_process import opened_bench


def test_a_record_before_the_bench_is_open_says_open_the_bench_first(tmp_path):
    client = BenchClient()
    try:
        with pytest.raises(BenchHostError, match="record: no bench is open; open the bench "
                                                 "first"):
            client.start_job("record", recording(tmp_path / "v.zarr"))
        assert not (tmp_path / "v.zarr").exists()
    finally:
        client.close()


@pytest.mark.parametrize("in_process", [False, True], ids=["child-process", "in-process"])
def test_a_job_refuses_keys_it_does_not_take_naming_them_and_the_accepted_ones(
        tmp_path, in_process):
    with opened_bench(in_process=in_process) as client:
        bad_option = {**recording(tmp_path / "v.zarr"), "options": {"fsp": 30.0}}
        with pytest.raises(BenchServiceError) as refused:
            client.start_job("record", bad_option)
        text = str(refused.value)
        assert "\n" not in text and "unknown option 'fsp'" in text
        assert ", ".join(RECORD_OPTIONS) in text
        with pytest.raises(BenchServiceError, match=r"record: unknown parameter 'fps'; it "
                                                 r"accepts out, frames, seconds, options, "
                                                 r"simulated"):
            client.start_job("record", {**recording(tmp_path / "v.zarr"), "fps": 30.0})
        with pytest.raises(BenchServiceError, match="unknown parameter 'nme'"):
            client.run_job("set_scene", {"nme": "none"})
        assert not (tmp_path / "v.zarr").exists()
        # as the operator guide shows it: frames and options only
        job = client.start_job("record", {"out": str(tmp_path / "v.zarr"), "frames": 3,
                                          "options": {"fps": 30.0}})
        assert job.result(90.0)["recorded"] == 3


def test_every_call_after_the_bench_process_is_killed_says_it_is_gone():
    window = BenchClient()
    window.run_job("open_bench", {"bench_path": None, "simulate": True, "seed": 0,
                                  "scene": "none"})
    notebook = BenchClient(address=window.address, authkey=window.authkey)
    job = notebook.start_job("set_scene", {"name": "none"})
    job.result(90.0)
    process = window._manager._process
    os.kill(process.pid, signal.SIGKILL)
    process.join(90.0)
    for client in (notebook, window):
        for call in (client.jobs, lambda c=client: c.job(job.id),
                     lambda c=client: c.start_job("set_scene", {"name": "none"}),
                     client.devices):
            with pytest.raises(BenchGoneError, match="the bench process at .* is gone"):
                call()
        assert not client.alive()
    for client in (notebook, window):
        client.close()  # nothing raised: there is nothing left to close
    with pytest.raises(BenchGoneError, match="is gone or not running"):
        BenchClient(address=window.address, authkey=window.authkey)
