"""Run-store integrity: checksums catch deleted and altered chunks, old stores still read."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys

import numpy as np
import pytest
import zarr

from instrument.runs.runstore import RunStore, RunStoreError


def _run(path):
    store = RunStore.create(path, plan_name="p", plan_params={}, points=[{"z": 1.0}, {"z": 2.0}],
                            frame_tags=[["psf", "psf"], ["psf", "psf"]], frame_shape=(8, 10),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    for i in range(4):
        store.write_frame(i, np.full((8, 10), i + 1, np.uint16), {"exposure_s": 0.1})
    store.write_product("psf_stack", np.ones((2, 8, 10), np.float32), depths_mm=[1.0, 2.0])
    return store


def test_intact_run_verifies_clean(tmp_path):
    store = _run(tmp_path / "r.zarr")
    assert store.has_checksums and store.verify() == []
    arr, attrs = store.product("psf_stack")
    assert arr.sum() == 160 and "crc32" not in attrs and attrs["depths_mm"] == [1.0, 2.0]


def test_deleted_frame_chunk_is_reported_not_read_as_zeros(tmp_path):
    _run(tmp_path / "r.zarr")
    (tmp_path / "r.zarr/frames/c/3/0/0").unlink()
    store = RunStore.open(tmp_path / "r.zarr")
    with pytest.raises(RunStoreError, match=r"frame 3 \(point 1\).*missing.*--redo 1"):
        store.frame(3)
    with pytest.raises(RunStoreError, match="frame 3"):
        store.point_frames(1)
    store.point_frames(0)  # the other point is intact
    problems = store.verify()
    assert len(problems) == 1 and "frame 3" in problems[0]


def test_altered_frame_chunk_is_reported(tmp_path):
    _run(tmp_path / "r.zarr")
    zarr.open_group(str(tmp_path / "r.zarr"), mode="r+")["frames"][2] = np.zeros((8, 10)) + 7
    store = RunStore.open(tmp_path / "r.zarr")
    with pytest.raises(RunStoreError, match=r"frame 2 \(point 1\).*differ"):
        store.frame(2)
    (tmp_path / "r.zarr/frames/c/1/0/0").write_bytes(b"garbage")
    problems = RunStore.open(tmp_path / "r.zarr").verify()
    assert [p.split(" (")[0] for p in problems] == ["frame 1", "frame 2"]


def test_damaged_product_plane_is_reported(tmp_path):
    _run(tmp_path / "r.zarr")
    (tmp_path / "r.zarr/products/psf_stack/0/c/1/0/0").unlink()
    store = RunStore.open(tmp_path / "r.zarr")
    with pytest.raises(RunStoreError, match="product 'psf_stack'.*plane 1"):
        store.product("psf_stack")
    assert len(store.verify()) == 1


def test_schema_1_store_reads_without_checksums(tmp_path):
    store = _run(tmp_path / "r.zarr")
    store.update_attrs(schema_version=1)
    shutil.rmtree(tmp_path / "r.zarr/crc32")
    old = RunStore.open(tmp_path / "r.zarr")
    assert not old.has_checksums and old.verify() == []
    assert old.frame(3).image[0, 0] == 4


def test_second_writer_is_refused_and_lock_released(tmp_path):
    store = _run(tmp_path / "r.zarr")
    store.lock()
    lock = tmp_path / "r.zarr/.lock"
    assert lock.is_file() and store.lock_owner()["pid"] == os.getpid()
    other = RunStore.open(tmp_path / "r.zarr", mode="r+")
    with pytest.raises(RunStoreError, match=f"process {os.getpid()} on .* is writing it"):
        other.lock()
    with pytest.raises(RunStoreError, match="not replacing"):
        RunStore.create(tmp_path / "r.zarr", plan_name="p", plan_params={}, points=[{}],
                        frame_tags=[["a"]], frame_shape=(2, 2), frame_dtype=np.uint16,
                        coord_names=[], overwrite=True)
    assert store.verify() == [] and RunStore.open(tmp_path / "r.zarr").has_checksums
    other.unlock()  # holds nothing: the owner's lock stays
    assert lock.is_file()
    store.unlock()
    assert not lock.exists() and store.lock_owner() is None
    other.lock()
    other.unlock()


def test_stale_lock_is_reported_not_broken(tmp_path):
    _run(tmp_path / "r.zarr")
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead = int(proc.stdout)
    lock = tmp_path / "r.zarr/.lock"
    lock.write_text(json.dumps({"pid": dead, "host": socket.gethostname(),
                                "started_utc": "x"}))
    store = RunStore.open(tmp_path / "r.zarr", mode="r+")
    with pytest.raises(RunStoreError, match=f"stale lock: the process {dead} that held it is "
                       f"gone; remove {lock}"):
        store.lock()
    assert lock.is_file()
    assert "stale lock" in store.summary()["lock"]
    lock.write_text("{")
    with pytest.raises(RunStoreError, match="unreadable"):
        store.lock()


def test_runner_refuses_a_locked_run_and_releases_its_own(tmp_path):
    from instrument.acquisition.runner import Runner
    from instrument.devices.virtual_bench import VirtualBench

    store = _run(tmp_path / "r.zarr")
    store.lock()
    with VirtualBench() as bench, pytest.raises(RunStoreError, match="is writing it"):
        Runner(bench).resume(tmp_path / "r.zarr")
    store.unlock()


def test_overwrite_replaces_only_a_run_store(tmp_path):
    args = dict(plan_name="p", plan_params={}, points=[{}], frame_tags=[["a"]],
                frame_shape=(2, 2), frame_dtype=np.uint16, coord_names=[], overwrite=True)
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "keep.txt").write_text("precious")
    (tmp_path / "file.zarr").write_text("precious")
    zarr.open_group(str(tmp_path / "other.zarr"), mode="w", zarr_format=3)
    for name in ("data", "file.zarr", "other.zarr"):
        with pytest.raises(RunStoreError, match="not a diffuserlab run store"):
            RunStore.create(tmp_path / name, **args)
    assert (tmp_path / "data" / "keep.txt").read_text() == "precious"
    assert (tmp_path / "file.zarr").read_text() == "precious"
    _run(tmp_path / "r.zarr")
    assert RunStore.create(tmp_path / "r.zarr", **args).n_frames == 1


@pytest.mark.parametrize("damage, message", [
    (lambda p: (p / "zarr.json").write_bytes((p / "zarr.json").read_bytes()[:200]),
     r"r.zarr/zarr.json is damaged \(JSONDecodeError"),
    (lambda p: (p / "zarr.json").write_text("not json"), "zarr.json is damaged"),
    (lambda p: (p / "zarr.json").write_text(json.dumps(_without(p, "plan"))),
     "is damaged: its zarr.json lacks plan;"),
    (lambda p: (p / "zarr.json").write_text(json.dumps(_without(p, "tags", "status"))),
     "lacks status, tags;"),
    (lambda p: (p / "tag/zarr.json").unlink(), r"its layout is unreadable \(KeyError: 'tag'\)"),
    (lambda p: (p / "frames/zarr.json").write_text("{"), "its layout is unreadable"),
])
def test_damaged_metadata_is_a_run_store_error_naming_the_damage(tmp_path, damage, message):
    _run(tmp_path / "r.zarr")
    damage(tmp_path / "r.zarr")
    with pytest.raises(RunStoreError, match=message):
        RunStore.open(tmp_path / "r.zarr")


def _without(path, *keys):
    meta = json.loads((path / "zarr.json").read_text())
    for key in keys:
        del meta["attributes"][key]
    return meta
