"""instrument.writer.products.write_volume and instrument.atomic.write_json write
atomically: a failure while writing leaves no partial file (or Zarr directory) under the
final name, keeps an earlier output, and leaves no temporary file behind."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import zarr

from instrument.atomic import write_json
from instrument.writer.products import write_volume

VOLUME = np.arange(2 * 4 * 5, dtype=np.float32).reshape(2, 4, 5)


@pytest.mark.parametrize("name", ["v.tif", "v.zarr"])
def test_write_volume_replaces_an_earlier_volume(tmp_path, name):
    path = tmp_path / name
    write_volume(path, VOLUME, {"depths_mm": [1.0, 2.0]})
    write_volume(path, 2 * VOLUME, {"depths_mm": [1.0, 2.0]})
    data = tifffile.imread(path) if name.endswith(".tif") else zarr.open_group(str(path))["0"][:]
    assert np.array_equal(data, 2 * VOLUME)
    assert [p.name for p in tmp_path.iterdir()] == [name]


@pytest.mark.parametrize("name, earlier", [("v.tif", False), ("v.tif", True),
                                           ("v.zarr", False), ("v.zarr", True)])
def test_write_volume_failure_leaves_no_partial_volume(tmp_path, monkeypatch, name, earlier):
    path = tmp_path / name
    if earlier:
        write_volume(path, VOLUME, {})
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))

    class Crash(RuntimeError):
        pass

    def crash(*args, **kwargs):
        raise Crash("disk went away")

    if name.endswith(".tif"):
        real = tifffile.imwrite

        def half(file, *args, **kwargs):
            real(file, VOLUME[:1])
            crash()

        monkeypatch.setattr(tifffile, "imwrite", half)
    else:
        monkeypatch.setattr(zarr.Array, "__setitem__", crash)
    with pytest.raises(Crash):
        write_volume(path, 3 * VOLUME, {})
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    if earlier:
        monkeypatch.undo()
        data = (tifffile.imread(path) if name.endswith(".tif")
                else zarr.open_group(str(path))["0"][:])
        assert np.array_equal(data, VOLUME)


def test_write_json_failure_keeps_the_earlier_file(tmp_path):
    path = write_json(tmp_path / "m.json", {"a": 1})
    with pytest.raises(TypeError):
        write_json(path, {"a": object()})
    assert path.read_text() == '{\n "a": 1\n}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]


def test_zarr_volume_is_an_ome_zarr_image(tmp_path):
    from ome_zarr_models.v05.image import Image

    path = tmp_path / "v.zarr"
    write_volume(path, VOLUME, {"depths_mm": [1.0, 1.5]}, pitch_um=6.9)
    ms = Image.from_zarr(zarr.open_group(str(path), mode="r")).ome_attributes.multiscales[0]
    assert [(a.name, a.type, a.unit) for a in ms.axes] == [
        ("z", "space", "micrometer"), ("y", "space", "micrometer"),
        ("x", "space", "micrometer")]
    assert list(ms.datasets[0].coordinateTransformations[0].scale) == [500.0, 6.9, 6.9]
    # the first plane where it is: the z origin
    assert list(ms.datasets[0].coordinateTransformations[1].translation) == [1000.0, 0, 0]
    write_volume(path, np.ones((3, 4, 5), np.float32), {"depths_mm": [1.0, 3.0, 4.0],
                                                        "bin_factor": 2})
    ms = Image.from_zarr(zarr.open_group(str(path), mode="r")).ome_attributes.multiscales[0]
    # uneven depths: OME-Zarr has one scale per axis, the mean spacing, stated
    assert (ms.axes[0].name, ms.axes[0].unit) == ("z", "micrometer")
    assert list(ms.datasets[0].coordinateTransformations[0].scale) == [1500.0, 2.0, 2.0]
    assert ms.metadata["depths_mm"] == [1.0, 3.0, 4.0] and "z_scale" in ms.metadata
    # no pitch: one unit per sensor pixel, the binning as the scale (as napari shows it)
    assert ms.axes[1].unit is None


def test_a_volume_written_before_as_an_array_is_replaced(tmp_path):
    path = tmp_path / "v.zarr"
    zarr.create_array(str(path), shape=VOLUME.shape, dtype="float32")[:] = VOLUME
    write_volume(path, 2 * VOLUME, {})
    assert np.array_equal(zarr.open_group(str(path))["0"][:], 2 * VOLUME)
