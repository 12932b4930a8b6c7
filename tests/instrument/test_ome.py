"""Runs and products as OME-Zarr 0.5: validated by ome-zarr-models, opened by xarray,
upgraded in place without touching a data chunk."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import zarr
from ome_zarr_models.v05.image import Image

from instrument.cli import main
from instrument.ome import volume_axes
from instrument.runstore import RunStore, RunStoreError
from instrument.runstore_records import VIDEO_PLAN

PITCH_UM, BINNING, FPS = 3.45, 2, 25.0


def _sweep(path, n_points=3, shape=(16, 20)):
    store = RunStore.create(
        path, plan_name="psf_sweep", plan_params={},
        points=[{"z_mm": 10.0 + k, "x_mm": 0.0} for k in range(n_points)],
        frame_tags=[["psf", "dark"]] * n_points, frame_shape=shape, frame_dtype=np.uint16,
        coord_names=["exposure_s"], device_settings={"cam": {"settings": {"binning": BINNING}}})
    store.update_attrs(camera={"id": "cam", "pixel_pitch_um": PITCH_UM})
    for i in range(store.n_frames):
        store.write_frame(i, np.full(shape, i, np.uint16), {"exposure_s": 0.01})
    return store


def _video(path, n=6, shape=(12, 16)):
    store = RunStore.create(
        path, plan_name=VIDEO_PLAN, plan_params={"frames": n}, points=[{}],
        frame_tags=[["video"] * n], frame_shape=shape, frame_dtype=np.uint8,
        coord_names=["exposure_s"], shard_frames=3)
    store.update_attrs(camera={"id": "cam", "pixel_pitch_um": PITCH_UM,
                               "frame_rate_hz": FPS})
    store.write_frames(0, np.arange(n * shape[0] * shape[1], dtype=np.uint8).reshape(
        n, *shape), np.full((n, 1), 0.01))
    return store


def _multiscale(group, name):
    image = Image.from_zarr(group)  # validates axes, scales and dimension names
    return next(m for m in image.ome_attributes.multiscales if m.name == name)


def _axes(ms):
    return [(a.name, a.type, a.unit) for a in ms.axes]


def _scale(ms):
    return list(ms.datasets[0].coordinateTransformations[0].scale)


def test_sweep_frames_and_every_product_kind_validate(tmp_path):
    store = _sweep(tmp_path / "s.zarr")
    rng = np.random.default_rng(0)
    store.write_product("psf_stack", rng.random((3, 16, 20), np.float32),
                        depths_mm=[10.0, 11.0, 12.0])
    store.write_product("psf_stack_raw", rng.random((3, 16, 20), np.float32),
                        depths_mm=[10.0, 12.0, 20.0])
    store.write_product("dark_mean", rng.random((16, 20), np.float32), units="DN")
    store.write_product("hot_pixel_map", np.zeros((16, 20), np.uint8))
    store.write_product("psf_grid_registered", rng.random((4, 16, 20), np.float32))
    store.write_product("angular_response", rng.random((5, 4)), columns=list("abcd"))
    store.write_product("slm_lut", rng.random(256))
    store.create_frame_product("recon_admm", store.n_frames, (8, 10), bin_factor=2)
    group = zarr.open_group(store.path, mode="r")
    frames = _multiscale(group, "frames")
    pitch = PITCH_UM * BINNING
    # the sweep's axis is named for what its points vary (z_mm, not the fixed x_mm)
    assert _axes(frames) == [("z_mm", None, None), ("y", "space", "micrometer"),
                             ("x", "space", "micrometer")]
    assert _scale(frames) == pytest.approx([1.0, pitch, pitch])
    for name in ("coords", "crc32", "done", "point", "tag"):
        assert group[name].metadata.dimension_names[0] == "z_mm"
    products = group["products"]
    even = _multiscale(products, "psf_stack")
    assert _axes(even)[0] == ("z", "space", "micrometer")
    assert _scale(even) == pytest.approx([1000.0, pitch, pitch])
    uneven = _multiscale(products, "psf_stack_raw")  # OME-Zarr has one scale per axis
    assert _axes(uneven)[0] == ("plane", None, None)
    assert uneven.metadata == {"depths_mm": [10.0, 12.0, 20.0]}
    assert _axes(_multiscale(products, "dark_mean"))[0][1:] == ("space", "micrometer")
    assert _multiscale(products, "hot_pixel_map")
    assert _axes(_multiscale(products, "psf_grid_registered"))[0][0] == "node"
    recon = _multiscale(products, "recon_admm")
    assert _axes(recon)[0][0] == "z_mm" and _scale(recon)[1] == pytest.approx(2 * pitch)
    names = [m.name for m in Image.from_zarr(products).ome_attributes.multiscales]
    assert "angular_response" not in names and "slm_lut" not in names  # no images
    assert products["angular_response"].metadata.dimension_names == ("row", "column")
    assert products["slm_lut"].metadata.dimension_names == ("entry",)
    assert products["recon_admm__done"].metadata.dimension_names == ("z_mm",)
    assert store.verify() == []


def test_video_time_axis_in_seconds(tmp_path):
    store = _video(tmp_path / "v.zarr")
    ms = _multiscale(zarr.open_group(store.path, mode="r"), "frames")
    assert _axes(ms)[0] == ("t", "time", "second")
    assert _scale(ms) == pytest.approx([1 / FPS, PITCH_UM, PITCH_UM])


def test_volume_axes_even_and_uneven():
    axis, meta = volume_axes([2.0, 2.5, 3.0], 3)
    assert (axis.name, axis.unit, axis.scale) == ("z", "micrometer", 500.0)
    axis, meta = volume_axes([1.0, 2.0, 4.0], 3)
    assert axis.name == "plane" and axis.unit is None and meta["depths_mm"] == [1, 2, 4]


def test_xarray_opens_a_run_as_a_tree(tmp_path):
    xr = pytest.importorskip("xarray")
    store = _video(tmp_path / "v.zarr")
    store.create_frame_product("recon_wiener", store.n_frames, (6, 8), bin_factor=2)
    # a ΔF/F of 4 of the 6 frames, binned as its source (the names say so)
    store.write_product("recon_wiener_dff", np.ones((4, 6, 8), np.float32),
                        frame_indices=[0, 1, 2, 3], source="recon_wiener")
    store.write_product("recon_wiener_dff_baseline", np.ones((6, 8), np.float32),
                        source="recon_wiener")
    store.write_product("flat", np.ones((5, 5), np.float32))  # another size: own names
    tree = xr.open_datatree(store.path, engine="zarr", consolidated=False)
    root = tree.to_dataset()
    assert root["frames"].dims == ("t", "y", "x") and root["coords"].dims == ("t", "coord")
    assert root["done"].dims == ("t",) and root.sizes["t"] == 6
    products = tree["products"].to_dataset()
    assert products["recon_wiener"].dims == ("t", "y_bin2", "x_bin2")
    assert products["recon_wiener"].shape == (6, 6, 8)
    assert products["recon_wiener_dff"].dims == ("t_recon_wiener_dff", "y_bin2", "x_bin2")
    assert products["recon_wiener_dff_baseline"].dims == ("y_bin2", "x_bin2")
    assert products["flat"].dims == ("y_flat", "x_flat")
    group = zarr.open_group(store.path, mode="r")["products"]
    dff = _multiscale(group, "recon_wiener_dff")
    assert _axes(dff)[0] == ("t_recon_wiener_dff", "time", "second")
    assert _scale(dff) == pytest.approx([1 / FPS, 2 * PITCH_UM, 2 * PITCH_UM])
    np.testing.assert_array_equal(root["frames"].values, store._group["frames"][:])


def _strip_to_legacy(path: Path) -> None:
    """Make ``path`` what a run written before this description looked like: no
    ``ome`` blocks, no dimension names (``coords`` had ("frame", "coord"))."""
    for meta in path.rglob("zarr.json"):
        doc = json.loads(meta.read_text())
        doc.get("attributes", {}).pop("ome", None)
        if doc.get("node_type") == "array":
            doc.pop("dimension_names", None)
            if meta.parent.name == "coords":
                doc["dimension_names"] = ["frame", "coord"]
        meta.write_text(json.dumps(doc))


def _chunk_hashes(path: Path) -> dict[str, str]:
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in path.rglob("*") if p.is_file() and p.name != "zarr.json"}


def test_upgrade_adds_the_description_without_touching_a_chunk(tmp_path, capsys):
    store = _sweep(tmp_path / "old.zarr", shape=(16, 20))
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 11.0, 12.0])
    store.create_frame_product("recon_admm", store.n_frames, (8, 10), bin_factor=2)
    store.write_product_frame("recon_admm", 0, np.ones((8, 10)))
    _strip_to_legacy(store.path)
    # a run written before still opens, verifies and is written to (resume)
    old = RunStore.open(store.path, "r+")
    assert old.verify() == []
    old.clear_point(2)
    old.write_frame(4, np.full((16, 20), 4, np.uint16), {"exposure_s": 0.01})
    old.write_frame(5, np.full((16, 20), 5, np.uint16), {"exposure_s": 0.01})
    old.write_product_frame("recon_admm", 1, np.ones((8, 10)))
    with pytest.raises(ValueError):
        Image.from_zarr(zarr.open_group(store.path, mode="r"))
    old.lock()  # a run another process writes is refused, unchanged
    with pytest.raises(RunStoreError, match="lock|writ"):
        RunStore.open(store.path, "r+").upgrade()
    old.unlock()
    before = _chunk_hashes(store.path)
    assert main(["runs", "upgrade", str(store.path)]) == 0
    assert "named the dimensions of" in capsys.readouterr().out
    assert _chunk_hashes(store.path) == before  # every chunk file byte for byte
    group = zarr.open_group(store.path, mode="r")
    assert _axes(_multiscale(group, "frames"))[0][0] == "z_mm"
    assert group["coords"].metadata.dimension_names == ("z_mm", "coord")
    assert _axes(_multiscale(group["products"], "psf_stack"))[0][0] == "z"
    assert _axes(_multiscale(group["products"], "recon_admm"))[0][0] == "z_mm"
    again = RunStore.open(store.path, "r+")
    assert again.verify() == [] and again.upgrade() == []
    assert again.frame(5).image[0, 0] == 5


def _export(run, out, *extra):
    assert main(["runs", "export", str(run), "--out", str(out), *extra]) == 0
    import tifffile

    return tifffile.TiffFile(out)


def test_export_imagej_hyperstacks_and_ome_tiff(tmp_path):
    from instrument.stacks import load_psf_stack

    store = _sweep(tmp_path / "s.zarr")
    depths = [10.0, 10.5, 11.0]
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32), depths_mm=depths)
    pitch = PITCH_UM * BINNING
    with _export(store.path, tmp_path / "psf.tif") as tif:  # Fiji: a Z stack in um
        assert tif.is_imagej and tif.series[0].axes == "ZYX"
        ij = tif.imagej_metadata
        assert ij["spacing"] == pytest.approx(500.0) and ij["unit"] == "um"
        num, den = tif.pages[0].tags["XResolution"].value
        assert den / num == pytest.approx(pitch, rel=1e-5)
    # the exported depths are read back as before
    assert load_psf_stack(tmp_path / "psf.tif")[1] == depths
    with _export(store.path, tmp_path / "psf.ome.tif") as tif:
        assert tif.is_ome and tif.series[0].axes == "ZYX"
        import tifffile

        pixels = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]["Pixels"]
        assert pixels["PhysicalSizeX"] == pytest.approx(pitch)
        assert pixels["PhysicalSizeZ"] == pytest.approx(500.0)
        assert pixels["PhysicalSizeXUnit"] == "µm"
    assert load_psf_stack(tmp_path / "psf.ome.tif")[1] == depths
    with _export(store.path, tmp_path / "frames.tif", "--frames") as tif:
        assert tif.series[0].axes == "TYX" and tif.series[0].shape == (6, 16, 20)
        assert tif.imagej_metadata["Labels"][1] == "frame 1 dark point 0"
        assert "finterval" not in tif.imagej_metadata  # a sweep: frames, not time


def test_export_video_frames_with_their_interval(tmp_path):
    store = _video(tmp_path / "v.zarr")
    with _export(store.path, tmp_path / "v.tif", "--frames") as tif:
        assert tif.series[0].axes == "TYX"
        assert tif.imagej_metadata["finterval"] == pytest.approx(1 / FPS)
    with _export(store.path, tmp_path / "v.ome.tif", "--frames") as tif:
        import tifffile

        pixels = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]["Pixels"]
        assert pixels["TimeIncrement"] == pytest.approx(1 / FPS)
        assert pixels["SizeT"] == 6 and pixels["TimeIncrementUnit"] == "s"
