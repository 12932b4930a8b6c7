"""A batch reconstruction in a child process (instrument.processing.batch_process), as the GUI runs
it: the same frames as in the caller's process, progress and cancel across the process
boundary, the child's errors back with their type and traceback, a killed child named
as such, and the caller's process left without dask's references."""

from __future__ import annotations

import gc
import multiprocessing
import os
import shutil
import sys
import threading

import numpy as np
import pytest

import recon
from instrument.processing.batch_process import (
    BATCH_NICE,
    BatchProcessError,
    _last_word,
    _portable,
    reconstruct_run_in_process,
)
from instrument.runs.runstore import RunStore, RunStoreError
from recon.options import ReconOptions
from tests.instrument.test_batch import video  # noqa: F401 (the fixture)

RECON = {"method": "admm", "iterations": 6, "tv": 1e-3, "bin_factor": 2}
OPTIONS = {"options": ReconOptions.validated(RECON, front="python"), "workers": 1}


@pytest.fixture
def run(video, tmp_path):  # noqa: F811
    """A copy of test_batch's 12-frame bead video."""
    path = tmp_path / "v.zarr"
    shutil.copytree(video[0] / "v.zarr", path)
    return path


def test_the_child_stores_what_the_caller_would_and_reports_progress(video, run):  # noqa: F811
    seen = []
    out = reconstruct_run_in_process(run, video[1], frames=range(0, 3), on_progress=seen.append,
                                     **OPTIONS)
    assert out["reconstructed"] == 3 and not out["cancelled"]
    assert out["process"]["pid"] != os.getpid()
    assert out["process"]["nice"] == min(19, os.nice(0) + BATCH_NICE)
    assert [p["done"] for p in seen] == [1, 2, 3] and {p["total"] for p in seen} == {3}
    store = RunStore.open(run)
    assert store.lock_owner() is None
    for i in range(3):
        expect = recon.reconstruct(video[1], store.frame(i).image, **RECON).image
        np.testing.assert_allclose(store.product_frame("recon_admm", i), expect, rtol=0,
                                   atol=1e-5 * float(np.abs(expect).max()))


def test_a_child_started_from_a_lowered_thread_is_lowered_from_the_process(video, run):  # noqa: F811
    """The GUI starts the batch from a job thread already at nice 10: the child runs
    ``BATCH_NICE`` above the process, not above that thread (it ran at 19, starved)."""
    from instrument.acquisition.live import lower_thread_priority

    process_nice = os.getpriority(os.PRIO_PROCESS, os.getpid())
    out = {}

    def from_a_job_thread():
        lower_thread_priority(10)
        out.update(reconstruct_run_in_process(run, video[1], frames=range(0, 1), **OPTIONS))

    t = threading.Thread(target=from_a_job_thread)
    t.start()
    t.join(300)
    assert out["reconstructed"] == 1
    assert out["process"]["nice"] == min(19, process_nice + BATCH_NICE)
    assert os.getpriority(os.PRIO_PROCESS, os.getpid()) == process_nice


def test_a_cancel_stops_the_child_and_keeps_its_frames(video, run):  # noqa: F811
    """A cancel set here reaches the child, which stops after the frame in hand and
    keeps it. The cancel is set before the start (set on the first frame's progress,
    the child of a loaded host had done all 12 frames before it arrived): the batch
    checks it after each frame stored, so exactly one is kept."""
    cancel, seen = threading.Event(), []
    cancel.set()
    out = reconstruct_run_in_process(run, video[1], cancel=cancel, on_progress=seen.append,
                                     **OPTIONS)
    assert out["cancelled"] and out["reconstructed"] == 1
    assert [p["done"] for p in seen] == [1]
    done = RunStore.open(run).product_frames_done("recon_admm")
    assert done.sum() == out["reconstructed"]


def test_the_childs_error_comes_back_with_its_type_and_traceback(video, run):  # noqa: F811
    reconstruct_run_in_process(run, video[1], frames=range(0, 1), **OPTIONS)
    with pytest.raises(RunStoreError, match="iterations differ") as info:
        reconstruct_run_in_process(run, video[1], ReconOptions.validated(
            {**RECON, "iterations": 7}, front="python"), frames=range(0, 1), workers=1)
    assert any("in the batch process" in note and "Traceback" in note
               for note in info.value.__notes__)


class _TwoArguments(RunStoreError):
    """A project error that cannot be pickled: it holds a lock (and its arguments do not
    round-trip, unless tblib, which dask installs, rebuilds it without them)."""

    def __init__(self, path, reason):
        super().__init__(f"{path}: {reason}")
        self.held = threading.Lock()


def test_an_error_that_cannot_be_pickled_keeps_its_message_and_kind():
    try:
        raise _TwoArguments("run.zarr", "damaged")
    except _TwoArguments as exc:
        portable = _portable(exc)
    assert type(portable).__name__ == "InputError" and str(portable) == "run.zarr: damaged"
    assert "_TwoArguments" in portable.__notes__[0]
    try:
        raise KeyError("a bug")
    except KeyError as exc:
        assert type(_portable(exc)) is KeyError


def test_a_child_that_dies_without_a_result_is_named_so():
    context = multiprocessing.get_context("spawn")
    messages = context.Queue()
    child = context.Process(target=os._exit, args=(9,))
    child.start()
    child.join(60)
    kind, error = _last_word(messages, child)
    assert kind == "error" and isinstance(error, BatchProcessError)
    assert "it exited with status 9" in str(error) and "start the batch again" in str(error)


def test_batches_in_a_child_leave_the_callers_references_alone(video, run):  # noqa: F811
    """In the caller's process a batch keeps ~230 references to None (dask's scheduler
    and client); through the child it keeps none of them."""
    reconstruct_run_in_process(run, video[1], frames=range(0, 1), **OPTIONS)  # warm up
    drifts = []
    for k in range(2):
        gc.collect()
        before = sys.getrefcount(None)
        reconstruct_run_in_process(run, video[1], frames=range(0, 2), product=f"p{k}",
                                   **OPTIONS)
        gc.collect()
        drifts.append(sys.getrefcount(None) - before)
    assert max(drifts) < 50, drifts
