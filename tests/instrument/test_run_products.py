"""Per-frame products of a run (a batch reconstruction): written plane by plane,
resumable, verified on read; and cutting a video run to the frames it holds."""

from __future__ import annotations

import numpy as np
import pytest

from instrument.acquisition.recorder import VIDEO_COORDS
from instrument.runs.runstore import RunStore, RunStoreError

SHAPE = (12, 16)


def _run(path, n=6):
    store = RunStore.create(path, plan_name="video", plan_params={"frames": n}, points=[{}],
                            frame_tags=[["video"] * n], frame_shape=SHAPE,
                            frame_dtype=np.uint16, coord_names=list(VIDEO_COORDS),
                            shard_frames=4, compressor="none")
    images = (np.arange(n)[:, None, None] + np.zeros((n, *SHAPE))).astype(np.uint16)
    return store, images


def test_frame_product_is_resumable_and_verified(tmp_path):
    store, _ = _run(tmp_path / "v.zarr")
    store.create_frame_product("recon_admm", 6, (6, 8), method="admm", iterations=5)
    planes = np.random.default_rng(0).random((6, 6, 8)).astype(np.float32)
    for i in (4, 1):
        store.write_product_frame("recon_admm", i, planes[i])
    assert store.products() == ["recon_admm"]  # the hidden arrays are not listed
    assert store.product_frames_done("recon_admm").tolist() == [0, 1, 0, 0, 1, 0]
    assert store.product_info("recon_admm")["planes_done"] == 2
    np.testing.assert_array_equal(store.product_frame("recon_admm", 4), planes[4])
    with pytest.raises(RunStoreError, match="holds 2 of 6 planes"):
        store.product("recon_admm")
    with pytest.raises(RunStoreError, match="plane 0 of product 'recon_admm'.*not written"):
        store.product_frame("recon_admm", 0)
    assert store.verify() == []  # unwritten planes are not damage
    # the same settings resume (done planes kept); other settings are refused
    store.create_frame_product("recon_admm", 6, (6, 8), method="admm", iterations=5)
    assert store.product_frames_done("recon_admm").sum() == 2
    with pytest.raises(RunStoreError, match="iterations differ"):
        store.create_frame_product("recon_admm", 6, (6, 8), method="admm", iterations=9)
    for i in (0, 2, 3, 5):
        store.write_product_frame("recon_admm", i, planes[i])
    data, attrs = RunStore.open(tmp_path / "v.zarr").product("recon_admm")
    np.testing.assert_array_equal(data, planes)
    assert attrs["method"] == "admm" and attrs["per_frame"]
    store.create_frame_product("recon_admm", 6, (6, 8), overwrite=True, method="admm",
                               iterations=9)
    assert store.product_frames_done("recon_admm").sum() == 0


def test_altered_or_deleted_product_plane_is_named(tmp_path):
    store, _ = _run(tmp_path / "v.zarr")
    store.create_frame_product("p", 6, (6, 8))
    for i in range(6):
        store.write_product_frame("p", i, np.full((6, 8), i + 1.0, np.float32))
    (tmp_path / "v.zarr" / "products" / "p" / "0" / "c" / "3" / "0" / "0").unlink()
    problems = RunStore.open(tmp_path / "v.zarr").verify()
    assert len(problems) == 1 and "plane 3 differs from the checksum" in problems[0]
    with pytest.raises(RunStoreError, match="plane 3"):
        RunStore.open(tmp_path / "v.zarr").product("p")


def test_frame_product_refuses_bad_planes_and_names(tmp_path):
    store, _ = _run(tmp_path / "v.zarr")
    store.create_frame_product("p", 6, (6, 8))
    with pytest.raises(RunStoreError, match="does not fit"):
        store.write_product_frame("p", 0, np.zeros((5, 8)))
    with pytest.raises(RunStoreError, match="outside product"):
        store.write_product_frame("p", 6, np.zeros((6, 8)))
    with pytest.raises(RunStoreError, match="invalid"):
        store.create_frame_product("a__done", 6, (6, 8))
    store.write_product("whole", np.ones((2, 3)))
    with pytest.raises(RunStoreError, match="not a per-frame product"):
        store.write_product_frame("whole", 0, np.ones((2, 3)))
    with pytest.raises(RunStoreError, match="read-only|writ"):
        RunStore.open(tmp_path / "v.zarr").create_frame_product("q", 6, (6, 8))


def test_truncate_keeps_the_recorded_frames_only(tmp_path):
    store, images = _run(tmp_path / "v.zarr", n=10)
    rows = np.zeros((5, len(VIDEO_COORDS)))
    rows[:, 0] = np.arange(5)
    store.write_frames(0, images[:5], rows)
    with pytest.raises(RunStoreError, match="not all are stored"):
        store.truncate(6)
    store.truncate(5)
    back = RunStore.open(tmp_path / "v.zarr")
    assert back.n_frames == 5 and back.done().all() and back.verify() == []
    assert back.attrs["plan"]["frames_per_point"] == [5]
    np.testing.assert_array_equal(back.frame(4).image, images[4])
