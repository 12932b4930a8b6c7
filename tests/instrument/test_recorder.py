"""The video recorder: sharded run store, no index gaps, counted loss, SIGKILL, lock."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

from drivers.camera import Frame, FrameRing
from drivers.simulated import SimulatedCamera
from instrument.acquisition.recorder import VIDEO_COORDS, Recorder, index_ranges, record_from_ring
from instrument.runs.runstore import RunStore, RunStoreError
from tests.refcycles import assert_freed_without_the_collector

SHAPE = (24, 32)


def _video_store(path, n, shard=8, compressor="blosc-lz4", shape=SHAPE):
    return RunStore.create(path, plan_name="video", plan_params={"frames": n},
                           points=[{}], frame_tags=[["video"] * n], frame_shape=shape,
                           frame_dtype=np.uint16, coord_names=list(VIDEO_COORDS),
                           shard_frames=shard, compressor=compressor)


def _frame(i, shape=SHAPE):
    image = (np.arange(shape[0] * shape[1], dtype=np.uint16).reshape(shape) + i).astype(np.uint16)
    return Frame(image=image, index=i, device_timestamp_s=0.05 * i, host_timestamp_s=1e9 + i,
                 exposure_s=0.01, gain=2.0, saturated_pixels=0)


def test_simulated_camera_frames_recorded_equal_delivered_without_gaps(tmp_path):
    cam = SimulatedCamera("cam0", sensor_shape=SHAPE)
    cam.open()
    cam.frame_rate_hz = 20.0
    store = _video_store(tmp_path / "v.zarr", 30)
    ring = FrameRing(8)
    rec = Recorder(store)
    rec.start()
    cam.start_stream(ring)
    seen = []
    record_from_ring(rec, ring, 30, on_frame=seen.append)
    cam.stop_stream()
    summary = rec.close(ring=ring)
    assert summary["delivered"] == summary["recorded"] == 30
    assert summary["lost_by_recorder"] == 0 and summary["index_gaps"] == []
    back = RunStore.open(tmp_path / "v.zarr")
    assert back.shard_frames == 8 and back.status == "complete" and back.lock_owner() is None
    assert back.verify() == [] and back.done().sum() == 30
    table = back.coords_table()
    assert table["frame_index"].tolist() == [f.index for f in seen]
    assert np.all(np.diff(table["frame_index"]) == 1)
    assert np.all(np.diff(table["device_timestamp_s"]) == pytest.approx(0.05))
    np.testing.assert_array_equal(back.frame(17).image, seen[17].image)
    assert back.frame(17).coords["exposure_s"] == pytest.approx(seen[17].exposure_s)
    assert back.summary()["summary"]["recording"]["recorded"] == 30


def test_slowed_sink_loses_frames_counted_by_index(tmp_path):
    store = _video_store(tmp_path / "v.zarr", 40, shard=4)
    entered, gate = threading.Event(), threading.Event()

    def slow_sink(start, images, rows):
        entered.set()
        gate.wait(60.0)  # the disk stalls until every frame was offered (a hang guard)
        store.write_frames(start, images, rows)

    rec = Recorder(store, queue_frames=6, sink=slow_sink)
    rec.start()
    accepted = [rec.offer(_frame(i)) for i in range(4)]
    assert entered.wait(60.0)  # a hang guard: the writer takes the shard at once
    accepted += [rec.offer(_frame(i)) for i in range(4, 20)]
    gate.set()
    summary = rec.close()
    lost = [i for i, ok in enumerate(accepted) if not ok]
    # the writer took 4 frames into its shard and blocks; 6 wait in the queue
    assert len(lost) == 10 and lost == list(range(10, 20))
    assert summary["lost_by_recorder"] == 10 and summary["lost_indices"] == [[10, 19]]
    assert summary["delivered"] == 20 and summary["recorded"] == 10
    back = RunStore.open(tmp_path / "v.zarr")
    assert back.done().sum() == 10 and back.verify() == []
    assert back.coords_table()["frame_index"][:10].tolist() == list(range(10))


def test_index_gaps_before_the_recorder_are_stored(tmp_path):
    store = _video_store(tmp_path / "v.zarr", 10, shard=4)
    rec = Recorder(store)
    rec.start()
    for i in (0, 1, 2, 5, 6, 9):
        assert rec.offer(_frame(i))
    summary = rec.close(status="stopped")
    assert summary["index_gaps"] == [[3, 4], [7, 8]]
    assert RunStore.open(tmp_path / "v.zarr").refresh()["status"] == "stopped"
    assert index_ranges([9, 3, 4, 5]) == [[3, 5], [9, 9]]


def test_sigkill_keeps_completed_shards_all_verifying(tmp_path):
    path = tmp_path / "v.zarr"
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {os.getcwd()!r})
        from tests.instrument.test_recorder import _frame, _video_store
        from instrument.acquisition.recorder import Recorder
        store = _video_store({str(path)!r}, 2000, shard=5)
        rec = Recorder(store)
        rec.start()
        i = 0
        while True:
            rec.offer(_frame(i))
            i += 1
            time.sleep(0.002)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if (path / "done" / "c" / "3").exists():  # four shards written
                break
            time.sleep(0.05)
        else:
            pytest.fail("the recording subprocess wrote no shards in 20 s")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    back = RunStore.open(path)
    summary = back.summary()
    held = summary["frames_done"]
    assert held >= 20 and held % 5 == 0 and summary["problems"] == []
    assert back.done()[:held].all() and not back.done()[held:].any()
    assert "stale lock" in summary["lock"] and back.status == "recording"
    np.testing.assert_array_equal(back.frame(held - 1).image, _frame(held - 1).image)


def test_lock_refuses_a_second_writer_and_overwrite_is_refused(tmp_path):
    store = _video_store(tmp_path / "v.zarr", 10)
    rec = Recorder(store)
    rec.start()
    other = Recorder(RunStore.open(tmp_path / "v.zarr", "r+"))
    with pytest.raises(RunStoreError, match="cannot write"):
        other.start()
    with pytest.raises(RunStoreError, match="already exists"):
        _video_store(tmp_path / "v.zarr", 10)
    rec.close()
    assert RunStore.open(tmp_path / "v.zarr").lock_owner() is None
    with pytest.raises(RunStoreError, match="all are taken"):
        full = Recorder(RunStore.open(tmp_path / "v.zarr", "r+"))
        full.start()
        try:
            for i in range(11):
                full.offer(_frame(i))
        finally:
            full.close()


def test_damaged_shard_is_reported_by_verify(tmp_path):
    store = _video_store(tmp_path / "v.zarr", 16, shard=8, compressor="none")
    rec = Recorder(store)
    rec.start()
    for i in range(16):
        rec.offer(_frame(i))
    rec.close()
    (tmp_path / "v.zarr/frames/c/1/0/0").unlink()
    problems = RunStore.open(tmp_path / "v.zarr").verify()
    assert len(problems) == 8 and "frame 8 " in problems[0]
    assert "frames/c/1/0/0 is missing" in problems[0]


def test_file_count_per_1000_frames(tmp_path):
    store = _video_store(tmp_path / "v.zarr", 1000, shard=20, shape=(4, 4))
    rec = Recorder(store, queue_frames=1000)
    rec.start()
    for i in range(1000):
        assert rec.offer(_frame(i, (4, 4)))
    rec.close()
    files = sum(len(fs) for _, _, fs in os.walk(tmp_path / "v.zarr"))
    # 50 shards x (frames, coords, crc32, done) + 8 zarr.json (was 4 files per frame;
    # the all-zero point and tag chunks equal their fill value and are not written)
    assert files == 4 * 50 + 8
    assert RunStore.open(tmp_path / "v.zarr").verify() == []


def test_recorder_needs_video_coords_and_valid_sharding(tmp_path):
    store = RunStore.create(tmp_path / "p.zarr", plan_name="p", plan_params={}, points=[{}],
                            frame_tags=[["a"]], frame_shape=SHAPE, frame_dtype=np.uint16,
                            coord_names=["z"])
    with pytest.raises(RunStoreError, match="lacks the video coordinates"):
        Recorder(store)
    with pytest.raises(RunStoreError, match="shard_frames=0 is invalid"):
        _video_store(tmp_path / "a.zarr", 4, shard=0)
    with pytest.raises(RunStoreError, match="unknown frame compressor"):
        _video_store(tmp_path / "b.zarr", 4, compressor="gzip")
    assert store.shard_frames is None


def test_a_failed_recorder_is_freed_without_the_collector(tmp_path):
    """The writer's error is kept without its traceback, whose frames held the recorder
    and the failed block's images (a cycle the GUI's frozen heap never collects)."""
    store = _video_store(tmp_path / "v.zarr", 8, shard=4)

    def full_disk(start, images, rows):
        raise OSError(28, "No space left on device")

    rec = Recorder(store, sink=full_disk)
    rec.start()
    for i in range(4):
        rec.offer(_frame(i))
    with pytest.raises(RunStoreError, match="No space left"):
        rec.close()
    held = {"rec": rec}
    del rec
    assert_freed_without_the_collector(held, "rec", "failed recorder")
