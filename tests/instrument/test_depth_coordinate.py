"""Uneven depths, issue 67: OME-Zarr 0.5 gives an axis one scale, so a stack's true
depths are written beside it as the coordinate array ``z`` (mm): xarray gives it as the
``z`` coordinate, OME-Zarr readers still read the one image, and a run checks it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from instrument.runs.runstore import RunStore, RunStoreError

xr = pytest.importorskip("xarray")

#: A default sweep's kind of depths: uniform in 1/z from 20 to 160 mm (25 planes), so
#: the mean spacing puts plane 24 far from its true depth.
DEPTHS_MM = [float(round(1.0 / v, 4)) for v in np.linspace(1 / 20.0, 1 / 160.0, 25)]


def _run(path, depths=DEPTHS_MM):
    store = RunStore.create(path, plan_name="psf-sweep", plan_params={}, points=[{}],
                            frame_tags=[[]], frame_shape=(12, 16),
                            frame_dtype=np.float32, coord_names=[])
    stack = np.random.default_rng(0).random((len(depths), 12, 16)).astype(np.float32)
    store.write_product("psf_stack", stack, depths_mm=depths)
    return store, stack


def _at_the_mean_spacing(ome: dict, plane: int) -> float:
    """Where the OME scale and translation put ``plane``, mm."""
    transforms = ome["multiscales"][0]["datasets"][0]["coordinateTransformations"]
    scale, shift = transforms[0]["scale"][0], transforms[1]["translation"][0]
    return (shift + scale * plane) / 1000.0


def test_xarray_gives_a_run_stacks_true_depths_as_its_z_coordinate(tmp_path):
    store, stack = _run(tmp_path / "cal.zarr")
    ds = xr.open_dataset(str(store.path), engine="zarr", group="products/psf_stack",
                         consolidated=False)
    assert list(ds["0"].dims) == ["z", "y", "x"]
    np.testing.assert_array_equal(ds["z"].values, DEPTHS_MM)
    assert ds["z"].attrs["units"] == "mm"
    # a plane by its true depth; the OME scale alone puts that plane elsewhere
    np.testing.assert_array_equal(ds["0"].sel(z=DEPTHS_MM[12]).values, stack[12])
    assert abs(_at_the_mean_spacing(ds.attrs["ome"], 12) - DEPTHS_MM[12]) > 10.0
    tree = xr.open_datatree(str(store.path), engine="zarr", consolidated=False)
    np.testing.assert_array_equal(tree["products/psf_stack"]["z"].values, DEPTHS_MM)


def test_the_stack_stays_one_valid_ome_zarr_image(tmp_path):
    import zarr
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader
    from ome_zarr_models.v05.image import Image

    store, _ = _run(tmp_path / "cal.zarr")
    group_path = store.path / "products" / "psf_stack"
    Image.from_zarr(zarr.open_group(str(group_path), mode="r"))  # validates
    nodes = list(Reader(parse_url(str(group_path)))())
    assert [[d.shape for d in n.data] for n in nodes] == [[(25, 12, 16)]]
    opened = RunStore.open(store.path)
    assert opened.damaged_products() == [] and not opened.layout_damage
    assert opened.products() == ["psf_stack"]  # the coordinate is no product
    data, attrs = opened.product("psf_stack")
    assert data.shape == (25, 12, 16) and attrs["depths_mm"] == DEPTHS_MM


def test_a_depth_coordinate_that_disagrees_is_damage(tmp_path):
    store, _ = _run(tmp_path / "cal.zarr", depths=[20.0, 25.0, 40.0])
    import zarr

    z = zarr.open_array(str(store.path / "products" / "psf_stack" / "z"), mode="r+")
    z[2] = 41.0
    with pytest.raises(RunStoreError, match=r"depth coordinate z/ holds \[20.0, 25.0, 41.0\]"):
        RunStore.open(store.path).product("psf_stack")
    assert any("depth coordinate" in p for p in RunStore.open(store.path).damaged_products())


def test_the_coordinates_layout_is_recorded(tmp_path):
    store, _ = _run(tmp_path / "cal.zarr", depths=[20.0, 25.0, 40.0])
    node = store.path / "products" / "psf_stack" / "z" / "zarr.json"
    meta = json.loads(node.read_text())
    meta["data_type"] = "float32"  # its bytes read as other numbers
    node.write_text(json.dumps(meta))
    damage = RunStore.open(store.path).layout_damage
    assert "products/psf_stack/z" in damage and "float32" in damage["products/psf_stack/z"]


def test_a_replaced_stack_without_depths_leaves_no_coordinate(tmp_path):
    store, _ = _run(tmp_path / "cal.zarr", depths=[20.0, 25.0, 40.0])
    store.write_product("psf_stack", np.ones((3, 12, 16), np.float32))
    assert not (store.path / "products" / "psf_stack" / "z").exists()
    opened = RunStore.open(store.path)
    assert opened.damaged_products() == [] and not opened.layout_damage


def test_a_recon3d_volume_carries_its_depths_as_its_z_coordinate(tmp_path):
    import zarr
    from ome_zarr_models.v05.image import Image

    from instrument.writer.products import write_volume

    volume = np.random.default_rng(1).random((25, 8, 10)).astype(np.float32)
    path = tmp_path / "v.zarr"
    write_volume(path, volume, {"depths_mm": DEPTHS_MM}, pitch_um=6.5)
    ds = xr.open_dataset(str(path), engine="zarr", consolidated=False)
    np.testing.assert_array_equal(ds["z"].values, DEPTHS_MM)
    assert ds["z"].attrs["units"] == "mm"
    np.testing.assert_array_equal(ds["0"].sel(z=DEPTHS_MM[24]).values, volume[24])
    Image.from_zarr(zarr.open_group(str(path), mode="r"))
    write_volume(path, volume[:2], {})  # no depths: no coordinate
    assert "z" not in xr.open_dataset(str(path), engine="zarr", consolidated=False).coords
