"""The run store: layout, write order, reading while written, products, errors."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from instrument.runs.runstore import SCHEMA_VERSION, RunStore, RunStoreError


def _create(path, **kw):
    args = dict(plan_name="p", plan_params={"a": 1}, points=[{"z": 1.0}, {"z": 2.0}],
                frame_tags=[["psf", "psf", "dark"], ["psf", "psf", "dark"]],
                frame_shape=(8, 10), frame_dtype=np.uint16, coord_names=["exposure_s", "z"],
                bench_config={"name": "b"}, device_settings={"cam": {}}, note="n")
    args.update(kw)
    return RunStore.create(path, **args)


def test_layout_roundtrip_and_progress(tmp_path):
    store = _create(tmp_path / "r.zarr")
    assert store.n_frames == 6 and store.n_points == 2 and store.tags == ["dark", "psf"]
    assert store.first_incomplete_point() == 0 and store.status == "created"
    for i in range(4):
        store.write_frame(i, np.full((8, 10), i, np.uint16), {"exposure_s": 0.1 * i, "z": 1.0})
    assert store.points_done().tolist() == [True, False]
    assert store.first_incomplete_point() == 1
    back = RunStore.open(tmp_path / "r.zarr")
    rec = back.frame(3)
    assert rec.point == 1 and rec.tag == "psf" and rec.image[0, 0] == 3
    assert rec.coords["exposure_s"] == pytest.approx(0.3)
    frames, coords = back.point_frames(0, "psf")
    assert frames[:, 0, 0].tolist() == [0, 1] and len(coords) == 2
    with pytest.raises(RunStoreError, match="not written"):
        back.frame(5)
    with pytest.raises(RunStoreError, match="not complete"):
        back.point_frames(1)
    assert np.isnan(back.coords_table()["z"][5])
    store.clear_point(1)
    assert store.done().sum() == 3
    a = back.refresh()
    assert a["schema_version"] == SCHEMA_VERSION and a["plan"]["params"] == {"a": 1}
    assert a["bench_config"] == {"name": "b"} and a["note"] == "n"


def test_products_and_summary(tmp_path):
    store = _create(tmp_path / "r.zarr")
    store.write_product("psf_stack", np.ones((2, 8, 10), np.float32), depths_mm=[1.0, 2.0])
    store.write_product("psf_stack", np.zeros((2, 8, 10), np.float32), depths_mm=[3.0, 4.0])
    arr, attrs = RunStore.open(tmp_path / "r.zarr").product("psf_stack")
    assert arr.sum() == 0 and attrs["depths_mm"] == [3.0, 4.0]
    with pytest.raises(RunStoreError, match="no product"):
        store.product("nope")
    store.update_attrs(status="complete", summary={"k": 1})
    store.add_warning("w1")
    s = RunStore.open(tmp_path / "r.zarr").summary()
    assert s["status"] == "complete" and s["warnings"] == ["w1"] and s["summary"] == {"k": 1}
    assert s["products"]["psf_stack"]["shape"] == [2, 8, 10]


def test_bad_writes_and_opens_are_refused(tmp_path):
    store = _create(tmp_path / "r.zarr")
    with pytest.raises(RunStoreError, match="frame shape"):
        store.write_frame(0, np.zeros((9, 10), np.uint16), {})
    with pytest.raises(RunStoreError, match="unknown coordinates"):
        store.write_frame(0, np.zeros((8, 10), np.uint16), {"temperature": 1.0})
    with pytest.raises(RunStoreError, match="outside"):
        store.write_frame(6, np.zeros((8, 10), np.uint16), {})
    with pytest.raises(RunStoreError, match="read-only"):
        RunStore.open(tmp_path / "r.zarr").write_frame(0, np.zeros((8, 10), np.uint16), {})
    with pytest.raises(RunStoreError, match="already exists"):
        _create(tmp_path / "r.zarr")
    _create(tmp_path / "r.zarr", overwrite=True)
    with pytest.raises(RunStoreError, match="no run store"):
        RunStore.open(tmp_path / "missing.zarr")
    store.update_attrs(schema_version=SCHEMA_VERSION + 1)
    with pytest.raises(RunStoreError, match="schema"):
        RunStore.open(tmp_path / "r.zarr")


def test_reader_never_sees_a_partial_frame(tmp_path):
    """A reader polling while a writer thread stores frames only ever reads complete
    frames (each one's pixels all equal its index)."""
    n = 60
    store = _create(tmp_path / "c.zarr", points=[{"i": i} for i in range(n)],
                    frame_tags=[["psf"]] * n, frame_shape=(64, 80))
    errors, reads = [], [0]

    def writer():
        for i in range(n):
            store.write_frame(i, np.full((64, 80), i, np.uint16), {"exposure_s": float(i)})

    def reader():
        try:
            while True:
                r = RunStore.open(tmp_path / "c.zarr")
                done = np.flatnonzero(r.done())
                for i in done[-3:]:
                    rec = r.frame(int(i))
                    assert np.all(rec.image == i) and rec.coords["exposure_s"] == i
                    reads[0] += 1
                if len(done) == n:
                    return
        except Exception as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer), threading.Thread(target=reader)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors and reads[0] > 0


@pytest.mark.parametrize("image, problem", [
    (np.full((8, 10), -5.0), "outside"), (np.full((8, 10), 70000.0), "outside"),
    (np.full((8, 10), np.nan), "NaN/inf"), (np.full((8, 10), np.inf), "NaN/inf"),
    (np.full((8, 10), 2.5), "non-integer"), (np.full((8, 10), -5, np.int32), "outside"),
    (np.full((8, 10), 70000, np.int64), "outside"), (np.ones((8, 10), complex), "cannot be"),
])
def test_values_the_dtype_cannot_hold_are_refused(tmp_path, image, problem):
    """An integer run refuses data that would wrap or round (-5 -> 65531, NaN -> 0)."""
    store = _create(tmp_path / "r.zarr")
    with pytest.raises(RunStoreError, match=f"frame 2: .*{problem}"):
        store.write_frame(2, image, {})
    assert not store.done()[2]


def test_values_that_fit_are_stored_exactly(tmp_path):
    store = _create(tmp_path / "r.zarr")
    store.write_frame(0, np.full((8, 10), 65535.0), {})
    store.write_frame(1, np.full((8, 10), 70, np.int64), {})
    store.write_frame(2, np.full((8, 10), 3, np.uint8), {})
    assert [int(store.frame(i).image[0, 0]) for i in range(3)] == [65535, 70, 3]
    assert store.frame(0).image.dtype == np.uint16
