"""A run's attributes set together are written together: one write of ``zarr.json``.

zarr's ``group.attrs.update`` sets one key at a time, each a write of the whole
document, so a reader (the window waiting for a killed bench's run to close) could see
``status="interrupted"`` without the ``closed_by`` set with it. Every ``zarr.json``
written is recorded here, so the check does not depend on a reader's timing.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading

import numpy as np
import pytest

from instrument.bench.bench_recovery import close_orphaned_run
from instrument.runs.run_integrity import LOCK_NAME, write_lock
from instrument.runs.runstore import RunStore


@pytest.fixture
def documents(monkeypatch):
    """Every root ``zarr.json`` written (as parsed JSON), in order."""
    from zarr.storage import _local

    written: list[dict] = []
    put = _local._put

    def recording_put(path, value, exclusive=False):
        n = put(path, value, exclusive=exclusive)
        if path.name == "zarr.json" and path.parent.name.endswith(".zarr"):
            written.append(json.loads(bytes(value.as_buffer_like())).get("attributes", {}))
        return n

    monkeypatch.setattr(_local, "_put", recording_put)
    return written


def _run(path):
    store = RunStore.create(path, plan_name="video", plan_params={}, points=[{}],
                            frame_tags=[["frame"] * 3], frame_shape=(8, 8),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    store.write_frame(0, np.zeros((8, 8), np.uint16), {"exposure_s": 0.01})
    return store


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_update_attrs_writes_every_value_at_once(tmp_path, documents):
    store = _run(tmp_path / "r.zarr")
    documents.clear()
    store.update_attrs(status="stopped", error="e", ended_utc="t", summary={"n": 1})
    assert len(documents) == 1
    assert {k: documents[0][k] for k in ("status", "error", "ended_utc", "summary")} == {
        "status": "stopped", "error": "e", "ended_utc": "t", "summary": {"n": 1}}
    assert RunStore.open(tmp_path / "r.zarr").attrs["summary"] == {"n": 1}


def test_a_closed_run_is_never_seen_interrupted_without_closed_by(tmp_path, documents):
    """Two closers at once (the window's job thread and its close of the client): one
    closes the run, in one write; the other finds it closed."""
    path = tmp_path / "r.zarr"
    store = _run(path)
    store.update_attrs(status="recording")
    pid = _dead_pid()
    assert write_lock(path, {"pid": pid, "host": socket.gethostname(), "started_utc": "t"})
    documents.clear()
    results: list[bool] = []
    go = threading.Barrier(2)

    def close(who: str) -> None:
        go.wait()
        results.append(close_orphaned_run(path, writer_pid=pid, closed_by=who,
                                          why="killed (SIGKILL)"))

    threads = [threading.Thread(target=close, args=(w,)) for w in ("job", "close")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert sorted(results) == [False, True]
    assert len(documents) == 1 and documents[0]["status"] == "interrupted"
    assert documents[0]["closed_by"]["why"] == "killed (SIGKILL)"
    assert documents[0]["closed_by"]["frames_kept"] == 1
    closed = RunStore.open(path)
    assert closed.status == "interrupted" and closed.attrs["closed_by"]["by"] in ("job", "close")
    assert not (path / LOCK_NAME).exists()


def test_a_product_is_never_seen_without_its_checksum(tmp_path, monkeypatch):
    """A product's attributes (its checksum among them) are one write of its
    ``zarr.json``: attribute by attribute, a reader could see a product without its
    ``crc32`` and take it for damaged."""
    from zarr.storage import _local

    store = _run(tmp_path / "r.zarr")
    written: list[dict] = []
    put = _local._put

    def recording_put(path, value, exclusive=False):
        n = put(path, value, exclusive=exclusive)
        if path.name == "zarr.json" and "products" in path.parts:
            written.append(json.loads(bytes(value.as_buffer_like())).get("attributes", {}))
        return n

    monkeypatch.setattr(_local, "_put", recording_put)
    store.write_product("recon", np.ones((4, 4), np.float32), method="fista", iterations=3)
    with_attributes = [doc for doc in written if "method" in doc or "crc32" in doc]
    assert with_attributes, "the product's attributes were never written"
    assert all("crc32" in doc for doc in with_attributes), with_attributes
    assert with_attributes[-1]["method"] == "fista"
