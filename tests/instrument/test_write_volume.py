"""instrument.reconstruct_files.write_volume and write_json write atomically: a failure
while writing leaves no partial file (or Zarr directory) under the final name, keeps an
earlier output, and leaves no temporary file behind."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import zarr

from instrument.reconstruct_files import write_json, write_volume

VOLUME = np.arange(2 * 4 * 5, dtype=np.float32).reshape(2, 4, 5)


@pytest.mark.parametrize("name", ["v.tif", "v.zarr"])
def test_write_volume_replaces_an_earlier_volume(tmp_path, name):
    path = tmp_path / name
    write_volume(path, VOLUME, {"depths_mm": [1.0, 2.0]})
    write_volume(path, 2 * VOLUME, {"depths_mm": [1.0, 2.0]})
    data = tifffile.imread(path) if name.endswith(".tif") else zarr.open_array(str(path))[:]
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
        data = tifffile.imread(path) if name.endswith(".tif") else zarr.open_array(str(path))[:]
        assert np.array_equal(data, VOLUME)


def test_write_json_failure_keeps_the_earlier_file(tmp_path):
    path = write_json(tmp_path / "m.json", {"a": 1})
    with pytest.raises(TypeError):
        write_json(path, {"a": object()})
    assert path.read_text() == '{\n "a": 1\n}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]
