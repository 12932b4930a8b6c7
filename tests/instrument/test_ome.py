"""Runs and products as OME-Zarr 0.5 (each image product its own image group):
validated by ome-zarr-models, opened by xarray, runs of the layout before opened,
verified, resumed and upgraded in place without touching a data chunk."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from ome_zarr_models import open_ome_zarr
from ome_zarr_models.v05.image import Image

from instrument.cli import main
from instrument.runs.ome import SWEEP_T, describe_products, volume_axes
from instrument.runs.runstore import RunStore, RunStoreError
from instrument.runs.runstore_records import VIDEO_PLAN
from instrument.writer.ome_axes import UNEVEN_Z, YX_SCALE

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


def _product_image(run, name):
    """The one multiscale of product ``name``'s own image group ``products/NAME``,
    validated by ome-zarr-models (the group as an OME-Zarr 0.5 image, its array ``0``
    named as its axes)."""
    group = zarr.open_group(Path(run) / "products" / name, mode="r")
    image = open_ome_zarr(group, version="0.5")  # what it is, found by validation
    assert isinstance(image, Image)
    (ms,) = image.ome_attributes.multiscales
    assert ms.name == name and [d.path for d in ms.datasets] == ["0"]
    # one image: no other array as a level; a stack's true depths beside it are a 1-D
    # coordinate named as its one dimension (xarray's z), not a dataset
    others = [k for k in group.array_keys() if k != "0"]
    assert others in ([], ["z"])
    for key in others:
        assert group[key].ndim == 1 and list(group[key].metadata.dimension_names) == [key]
    return ms


def _axes(ms):
    return [(a.name, a.type, a.unit) for a in ms.axes]


def _scale(ms):
    return list(ms.datasets[0].coordinateTransformations[0].scale)


def _origin(ms):
    return list(ms.datasets[0].coordinateTransformations[1].translation)


def _every_product_kind(store):
    """Every kind of product a run holds (images of each axis kind, a table, a LUT,
    a per-frame reconstruction) written to ``store``; the image products' names."""
    rng = np.random.default_rng(0)
    store.write_product("psf_stack", rng.random((3, 16, 20), np.float32),
                        depths_mm=[10.0, 11.0, 12.0])
    store.write_product("psf_stack_raw", rng.random((3, 16, 20), np.float32),
                        depths_mm=[10.0, 12.0, 20.0])
    store.write_product("dark_mean", rng.random((16, 20), np.float32), units="DN")
    store.write_product("hot_pixel_map", np.zeros((16, 20), np.uint8))
    store.write_product("psf_grid_registered", rng.random((4, 16, 20), np.float32))
    store.write_product("bead_images", rng.random((4, 16, 20), np.float32), bin_factor=1)
    store.write_product("angular_response", rng.random((5, 4)), columns=list("abcd"))
    store.write_product("slm_lut", rng.random(256))
    store.create_frame_product("recon_admm", store.n_frames, (8, 10), bin_factor=2)
    store.write_product_frame("recon_admm", 0, np.ones((8, 10)))
    return ["bead_images", "dark_mean", "hot_pixel_map", "psf_grid_registered",
            "psf_stack", "psf_stack_raw", "recon_admm"]


def test_sweep_frames_and_every_product_kind_validate(tmp_path):
    store = _sweep(tmp_path / "s.zarr")
    images = _every_product_kind(store)
    group = zarr.open_group(store.path, mode="r")
    frames = _multiscale(group, "frames")
    pitch = PITCH_UM * BINNING
    # one-letter axes (bioio takes no other): a sweep's frames counted in time order,
    # without a unit (a PSF and a dark frame per point), as its metadata says
    assert _axes(frames) == [("t", "time", None), ("y", "space", "micrometer"),
                             ("x", "space", "micrometer")]
    assert _scale(frames) == pytest.approx([1.0, pitch, pitch])
    assert frames.metadata == {"t": SWEEP_T, "yx_scale": YX_SCALE}
    for name in ("coords", "crc32", "done", "point", "tag"):
        assert group[name].metadata.dimension_names[0] == "t"
    # each image product is its own OME-Zarr image: products/NAME with its array at 0
    products = group["products"]
    assert sorted(products.group_keys()) == images
    assert "ome" not in products.attrs  # a plain group: no multiscales of several images
    for name in images:
        _product_image(store.path, name)
        attrs = products[f"{name}/0"].attrs  # the product's attributes go with its array
        assert "crc32" in attrs or attrs["per_frame"]
    even = _product_image(store.path, "psf_stack")
    assert _axes(even)[0] == ("z", "space", "micrometer")
    assert _scale(even) == pytest.approx([1000.0, pitch, pitch])
    assert _origin(even) == pytest.approx([10000.0, 0.0, 0.0])  # the first plane's depth
    uneven = _product_image(store.path, "psf_stack_raw")  # one scale per axis: the mean
    assert _axes(uneven)[0] == ("z", "space", "micrometer")
    assert _scale(uneven)[0] == pytest.approx(5000.0) and _origin(uneven)[0] == 10000.0
    assert uneven.metadata == {"depths_mm": [10.0, 12.0, 20.0], "z_scale": UNEVEN_Z,
                               "yx_scale": YX_SCALE}
    assert _axes(_product_image(store.path, "dark_mean"))[0][1:] == ("space", "micrometer")
    assert _axes(_product_image(store.path, "psf_grid_registered"))[0] == (
        "c", "channel", None)  # one PSF per grid node
    beads = _product_image(store.path, "bead_images")  # 3-D without depths: planes
    assert _axes(beads) == [("z", "space", None), ("y", "space", "micrometer"),
                            ("x", "space", "micrometer")]
    assert _scale(beads) == pytest.approx([1.0, pitch, pitch])
    recon = _product_image(store.path, "recon_admm")  # binning is a scale, not a name
    assert _axes(recon) == [("t", "time", None), ("y", "space", "micrometer"),
                            ("x", "space", "micrometer")]
    assert _scale(recon)[1] == pytest.approx(2 * pitch)
    assert recon.metadata["bin_factor"] == 2
    # tables and LUTs are no images: arrays of products/, as the per-frame bookkeeping
    assert sorted(products.array_keys()) == ["angular_response", "recon_admm__crc32",
                                             "recon_admm__done", "slm_lut"]
    assert products["angular_response"].metadata.dimension_names == ("row", "column")
    assert products["slm_lut"].metadata.dimension_names == ("entry",)
    assert products["recon_admm__done"].metadata.dimension_names == ("t",)
    assert sorted(store.products()) == sorted([*images, "angular_response", "slm_lut"])
    assert store.verify() == []
    assert store.product("bead_images")[0].shape == (4, 16, 20)
    assert store.product_frame("recon_admm", 0)[0, 0] == 1.0
    # xarray: each image group opens on its own, its depths in the array's attributes
    xr = pytest.importorskip("xarray")
    beads = xr.open_dataset(store.path, engine="zarr", group="products/bead_images",
                            consolidated=False)["0"]
    assert beads.sizes == {"z": 4, "y": 16, "x": 20}
    raw = xr.open_dataset(store.path, engine="zarr", group="products/psf_stack_raw",
                          consolidated=False)["0"]
    assert raw.dims == ("z", "y", "x") and raw.attrs["depths_mm"] == [10.0, 12.0, 20.0]


def test_video_time_axis_in_seconds(tmp_path):
    store = _video(tmp_path / "v.zarr")
    ms = _multiscale(zarr.open_group(store.path, mode="r"), "frames")
    assert _axes(ms)[0] == ("t", "time", "second")
    assert _scale(ms) == pytest.approx([1 / FPS, PITCH_UM, PITCH_UM])


def test_volume_axes_even_and_uneven():
    axis, meta = volume_axes([2.0, 2.5, 3.0], 3)
    assert (axis.name, axis.unit, axis.scale, axis.origin) == ("z", "micrometer", 500.0,
                                                               2000.0)
    assert "z_scale" not in meta
    axis, meta = volume_axes([1.0, 2.0, 4.0], 3)  # uneven: the mean spacing, stated
    assert (axis.name, axis.unit, axis.scale, axis.origin) == ("z", "micrometer", 1500.0,
                                                               1000.0)
    assert meta == {"depths_mm": [1, 2, 4], "z_scale": UNEVEN_Z}
    axis, _ = volume_axes([5.0], 1)  # one plane: its depth as the origin
    assert (axis.unit, axis.origin) == ("micrometer", 5000.0)
    axis, _ = volume_axes(None, 4)  # no depths: planes without a unit
    assert (axis.name, axis.unit, axis.origin) == ("z", None, 0.0)


def test_xarray_opens_each_image_of_a_run(tmp_path):
    """One-letter dimension names in every group: xarray opens the root (the frames),
    ``products/`` and each image group on its own with those names; the whole run as
    one tree where the groups' sizes agree (a tree wants one size per name)."""
    xr = pytest.importorskip("xarray")
    store = _video(tmp_path / "v.zarr")
    store.create_frame_product("recon_wiener", store.n_frames, (6, 8), bin_factor=2)
    # a ΔF/F of 4 of the 6 frames, binned as its source (its scale says so)
    store.write_product("recon_wiener_dff", np.ones((4, 6, 8), np.float32),
                        frame_indices=[0, 1, 2, 3], source="recon_wiener")
    store.write_product("recon_wiener_dff_baseline", np.ones((6, 8), np.float32),
                        source="recon_wiener")
    store.write_product("flat", np.ones((5, 5), np.float32))
    store.write_product("lut", np.arange(7.0))  # no image: an array of products/

    def group(path=None):
        return xr.open_dataset(store.path, engine="zarr", group=path, consolidated=False)

    root = group()
    assert root["frames"].dims == ("t", "y", "x") and root["coords"].dims == ("t", "coord")
    assert root["done"].dims == ("t",) and root.sizes["t"] == 6
    products = group("products")
    assert products["recon_wiener__done"].dims == ("t",)
    assert products["lut"].dims == ("entry",)

    def image(name):  # each image product: a group of its own, its array "0"
        return group(f"products/{name}")["0"]

    assert image("recon_wiener").dims == ("t", "y", "x")
    assert image("recon_wiener").shape == (6, 6, 8)
    assert image("recon_wiener").attrs["per_frame"] is True
    assert image("recon_wiener_dff").dims == ("t", "y", "x")
    assert image("recon_wiener_dff_baseline").dims == ("y", "x")
    assert image("flat").dims == ("y", "x")
    assert group("products/flat").attrs["ome"]["multiscales"][0]["name"] == "flat"
    dff = _product_image(store.path, "recon_wiener_dff")
    assert _axes(dff)[0] == ("t", "time", "second")
    assert _scale(dff) == pytest.approx([1 / FPS, 2 * PITCH_UM, 2 * PITCH_UM])
    np.testing.assert_array_equal(root["frames"].values, store._group["frames"][:])
    np.testing.assert_array_equal(image("flat").values, np.ones((5, 5)))
    same = _video(tmp_path / "same.zarr")  # products of the frames' size: one tree
    same.create_frame_product("recon_wiener", same.n_frames, (12, 16), bin_factor=1)
    tree = xr.open_datatree(same.path, engine="zarr", consolidated=False)
    assert tree["products/recon_wiener"].to_dataset()["0"].dims == ("t", "y", "x")


def _strip_to_legacy(path: Path) -> None:
    """Make ``path`` what a run written before this description looked like: no
    ``ome`` blocks, no dimension names (``coords`` had ("frame", "coord")), no record
    of them."""
    for meta in path.rglob("zarr.json"):
        doc = json.loads(meta.read_text())
        doc.get("attributes", {}).pop("ome", None)
        doc.get("attributes", {}).pop("described", None)
        if doc.get("node_type") == "array":
            doc.pop("dimension_names", None)
            if meta.parent.name == "coords":
                doc["dimension_names"] = ["frame", "coord"]
        meta.write_text(json.dumps(doc))


def _to_old_layout(path: Path) -> None:
    """Make ``path``'s products what a run written before the image groups held: each
    image product's array moved back to ``products/NAME`` (its group gone, no chunk
    rewritten), the run's layout record keyed ``NAME`` again, ``products/``
    holding one ``ome`` block listing every image, and no record of the ``ome``
    blocks and dimension names (what runs wrote then)."""
    products = path / "products"
    for array in sorted(products.glob("*/0")):
        name = array.parent.name
        os.replace(array, products / f"{name}.old")
        shutil.rmtree(products / name)
        os.replace(products / f"{name}.old", products / name)
    doc = json.loads((products / "zarr.json").read_text())
    record = doc["attributes"]["arrays"]
    doc["attributes"]["arrays"] = {k.removesuffix("/0"): v for k, v in record.items()}
    (products / "zarr.json").write_text(json.dumps(doc))
    group = zarr.open_group(path, mode="r+")
    describe_products(group["products"], dict(group.attrs))
    assert "ome" in group["products"].attrs and not list(group["products"].group_keys())
    for node in (group, group["products"]):
        del node.attrs["described"]


def _chunks(path: Path) -> dict[str, tuple[str, int]]:
    """Every file of ``path`` but the metadata documents: its bytes' hash and inode."""
    return {str(p.relative_to(path)): (hashlib.sha256(p.read_bytes()).hexdigest(),
                                       p.stat().st_ino)
            for p in path.rglob("*") if p.is_file() and p.name != "zarr.json"}


def _moved(chunks: dict, names) -> dict:
    """``chunks`` with each file of the products ``names`` where the upgrade puts it:
    ``products/NAME/...`` under ``products/NAME/0/...``."""
    out = {}
    for key, value in chunks.items():
        parts = key.split("/")
        if len(parts) > 2 and parts[0] == "products" and parts[1] in names:
            key = "/".join([*parts[:2], "0", *parts[2:]])
        out[key] = value
    return out


def test_upgrade_adds_the_description_without_touching_a_chunk(tmp_path, capsys):
    store = _sweep(tmp_path / "old.zarr", shape=(16, 20))
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 11.0, 12.0])
    store.write_product("bead_images", np.full((2, 16, 20), 2, np.float32), bin_factor=1)
    store.write_product("slm_lut", np.arange(256.0))
    store.create_frame_product("recon_admm", store.n_frames, (8, 10), bin_factor=2)
    store.write_product_frame("recon_admm", 0, np.ones((8, 10)))
    _to_old_layout(store.path)
    _strip_to_legacy(store.path)
    # a run written before still opens, verifies and is written to (resume)
    old = RunStore.open(store.path, "r+")
    assert old.verify() == []
    assert old.products() == ["bead_images", "psf_stack", "recon_admm", "slm_lut"]
    old.clear_point(2)
    old.write_frame(4, np.full((16, 20), 4, np.uint16), {"exposure_s": 0.01})
    old.write_frame(5, np.full((16, 20), 5, np.uint16), {"exposure_s": 0.01})
    old.write_product_frame("recon_admm", 1, np.ones((8, 10)))
    assert (store.path / "products/recon_admm/c/1/0/0").is_file()  # where it was
    with _export(store.path, tmp_path / "psf.tif") as tif:  # runs export reads it there
        assert tif.series[0].axes == "ZYX"
        assert tif.imagej_metadata["spacing"] == pytest.approx(1000.0)
    with pytest.raises(ValueError):
        Image.from_zarr(zarr.open_group(store.path, mode="r"))
    old.lock()  # a run another process writes is refused, unchanged
    with pytest.raises(RunStoreError, match="lock|writ"):
        RunStore.open(store.path, "r+").upgrade()
    old.unlock()
    before = _chunks(store.path)
    assert main(["runs", "upgrade", str(store.path)]) == 0
    out = capsys.readouterr().out
    assert "named the dimensions of" in out and "moved 3 image products" in out
    images = ("bead_images", "psf_stack", "recon_admm")
    # every chunk file byte for byte, the same file (renamed with its folder)
    assert _chunks(store.path) == _moved(before, images)
    group = zarr.open_group(store.path, mode="r")
    assert _axes(_multiscale(group, "frames"))[0][0] == "t"
    assert group["coords"].metadata.dimension_names == ("t", "coord")
    assert "ome" not in group["products"].attrs
    assert _axes(_product_image(store.path, "psf_stack"))[0][0] == "z"
    assert _axes(_product_image(store.path, "recon_admm"))[0][0] == "t"
    assert _axes(_product_image(store.path, "bead_images"))[0][0] == "z"
    assert sorted(group["products"].array_keys()) == ["recon_admm__crc32",
                                                      "recon_admm__done", "slm_lut"]
    again = RunStore.open(store.path, "r+")
    assert again.verify() == [] and again.layout_damage == {}
    assert again.upgrade() == {"named": [], "moved": []}  # idempotent
    assert _chunks(store.path) == _moved(before, images)
    assert again.frame(5).image[0, 0] == 5
    assert again.product("bead_images")[0][1, 0, 0] == 2.0
    assert again.product_frames_done("recon_admm").tolist()[:3] == [True, True, False]
    assert main(["runs", "verify", str(store.path)]) == 0
    assert "intact" in capsys.readouterr().out


def test_a_run_of_the_layout_before_opens_resumes_and_upgrades(tmp_path, capsys):
    """A run written just before the image groups (its products arrays of products/,
    which held one ome block listing them) is read and resumed as it was, a product
    added to it goes into a group of its own, and the upgrade moves the rest."""
    store = _video(tmp_path / "v.zarr")
    store.create_frame_product("recon_wiener", store.n_frames, (6, 8), bin_factor=2)
    for i in range(3):
        store.write_product_frame("recon_wiener", i, np.full((6, 8), i, np.float32))
    store.write_product("flat", np.ones((5, 5), np.float32))
    _to_old_layout(store.path)
    old = RunStore.open(store.path, "r+")
    assert old.verify() == [] and old.products() == ["flat", "recon_wiener"]
    assert [m.name for m in Image.from_zarr(old._group["products"]).ome_attributes
            .multiscales] == ["flat", "recon_wiener"]
    # resumed: the per-frame product of the layout before is kept and finished
    old.create_frame_product("recon_wiener", old.n_frames, (6, 8), bin_factor=2)
    for i in range(3, 6):
        old.write_product_frame("recon_wiener", i, np.full((6, 8), i, np.float32))
    assert old.product("recon_wiener")[0][:, 0, 0].tolist() == [0, 1, 2, 3, 4, 5]
    old.write_product("recon_wiener_dff", np.ones((4, 6, 8), np.float32),
                      frame_indices=[0, 1, 2, 3], source="recon_wiener")
    dff = _product_image(old.path, "recon_wiener_dff")
    assert _axes(dff)[1] == ("y", "space", "micrometer")
    assert _scale(dff)[1] == pytest.approx(2 * PITCH_UM)  # the source's binning, found
    # in either layout
    old.write_product("flat", np.full((5, 5), 2, np.float32))  # replaced: a group now
    _product_image(old.path, "flat")
    assert [m.name for m in Image.from_zarr(old._group["products"]).ome_attributes
            .multiscales] == ["recon_wiener"]  # the block lists what is left there
    assert old.verify() == []
    assert main(["runs", "show", str(old.path)]) == 0
    shown = capsys.readouterr().out
    assert "product  recon_wiener: 6x6x8 float32  (6 of 6 frames done)" in shown
    assert "product  flat: 5x5 float32" in shown
    before = _chunks(old.path)
    assert old.upgrade() == {"named": [], "moved": ["recon_wiener"]}
    assert _chunks(old.path) == _moved(before, ("recon_wiener",))
    assert "ome" not in zarr.open_group(old.path / "products", mode="r").attrs
    new = RunStore.open(old.path)
    assert new.verify() == [] and new.layout_damage == {}
    assert new.products() == ["flat", "recon_wiener", "recon_wiener_dff"]
    assert new.product("recon_wiener")[0][:, 0, 0].tolist() == [0, 1, 2, 3, 4, 5]
    assert new.product_info("recon_wiener")["planes_done"] == 6


def test_upgrade_finishes_a_move_cut_short(tmp_path):
    """An upgrade killed between its renames: the array already in its temporary group
    (the product missing from the run meanwhile, so verify names it), the record not
    yet renamed; the next upgrade finishes the move and the run is intact."""
    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 11.0, 12.0])
    _to_old_layout(store.path)
    products = store.path / "products"
    zarr.open_group(store.path / "products", mode="r+").create_group("psf_stack__moving")
    os.replace(products / "psf_stack", products / "psf_stack__moving" / "0")
    cut = RunStore.open(store.path, "r+")
    assert cut.products() == []
    assert any("'psf_stack'" in p and "missing" in p for p in cut.verify())
    before = _chunks(store.path)
    assert cut.upgrade()["moved"] == ["psf_stack"]
    assert not (products / "psf_stack__moving").exists()
    assert _chunks(store.path) == {k.replace("psf_stack__moving/0", "psf_stack/0"): v
                                   for k, v in before.items()}
    done = RunStore.open(store.path)
    assert done.verify() == [] and done.layout_damage == {}
    _product_image(store.path, "psf_stack")


def _export(run, out, *extra):
    assert main(["runs", "export", str(run), "--out", str(out), *extra]) == 0
    import tifffile

    return tifffile.TiffFile(out)


def test_export_imagej_hyperstacks_and_ome_tiff(tmp_path):
    from instrument.runs.stacks import load_psf_stack

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


def test_a_run_written_with_the_names_before_keeps_them(tmp_path, capsys):
    """A run written before the one-letter names (``z_mm`` frames, a ``plane`` stack,
    a reconstruction on ``y_bin2``/``x_bin2``) is read by its stored names: described,
    verified and exported as it is, its scales and origins the new ones."""
    from instrument.runs.ome import describe_run, set_dimension_names

    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack_raw", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 12.0, 20.0])
    store.create_frame_product("recon_admm", store.n_frames, (8, 10), bin_factor=2)
    store.write_product_frame("recon_admm", 0, np.ones((8, 10)))
    old = {"frames": ["z_mm", "y", "x"], "coords": ["z_mm", "coord"],
           **{n: ["z_mm"] for n in ("crc32", "done", "point", "tag")},
           "products/psf_stack_raw/0": ["plane", "y", "x"],
           "products/recon_admm/0": ["z_mm", "y_bin2", "x_bin2"],
           "products/recon_admm__done": ["z_mm"], "products/recon_admm__crc32": ["z_mm"]}
    for name, dims in old.items():
        set_dimension_names(store.path / name, dims)
    group = zarr.open_group(store.path, mode="r+")
    for node in (group, group["products"]):
        del node.attrs["described"]  # (a run of then recorded no description)
    describe_run(group)
    frames = _multiscale(zarr.open_group(store.path, mode="r"), "frames")
    assert [a[0] for a in _axes(frames)] == ["z_mm", "y", "x"]
    raw = _product_image(store.path, "psf_stack_raw")
    assert _axes(raw)[0] == ("plane", "space", "micrometer")
    assert _origin(raw)[0] == 10000.0
    recon = _product_image(store.path, "recon_admm")
    assert [a[0] for a in _axes(recon)] == ["z_mm", "y_bin2", "x_bin2"]
    assert _scale(recon)[1] == pytest.approx(2 * PITCH_UM * BINNING)
    again = RunStore.open(store.path)
    assert again.verify() == []
    assert [a.name for a in again.product_axes("recon_admm")[0]] == ["z_mm", "y_bin2",
                                                                     "x_bin2"]
    assert main(["runs", "export", str(store.path), "--product", "psf_stack_raw",
                 "--out", str(tmp_path / "raw.tif")]) == 0
    assert main(["runs", "verify", str(store.path)]) == 0
    assert "intact" in capsys.readouterr().out
