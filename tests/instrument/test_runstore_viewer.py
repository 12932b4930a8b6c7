"""What a viewer needs from a run store: a summary that reads no frame, and a check of
every frame that reports its progress (the GUI's Results panel runs it once, apart)."""

from __future__ import annotations

import numpy as np
import pytest

from instrument.runs.runstore import RunStore


def _run(path, n=6):
    store = RunStore.create(path, plan_name="p", plan_params={},
                            points=[{"z": float(k)} for k in range(n)],
                            frame_tags=[["psf"]] * n, frame_shape=(8, 10),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    for i in range(n - 1):  # the last frame is not written
        store.write_frame(i, np.full((8, 10), i + 1, np.uint16), {"exposure_s": 0.1})
    return store


def test_summary_without_verify_reads_no_frame(tmp_path, monkeypatch):
    _run(tmp_path / "r.zarr")
    store = RunStore.open(tmp_path / "r.zarr")
    reads = []
    monkeypatch.setattr(store, "_read", lambda i: reads.append(i))
    s = store.summary(verify=False)
    assert reads == [] and s["problems"] is None
    assert s["frames_done"] == 5 and s["frames"] == 6 and s["plan"] == "p"
    monkeypatch.undo()
    assert store.summary()["problems"] == []  # the default still checks every frame


def test_verify_reports_progress_and_still_finds_damage(tmp_path):
    _run(tmp_path / "r.zarr")
    (tmp_path / "r.zarr/frames/c/2/0/0").unlink()
    store = RunStore.open(tmp_path / "r.zarr")
    seen = []
    problems = store.verify(on_progress=lambda k, n: seen.append((k, n)))
    assert seen == [(k, 5) for k in range(1, 6)]
    assert len(problems) == 1 and "frame 2" in problems[0]


@pytest.mark.parametrize("block_bytes", [1, 64 * 2 ** 20])
def test_a_block_check_of_a_sharded_video_finds_the_altered_frame(tmp_path, monkeypatch,
                                                                  block_bytes):
    """Frames are checked a block of shards at a time (one block, or a shard per block):
    a frame altered inside a shard, and one never written, are told apart, with the
    progress of every done frame."""
    import zarr

    import instrument.runs.run_integrity as integrity

    monkeypatch.setattr(integrity, "VERIFY_BLOCK_BYTES", block_bytes)
    n = 10
    store = RunStore.create(tmp_path / "v.zarr", plan_name="video", plan_params={},
                            points=[{"t": float(k)} for k in range(n)],
                            frame_tags=[["frame"]] * n, frame_shape=(8, 10),
                            frame_dtype=np.uint16, coord_names=["exposure_s"],
                            shard_frames=4)
    rng = np.random.default_rng(0)
    for i in range(n - 1):  # the last frame is not written
        store.write_frame(i, rng.integers(0, 4000, (8, 10)).astype(np.uint16),
                          {"exposure_s": 0.01})
    assert RunStore.open(tmp_path / "v.zarr").verify() == []
    zarr.open_group(str(tmp_path / "v.zarr"), mode="r+")["frames"][5] = np.full((8, 10), 7)
    seen = []
    problems = RunStore.open(tmp_path / "v.zarr").verify(
        on_progress=lambda k, total: seen.append((k, total)))
    assert seen == [(k, 9) for k in range(1, 10)]
    assert len(problems) == 1 and problems[0].startswith("frame 5 ") and "differ" in problems[0]
