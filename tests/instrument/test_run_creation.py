"""A new run's directory is claimed atomically, and a process removes only the runs it
created itself (:func:`instrument.runs.run_paths.discard_partial_run`, the creator's token);
outputs of a group take only free names (:func:`instrument.atomic.output_group`).

The races between two real processes are in ``tests/faults/test_output_races.py``.
"""

from __future__ import annotations

import errno

import numpy as np
import pytest
import zarr

import instrument.runs.run_creation as run_creation
from instrument.atomic import atomic_dir, output_group
from instrument.runs.run_paths import CREATOR_ATTR, creator_of, discard_partial_run
from instrument.runs.runstore import RunStore, RunStoreError, is_run_store
from instrument.writer.files import save_image
from recon.errors import ReconInputError


def _create(path, **kw):
    return RunStore.create(path, plan_name="p", plan_params={}, points=[{"z": 1.0}],
                           frame_tags=[["psf", "psf"]], frame_shape=(4, 6),
                           frame_dtype=np.uint16, coord_names=["exposure_s"], **kw)


def _names(folder):
    return sorted(p.name for p in folder.iterdir())


def test_discard_partial_run_removes_only_a_run_this_process_created(tmp_path):
    mine = _create(tmp_path / "new" / "r.zarr")
    theirs = _create(tmp_path / "theirs.zarr")  # as if created by another process
    assert mine.creation_token and mine.creation_token != theirs.creation_token
    assert creator_of(mine.path)["token"] == mine.creation_token
    assert RunStore.open(mine.path).creation_token is None  # only the creator holds it
    # another's run: never removed, whatever the token, nor without one
    assert not discard_partial_run(theirs.path, token=mine.creation_token)
    assert not discard_partial_run(theirs.path, token=None)
    assert not discard_partial_run(theirs.path, token=mine.creation_token, claimed=True)
    # a run written before creators were recorded: not this process's either
    group = zarr.open_group(str(theirs.path), mode="r+", zarr_format=3)
    del group.attrs[CREATOR_ATTR]
    assert creator_of(theirs.path) is None
    assert not discard_partial_run(theirs.path, token=mine.creation_token)
    assert is_run_store(theirs.path) and RunStore.open(theirs.path).n_frames == 2
    # its own run: removed, with the folder made for it, nothing hidden left
    assert discard_partial_run(mine.path, [tmp_path / "new"], token=mine.creation_token)
    assert _names(tmp_path) == ["theirs.zarr"]


def test_create_refuses_a_path_another_process_claimed_meanwhile(tmp_path, monkeypatch):
    """The directory appears between create's existence check and its own claim: the
    claim (os.mkdir) fails, create is refused in one line, the other's files stay."""
    path = tmp_path / "r.zarr"
    claim = run_creation.claim_run_dir

    def another_first(p):
        p.mkdir()
        (p / "theirs.txt").write_text("another process's run")
        return claim(p)

    monkeypatch.setattr(run_creation, "claim_run_dir", another_first)
    with pytest.raises(RunStoreError, match="already exists .another process created it "
                       "meanwhile.; choose another --out or pass --overwrite") as exc:
        _create(path)
    assert "\n" not in str(exc.value)
    assert _names(path) == ["theirs.txt"] and _names(tmp_path) == ["r.zarr"]


def test_create_removes_its_own_half_made_run(tmp_path, monkeypatch):
    def full_disk(group):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(run_creation, "describe_run", full_disk)
    with pytest.raises(OSError, match="No space"):
        _create(tmp_path / "o" / "r.zarr")
    assert _names(tmp_path) == ["o"] and _names(tmp_path / "o") == []


def test_overwrite_replaces_a_run_and_leaves_nothing_aside(tmp_path):
    old = _create(tmp_path / "r.zarr")
    new = _create(tmp_path / "r.zarr", overwrite=True)
    assert new.creation_token != old.creation_token
    assert creator_of(tmp_path / "r.zarr")["token"] == new.creation_token
    assert _names(tmp_path) == ["r.zarr"]


def test_an_output_group_without_replace_keeps_a_name_taken_meanwhile(tmp_path):
    """Without --overwrite, the outputs of a group go in place only under free names:
    one written meanwhile by another process is kept, none of the group's is put in
    place (the free names claimed are released), no temporary is left."""
    vol, png = tmp_path / "v.zarr", tmp_path / "v_mip.png"
    with pytest.raises(ReconInputError, match=r"v_mip.png already exists .another process "
                       r"wrote it meanwhile; it is kept.; choose another --out"):
        with output_group(replace=False):
            with atomic_dir(vol) as tmp:
                (tmp / "zarr.json").write_text("{}")
            save_image(png, np.ones((4, 4), np.float32))
            png.write_bytes(b"theirs")  # after this command checked its outputs
    assert _names(tmp_path) == ["v_mip.png"] and png.read_bytes() == b"theirs"
    (tmp_path / "v.zarr").mkdir()
    (tmp_path / "v.zarr" / "theirs").write_text("x")
    png.unlink()
    with pytest.raises(ReconInputError, match="v.zarr already exists"):
        with output_group(replace=False):
            save_image(png, np.ones((4, 4), np.float32))
            with atomic_dir(vol) as tmp:
                (tmp / "zarr.json").write_text("{}")
    assert _names(tmp_path) == ["v.zarr"] and _names(vol) == ["theirs"]
    # free names: placed, files and folders
    (vol / "theirs").unlink()
    vol.rmdir()
    with output_group(replace=False):
        with atomic_dir(vol) as tmp:
            (tmp / "zarr.json").write_text("{}")
        save_image(png, np.ones((4, 4), np.float32))
    assert _names(tmp_path) == ["v.zarr", "v_mip.png"] and _names(vol) == ["zarr.json"]
