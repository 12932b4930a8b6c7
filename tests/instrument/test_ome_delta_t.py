"""OME-TIFF frames and per-frame products carry each plane's recorded time as its
``DeltaT`` (bioio's ``time_interval`` was None: only ``TimeIncrement`` was written;
issue 67)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from instrument.runs.runstore import RunStore
from instrument.runs.runstore_records import VIDEO_PLAN
from instrument.runs.stacks import export_tiff

bioio = pytest.importorskip("bioio")
bioio_ome_tiff = pytest.importorskip("bioio_ome_tiff")

TIMES = [1000.0, 1000.04, 1000.08, 1000.125, 1000.16]


def _video(path):
    n, shape = len(TIMES), (12, 16)
    store = RunStore.create(path, plan_name=VIDEO_PLAN, plan_params={"frames": n},
                            points=[{}], frame_tags=[["video"] * n], frame_shape=shape,
                            frame_dtype=np.uint16,
                            coord_names=["exposure_s", "device_timestamp_s"])
    store.update_attrs(camera={"id": "cam", "pixel_pitch_um": 3.45, "frame_rate_hz": 25.0})
    store.write_frames(0, np.arange(n * 192, dtype=np.uint16).reshape(n, *shape),
                       np.column_stack([np.full(n, 0.01), TIMES]))
    store.create_frame_product("recon_admm", n, shape, np.float32)
    for i in range(n):
        store.write_product_frame("recon_admm", i, np.full(shape, i, np.float32))
    return store


def _delta_t(path) -> list[float]:
    with tifffile.TiffFile(path) as tif:
        planes = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]["Pixels"]["Plane"]
    return [float(p["DeltaT"]) for p in planes]


def test_frames_and_a_per_frame_product_carry_each_planes_time(tmp_path):
    store = _video(tmp_path / "v.zarr")
    want = [t - TIMES[0] for t in TIMES]
    for product, name in ((None, "frames.ome.tif"), ("recon_admm", "recon.ome.tif")):
        out, _ = export_tiff(store.path, tmp_path / name, product=product)
        assert _delta_t(out) == pytest.approx(want)
        seen = bioio.BioImage(str(out), reader=bioio_ome_tiff.Reader)
        assert seen.dims.T == len(TIMES)
        # bioio reads the planes' DeltaT into its standard metadata (bioio-ome-tiff
        # 1.4's Reader has no time_interval of its own: None whatever the file holds)
        meta = seen.standard_metadata
        assert meta.timelapse_interval.total_seconds() == pytest.approx(0.04)
        assert meta.total_time_duration.total_seconds() == pytest.approx(0.16)


def test_bioio_tifffile_opens_the_imagej_hyperstacks_with_their_pixel_sizes(tmp_path):
    """bioio-tifffile (MIT, the interop extra) opens an ImageJ hyperstack export with
    its axes and pixel sizes (docs/open-data.md said it did not)."""
    bioio_tifffile = pytest.importorskip("bioio_tifffile")
    store = _video(tmp_path / "v.zarr")
    out, _ = export_tiff(store.path, tmp_path / "frames.tif", product=None)
    seen = bioio.BioImage(str(out), reader=bioio_tifffile.Reader)
    assert (seen.dims.T, seen.dims.Y, seen.dims.X) == (len(TIMES), 12, 16)
    assert seen.physical_pixel_sizes.Y == pytest.approx(3.45)
    assert seen.physical_pixel_sizes.X == pytest.approx(3.45)
