"""ome-zarr-py (the OME-Zarr reference reader, the ``interop`` extra) opens a run and
each of its image products with named axes and physical scales: the runs are read by
a library labs use, not only validated against the schema."""

from __future__ import annotations

import zarr

from tests.drivers.interop.clients import client

from .test_ome import BINNING, PITCH_UM, _every_product_kind, _sweep

ome_io = client("ome_zarr.io", "ome-zarr")
ome_reader = client("ome_zarr.reader", "ome-zarr")


def _image(path) -> tuple[list[str], tuple, list[float]]:
    """ome-zarr-py's reading of the image at ``path``: axes, shape, scale."""
    nodes = list(ome_reader.Reader(ome_io.parse_url(str(path)))())
    assert nodes, f"ome-zarr-py found no image at {path}"
    node = nodes[0]
    assert any(type(s).__name__ == "Multiscales" for s in node.specs), node.specs
    transforms = {t["type"]: t for t in node.metadata["coordinateTransformations"][0]}
    assert set(transforms) == {"scale", "translation"}  # every image says its origin
    return ([a["name"] for a in node.metadata["axes"]], tuple(node.data[0].shape),
            transforms["scale"]["scale"])


def test_ome_zarr_py_opens_the_run_and_each_image_product(tmp_path):
    store = _sweep(tmp_path / "s.zarr")
    images = _every_product_kind(store)
    group = zarr.open_group(store.path, mode="r")
    pitch = PITCH_UM * BINNING
    axes, shape, scale = _image(store.path)  # the frames, counted in time order
    assert axes == ["t", "y", "x"] and shape == group["frames"].shape
    assert scale[1:] == [pitch, pitch]
    for name in images:  # every product its own image (before: none but the frames)
        axes, shape, scale = _image(store.path / "products" / name)
        assert shape == group[f"products/{name}/0"].shape, name
        # one letter each, y and x last (a binned product too: binning is its scale)
        assert axes[-2:] == ["y", "x"] and len(axes) == len(shape), (name, axes)
        assert all(a in "tczyx" and len(a) == 1 for a in axes), (name, axes)
    axes, _, scale = _image(store.path / "products" / "psf_stack")
    assert axes[0] == "z" and scale[0] == 1000.0  # evenly spaced depths in micrometres
