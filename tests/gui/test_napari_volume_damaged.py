"""The napari reader on recon3d volumes whose OME description was damaged after
writing: one clear error (the project's InputError, one line naming the problem and
the fix), never a KeyError or ValueError from inside the reader. Each store is written
by the project's own writer and then its ``ome`` block edited, as a hand edit or
another tool would. The reader function is called directly (no napari needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from diffuserlab.errors import InputError
from gui.napari_plugin.reader import get_reader, read_volume
from instrument.writer.products import write_volume


def _volume(path: Path) -> Path:
    write_volume(path, np.ones((3, 8, 10), np.float32), {"depths_mm": [1.0, 2.0, 4.0]},
                 pitch_um=6.9)
    return path


def _edit(path: Path, change) -> None:
    import zarr

    group = zarr.open_group(str(path), mode="r+")
    attrs = dict(group.attrs)
    change(attrs)
    group.attrs.put(attrs)


def _drop_ome(a):
    del a["ome"]


def _drop_axis(a):
    a["ome"]["multiscales"][0]["axes"].pop()


def _drop_scale(a):
    a["ome"]["multiscales"][0]["datasets"][0]["coordinateTransformations"][0]["scale"].pop()


def _missing_dataset(a):
    a["ome"]["multiscales"][0]["datasets"][0]["path"] = "1"


def _no_datasets(a):
    a["ome"]["multiscales"][0]["datasets"] = []


def _axis_without_name(a):
    del a["ome"]["multiscales"][0]["axes"][0]["name"]


def _axes_not_a_list(a):
    a["ome"]["multiscales"][0]["axes"] = "zyx"


def _text_scale(a):
    a["ome"]["multiscales"][0]["datasets"][0]["coordinateTransformations"][0]["scale"] = [
        "one", 6.9, 6.9]


DAMAGE = {
    "ome block missing": (_drop_ome, "lacks 'ome'"),
    "short an axis": (_drop_axis, "2 axes and 3 scales"),
    "short a scale": (_drop_scale, "3 axes and 2 scales"),
    "names a missing dataset": (_missing_dataset, "dataset '1'"),
    "no dataset": (_no_datasets, "empty list"),
    "an axis without a name": (_axis_without_name, "lacks 'name'"),
    "axes not a list": (_axes_not_a_list, "malformed"),
    "a scale that is no number": (_text_scale, "malformed"),
}


@pytest.mark.parametrize("name", DAMAGE)
def test_a_damaged_volume_description_is_one_clear_error(tmp_path, name):
    """Before: KeyError 'ome' / 'multiscales', ValueError from zip(strict=True), or
    zarr's KeyError for a dataset that is not there."""
    change, words = DAMAGE[name]
    path = _volume(tmp_path / "vol.zarr")
    _edit(path, change)
    assert get_reader(str(path)) is read_volume  # still ours: the marker is there
    with pytest.raises(InputError) as info:
        read_volume(str(path))
    line = str(info.value)
    assert "\n" not in line and str(path) in line and words in line, line
    assert "recon3d --out" in line  # the fix


def test_an_intact_volume_still_reads(tmp_path):
    path = _volume(tmp_path / "vol.zarr")
    ((data, kwargs, kind),) = read_volume(str(path))
    assert data.shape == (3, 8, 10) and kind == "image"
    # uneven depths: a ``plane`` axis, or (OME axes t, c, z, y, x) z at their mean
    # spacing from the first depth
    first = (kwargs["axis_labels"][0], kwargs["scale"][0], kwargs["translate"][0])
    assert first in (("plane", 1.0, 0.0), ("z", 1500.0, 1000.0)), first
    assert kwargs["axis_labels"][1:] == ["y", "x"]
    assert kwargs["scale"][1:] == pytest.approx([6.9, 6.9])
    assert kwargs["metadata"]["depths_mm"] == [1.0, 2.0, 4.0]
