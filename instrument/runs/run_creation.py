"""Creating a run store: its whole layout at once, claimed atomically, removed again
when writing it fails (the layout is described in :mod:`instrument.runs.runstore`'s module
docstring; :meth:`RunStore.create <instrument.runs.runstore.RunStore.create>` is
:func:`create_run`).

The schema version a new run records, the frame compressors a sharded (video) run may
use, and the software version and UTC time stamps a run's attributes hold are
declared here.
"""

from __future__ import annotations

import datetime as _dt
import os
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from diffuserlab.jsonio import jsonable

from .ome import describe_run, run_dims
from .run_description import record_description
from .run_integrity import LOCK_NAME, RunStoreError, lock_problem, write_lock
from .run_layout import RUN_ARRAYS, record_layout
from .run_paths import (
    CREATOR_ATTR,
    claim_run_dir,
    discard_partial_run,
    is_run_store,
    remove_replaced_run,
)

__all__ = ["FRAME_COMPRESSORS", "SCHEMA_VERSION", "create_run", "exists_text",
           "frame_compressors", "software_version", "utc_now"]

#: Version of the layout above; bumped on any incompatible change.
SCHEMA_VERSION = 2
#: Frame compressors a sharded run may use: "default" is zarr's own (zstd level 0,
#: what unsharded runs use), "none" stores raw bytes, "zstd1" is zstd level 1,
#: "blosc-lz4" is blosc lz4 with bit shuffle (all lossless).
FRAME_COMPRESSORS = ("default", "none", "zstd1", "blosc-lz4")


def frame_compressors(name: str):
    """The zarr ``compressors`` argument for one of :data:`FRAME_COMPRESSORS`."""
    from zarr.codecs import BloscCodec, ZstdCodec

    choices = {"default": "auto", "none": None, "zstd1": ZstdCodec(level=1),
               "blosc-lz4": BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle")}
    if name not in choices:
        raise RunStoreError(f"unknown frame compressor {name!r}; use one of "
                            f"{list(FRAME_COMPRESSORS)}")
    return choices[name]


def software_version() -> str:
    """The installed diffuserlab version (``"unknown"`` when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("diffuserlab")
    except PackageNotFoundError:
        return "unknown"


def utc_now() -> str:
    """Current UTC time, ISO 8601."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def exists_text(path: Path, meanwhile: bool = False) -> str:
    """The refusal of a new run at an existing ``path`` (one line)."""
    how = " (another process created it meanwhile)" if meanwhile else ""
    return (f"{path} already exists{how}; choose another --out or pass --overwrite to "
            "replace it")


def create_run(cls, path: str | Path, *, plan_name: str, plan_params: Mapping[str, Any],
               points: Sequence[Mapping[str, Any]], frame_tags: Sequence[Sequence[str]],
               frame_shape: tuple[int, int], frame_dtype, coord_names: Sequence[str],
               bench_config: Mapping[str, Any] | None = None,
               device_settings: Mapping[str, Any] | None = None, note: str = "",
               overwrite: bool = False, shard_frames: int | None = None,
               compressor: str = "default",
               coord_specs: Mapping[str, Mapping[str, str]] | None = None,
               keep_lock: bool | None = None):
    """Create the store of a new run with its whole layout
    (:meth:`RunStore.create <instrument.runs.runstore.RunStore.create>` is this function
    bound to its class).

    Parameters
    ----------
    cls : type
        The store class (:class:`instrument.runs.runstore.RunStore`), built on the new
        run's group as ``cls(path, group, writable=True)``.
    path : str or Path
        Directory to create (conventionally ``NAME.zarr``).
    plan_name : str
    plan_params : Mapping
        JSON-able parameters that rebuild the plan (stored for resume).
    points : sequence of Mapping
        One JSON-able description per plan point (e.g. ``{"z_mm": 20.0}``).
    frame_tags : sequence of sequence of str
        Per point, the tag of each frame it captures, in order (its length is
        the point's frame count).
    frame_shape : (rows, cols)
    frame_dtype : numpy dtype
        The camera's frame dtype.
    coord_names : sequence of str
        Names of the per-frame coordinates.
    bench_config, device_settings : Mapping, optional
        Snapshots stored with the run.
    note : str
        The operator's note.
    overwrite : bool
        Replace an existing run store at ``path`` (recognised by the schema
        marker in its ``zarr.json``; nothing else is deleted). The lock comes first:
        the run replaced is locked by this call (refused, naming the holder, when
        another process holds it) before it is moved aside and removed, and the new
        run is locked from the moment its directory exists, so of two processes
        replacing one run at once the second is refused and never removes the
        first one's new run.

        The run's directory is created atomically (:func:`instrument.runs.run_paths.claim_run_dir`):
        of processes creating the same path at once one succeeds, the others are
        refused and touch nothing. A failure while the layout is written removes
        the run again (only this call's own).
    shard_frames : int, optional
        Store ``k`` frames per shard file (video runs; see "Sharded runs" in
        :mod:`instrument.runs.runstore`'s notes). None (default): one frame per file, as before.
    compressor : str
        One of :data:`FRAME_COMPRESSORS`, for a sharded run's frames
        (unsharded runs always use "default").
    coord_specs : Mapping, optional
        ``{name: {"unit": str, "dim": str}}`` for every coordinate
        (:func:`instrument.runs.coords.coord_specs`), stored in the ``coords`` array's
        attributes ``units`` and ``dims``
        (:meth:`RunStore.coord_info <instrument.runs.runstore.RunStore.coord_info>` reads them
        back).
    keep_lock : bool, optional
        Return the store holding the run's writer lock (``RUN.zarr/.lock``, taken when
        the directory was created; :meth:`RunStore.lock
        <instrument.runs.runstore.RunStore.lock>` is then a no-op and
        :meth:`~instrument.runs.runstore.RunStore.unlock` releases it). Default: with
        ``overwrite`` (a replaced run's writer keeps it, so no other process replaces
        the new run before it is written); without it the lock is released once the
        layout is written.

    Returns
    -------
    RunStore
        The new run's store (a ``cls``), open for writing; its ``creation_token``
        is the one the run records as its creator's.

    Raises
    ------
    RunStoreError
        ``path`` exists (and ``overwrite`` is False) or was created by another
        process meanwhile, ``path`` exists and is not
        a run store (a file or another directory: never replaced), the run at
        ``path`` is locked by a writer (named) or being created by another process,
        the layout is empty, ``shard_frames``
        is not a positive integer or ``compressor`` is unknown, ``coord_specs``
        lacks a coordinate.
    """
    import zarr

    path = Path(path)
    if path.exists() and not overwrite:
        raise RunStoreError(exists_text(path))
    if path.exists() and not is_run_store(path):
        raise RunStoreError(
            f"not replacing {path}: it is not a diffuserlab run store (only a run's "
            "directory is ever deleted); choose another name or remove it yourself")
    if (path / LOCK_NAME).exists():
        raise RunStoreError(f"not replacing {path}: {lock_problem(path)}")
    k = 1 if shard_frames is None else shard_frames
    if not isinstance(k, int | np.integer) or isinstance(k, bool) or k < 1:
        raise RunStoreError(f"shard_frames={shard_frames!r} is invalid; use an integer "
                            ">= 1 or None")
    compressors = frame_compressors(compressor)
    if shard_frames is None and compressor != "default":
        raise RunStoreError(f"compressor {compressor!r} needs shard_frames (a sharded "
                            "video run); unsharded runs use the default")
    missing = [n for n in coord_names if coord_specs is not None and n not in coord_specs]
    if missing:
        raise RunStoreError(f"coord_specs lacks the unit of {missing}")
    if len(points) != len(frame_tags) or not points:
        raise RunStoreError("a run needs at least one point and one tag list per point "
                            "(an empty list for a point without frames)")
    tags = sorted({t for per in frame_tags for t in per})
    point_of = np.concatenate([np.full(len(per), i, np.int32)
                               for i, per in enumerate(frame_tags)]).astype(np.int32)
    tag_of = np.array([tags.index(t) for per in frame_tags for t in per], np.int16)
    n = int(point_of.size)
    rows, cols = (int(v) for v in frame_shape)
    lock = {"pid": os.getpid(), "host": socket.gethostname(), "started_utc": utc_now()}
    if overwrite and path.exists():  # locked first, then renamed aside and removed
        _replace_locked(path, lock)
    try:
        creator = claim_run_dir(path)
    except FileExistsError:  # another process created it since the check above
        raise RunStoreError(exists_text(path, meanwhile=True)) from None
    if not write_lock(path, lock):  # another replacer locked the empty folder first
        problem = lock_problem(path)
        discard_partial_run(path, token=creator["token"], claimed=True)
        raise RunStoreError(f"not creating {path}: {problem}")
    try:  # the layout; a failure removes this call's own half-made run
        group = zarr.create_group(str(path), zarr_format=3)  # beside its .lock
        k = int(min(k, max(n, 1)))
        sharding = {} if shard_frames is None else {"shards": (k, rows, cols),
                                                    "compressors": compressors}
        dims = run_dims({"plan": {"name": plan_name, "points": list(points)}})
        group.create_array("frames", shape=(n, rows, cols), chunks=(1, rows, cols),
                           dtype=np.dtype(frame_dtype), fill_value=0,
                           dimension_names=dims["frames"], **sharding)
        coords = group.create_array("coords", shape=(n, len(coord_names)),
                                    chunks=(k, len(coord_names)), dtype="float64",
                                    fill_value=np.nan, dimension_names=dims["coords"])
        coords.attrs["names"] = list(coord_names)
        if coord_specs is not None:
            coords.attrs["units"] = {n: str(coord_specs[n]["unit"]) for n in coord_names}
            coords.attrs["dims"] = {n: str(coord_specs[n]["dim"]) for n in coord_names}
        group.create_array("crc32", shape=(n,), chunks=(k,), dtype="uint32", fill_value=0,
                           dimension_names=dims["crc32"])
        group.create_array("done", shape=(n,), chunks=(k,), dtype="uint8", fill_value=0,
                           dimension_names=dims["done"])
        group.create_array("point", shape=(n,), chunks=(max(n, 1),), dtype="int32",
                           dimension_names=dims["point"])[:] = point_of
        group.create_array("tag", shape=(n,), chunks=(max(n, 1),), dtype="int16",
                           dimension_names=dims["tag"])[:] = tag_of
        group.create_group("products")
        group.update_attributes(jsonable({  # one write: never a half-written record
            "schema": "diffuserlab-run", "schema_version": SCHEMA_VERSION,
            "software_version": software_version(), "created_utc": utc_now(),
            "started_utc": None, "ended_utc": None, "status": "created",
            "plan": {"name": plan_name, "params": dict(plan_params), "points": list(points),
                     "frames_per_point": [len(per) for per in frame_tags]},
            "tags": tags, "bench_config": dict(bench_config or {}),
            "device_settings": dict(device_settings or {}), "note": note,
            "resumes": [], "warnings": [], "error": None, "summary": {},
            CREATOR_ATTR: creator,
        }))
        if shard_frames is not None:
            group.attrs["storage"] = {"shard_frames": k, "compressor": compressor}
        describe_run(group)
        record_layout(group, path, RUN_ARRAYS)  # what every later open compares with
        record_description(group, path, RUN_ARRAYS)  # what runs verify compares with
        store = cls(path, group, writable=True)
    except BaseException:
        discard_partial_run(path, token=creator["token"], claimed=True)
        raise
    store.creation_token = creator["token"]
    if keep_lock if keep_lock is not None else overwrite:
        store._locked = True
    else:
        (path / LOCK_NAME).unlink(missing_ok=True)
    return store


def _replace_locked(path: Path, lock: dict) -> None:
    """Remove the run at ``path`` for a new one, holding its writer lock first: refused
    (naming the holder) when another process writes it, replaces it, or is creating a
    run there; nothing when it is gone already (the new run's claim decides)."""
    try:
        locked = write_lock(path, lock)
    except (FileNotFoundError, NotADirectoryError):  # moved aside meanwhile
        return
    if not locked:
        raise RunStoreError(f"not replacing {path}: {lock_problem(path)}")
    if not is_run_store(path):  # a folder another process is filling: not ours to touch
        (path / LOCK_NAME).unlink(missing_ok=True)
        raise RunStoreError(f"not replacing {path}: another process is creating a run "
                            "there; choose another --out, or wait for it and try again")
    remove_replaced_run(path)
