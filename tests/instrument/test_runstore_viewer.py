"""What a viewer needs from a run store: a summary that reads no frame, and a check of
every frame that reports its progress (the GUI's Results panel runs it once, apart)."""

from __future__ import annotations

import numpy as np

from instrument.runstore import RunStore


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
