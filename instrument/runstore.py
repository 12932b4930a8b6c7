"""Run storage: one Zarr v3 store per run (docs/architecture.md, "Storage").

Layout of ``RUN.zarr``::

    zarr.json            attributes: schema and software versions, plan (name, params,
                         points, frame tags), bench config and device settings
                         snapshots, operator note, status, start/end times, resumes,
                         warnings, ``created_by`` (the creating process: pid, host,
                         token; instrument.run_paths); ``arrays``: each array's
                         shape, dtype, chunks, codecs and fill value as written
                         (instrument.run_layout; ``products/`` keeps the same for
                         its products); ``described``: the ``ome`` block and the
                         arrays' dimension names as written
                         (instrument.run_description; likewise)
    frames               (n_frames, rows, cols) camera dtype, one frame per chunk
    coords               (n_frames, n_coords) float64, one row per chunk; column names
                         in its attribute ``names`` (stage positions, LED, SLM pattern
                         id, exposure, gain, timestamps, saturation count, ...), their
                         units and dimension names in ``units`` and ``dims``
                         ({name: str}, from instrument.coords); Zarr dimension names
                         (the frames' first axis, "coord"; ("frame", "coord") before
                         the OME-Zarr description)
    crc32                (n_frames,) uint32, one element per chunk: CRC-32 of the frame's
                         bytes (little-endian) then of its coordinate row (float64
                         little-endian), written before the done flag (schema 2; schema-1
                         stores have none and are read without verification)
    done                 (n_frames,) uint8, one element per chunk: 1 once the frame, its
                         coordinates and its checksum are written
    point                (n_frames,) int32: the plan point of each frame (fixed)
    tag                  (n_frames,) int16: index into the ``tags`` attribute (fixed)
    storage attribute    present on sharded (video) runs only: {"shard_frames": k,
                         "compressor": NAME}; see "Sharded runs" below
    .lock                JSON {pid, host, started_utc} while a process writes the run
                         (:meth:`RunStore.lock`); not part of the Zarr hierarchy
    products/NAME/0      what a plan derives from the frames (PSF stack, maps, ...):
                         an image product is an OME-Zarr image group ``products/NAME``
                         (its ``ome`` block) holding its array ``0``; a table or LUT is
                         an array ``products/NAME`` (as every product of a run written
                         before the image groups; :mod:`instrument.product_nodes` reads
                         either); the array's attribute ``crc32``: CRC-32 per plane
                         (first axis) of a 3-D product, of the whole array otherwise
    dimension_names, ome every array names its dimensions (the frames' first axis
                         ``t`` for a video, named for what a sweep's points vary
                         otherwise, shared by the per-frame arrays); the root's and each
                         product group's ``ome`` attribute describe them as OME-Zarr
                         0.5 images (:mod:`instrument.ome`; ``runs upgrade`` adds them
                         to a run written before and moves its image products into
                         their groups)

The whole layout is fixed when the run is created (the plan declares every point
and frame up front), so the metadata never changes while frames are written. Each
chunk is written atomically (zarr's local store writes a temporary file and renames
it) in the order frame, coordinates, checksum, done flag: a reader that trusts only
frames flagged done never sees a partial one, and a crash loses at most the frame in
flight. Reading a frame or a product verifies its checksum, so a chunk file deleted
(zarr would return zeros) or altered afterwards is reported (RunStoreError naming the
frame or product plane) instead of being read as data; :meth:`RunStore.verify`
checks a whole run.

Sharded runs (video, ``RunStore.create(shard_frames=k)``): ``frames`` keeps one
frame per inner chunk but groups ``k`` frames per shard file (zarr's sharding
codec), and ``coords``, ``crc32`` and ``done`` hold ``k`` frames per chunk, so a
block of ``k`` frames costs 4 files instead of ``4 k``. Writing one inner chunk
rewrites its whole shard, so such runs are written a shard at a time with
:meth:`RunStore.write_frames` (frames, coordinates, checksums, then done flags): a
crash loses at most the shard being written. Readers are unchanged (same arrays,
shapes and meaning; schema 2).
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from diffuserlab.jsonio import jsonable

from .ome import describe_run, run_dims
from .run_description import record_description
from .run_integrity import (
    LOCK_NAME,
    DamagedFrameError,
    RunStoreError,
    frame_crc,
    lock_problem,
    read_lock,
    write_lock,
)
from .run_layout import RUN_ARRAYS, layout_problems, record_layout
from .run_paths import (
    CREATOR_ATTR,
    claim_run_dir,
    discard_partial_run,
    is_run_store,
    product_location,
    remove_replaced_run,
)
from .run_products import ProductsMixin
from .run_reading import FrameRecord, RunReadingMixin

__all__ = ["FRAME_COMPRESSORS", "SCHEMA_VERSION", "DamagedFrameError", "FrameRecord", "RunStore",
           "RunStoreError", "discard_partial_run", "is_run_store", "product_location",
           "software_version", "utc_now"]

log = logging.getLogger(__name__)

#: Version of the layout above; bumped on any incompatible change.
SCHEMA_VERSION = 2
#: Schema versions this diffuserlab reads (1: no checksums).
READABLE_SCHEMAS = (1, 2)
#: Frame compressors a sharded run may use: "default" is zarr's own (zstd level 0,
#: what unsharded runs use), "none" stores raw bytes, "zstd1" is zstd level 1,
#: "blosc-lz4" is blosc lz4 with bit shuffle (all lossless).
FRAME_COMPRESSORS = ("default", "none", "zstd1", "blosc-lz4")


def _frame_compressors(name: str):
    """The zarr ``compressors`` argument for one of :data:`FRAME_COMPRESSORS`."""
    from zarr.codecs import BloscCodec, ZstdCodec

    choices = {"default": "auto", "none": None, "zstd1": ZstdCodec(level=1),
               "blosc-lz4": BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle")}
    if name not in choices:
        raise RunStoreError(f"unknown frame compressor {name!r}; use one of "
                            f"{list(FRAME_COMPRESSORS)}")
    return choices[name]


#: Attributes every run's zarr.json holds (a store lacking one is damaged).
REQUIRED_ATTRS = ("schema_version", "software_version", "status", "plan", "tags",
                  "bench_config", "device_settings", "note", "resumes", "warnings", "summary")
REQUIRED_PLAN_ATTRS = ("name", "params", "points", "frames_per_point")


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


def _exists_text(path: Path, meanwhile: bool = False) -> str:
    """The refusal of a new run at an existing ``path`` (one line)."""
    how = " (another process created it meanwhile)" if meanwhile else ""
    return (f"{path} already exists{how}; choose another --out or pass --overwrite to "
            "replace it")


class RunStore(ProductsMixin, RunReadingMixin):
    """A run's Zarr v3 store: create, write frames, read (also while being written).

    Use :meth:`create` for a new run and :meth:`open` for an existing one.

    Attributes
    ----------
    path : pathlib.Path
    attrs : dict
        The run's attributes (a snapshot; :meth:`refresh` re-reads them).
    layout_damage : dict
        ``{array: problem line}`` for each array whose metadata differs from what the
        run recorded when it wrote it (:mod:`instrument.run_layout`); such arrays are
        never read or written (:meth:`require_layout`), :meth:`verify` lists them.
    creation_token : str or None
        Set on the store :meth:`create` returns: the token its run records as its
        creator's (:data:`instrument.run_paths.CREATOR_ATTR`), the proof
        :func:`instrument.run_paths.discard_partial_run` asks for; None on a store
        opened with :meth:`open`.
    """

    creation_token: str | None = None

    def __init__(self, path: Path, group, writable: bool) -> None:
        self.path = Path(path)
        self._group = group
        self.writable = writable
        self.attrs = dict(group.attrs)
        if self.attrs.get("schema") != "diffuserlab-run":
            raise RunStoreError(f"{self.path} is a Zarr store but not a diffuserlab run")
        if self.attrs.get("schema_version") not in READABLE_SCHEMAS:
            raise RunStoreError(
                f"{self.path} has run schema {self.attrs.get('schema_version')}, this "
                f"diffuserlab reads {list(READABLE_SCHEMAS)}; open it with the version that wrote "
                f"it ({self.attrs.get('software_version')})")
        missing = [k for k in REQUIRED_ATTRS if k not in self.attrs]
        plan = self.attrs.get("plan")
        if isinstance(plan, Mapping):
            missing += [f"plan.{k}" for k in REQUIRED_PLAN_ATTRS if k not in plan]
        elif "plan" not in missing:
            missing.append("plan")
        if missing:
            raise RunStoreError(
                f"{self.path} is damaged: its zarr.json lacks {', '.join(missing)}; restore "
                "zarr.json from a backup copy of the run (the frames are not affected)")
        # the arrays' metadata against the run's record, before anything is read by it
        self.layout_damage = layout_problems(self.path, self.attrs)
        unusable = [self.layout_damage[n] for n in ("point", "tag") if n in self.layout_damage]
        if unusable:
            raise RunStoreError(unusable[0])
        try:
            self._coord_names = list(self._group["coords"].attrs["names"])
            self._point = np.asarray(self._group["point"][:])
            self._tag = np.asarray(self._group["tag"][:])
            for name in ("frames", "done", "products"):
                self._group[name]
        except (KeyError, ValueError, TypeError, OSError) as exc:
            raise RunStoreError(
                f"{self.path} is damaged: its layout is unreadable ({type(exc).__name__}: "
                f"{exc}); restore the run from a backup copy") from None
        # (a file check: listing the group would warn about the .lock file)
        self.has_checksums = (self.path / "crc32" / "zarr.json").is_file()

    # ------------------------------------------------------------------ create / open
    @classmethod
    def create(cls, path: str | Path, *, plan_name: str, plan_params: Mapping[str, Any],
               points: Sequence[Mapping[str, Any]], frame_tags: Sequence[Sequence[str]],
               frame_shape: tuple[int, int], frame_dtype, coord_names: Sequence[str],
               bench_config: Mapping[str, Any] | None = None,
               device_settings: Mapping[str, Any] | None = None, note: str = "",
               overwrite: bool = False, shard_frames: int | None = None,
               compressor: str = "default",
               coord_specs: Mapping[str, Mapping[str, str]] | None = None) -> RunStore:
        """Create the store of a new run with its whole layout.

        Parameters
        ----------
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
            marker in its ``zarr.json``; nothing else is deleted).

            The run's directory is created atomically (:func:`instrument.run_paths.claim_run_dir`):
            of processes creating the same path at once one succeeds, the others are
            refused and touch nothing. A failure while the layout is written removes
            the run again (only this call's own).
        shard_frames : int, optional
            Store ``k`` frames per shard file (video runs; see "Sharded runs" in
            the module notes). None (default): one frame per file, as before.
        compressor : str
            One of :data:`FRAME_COMPRESSORS`, for a sharded run's frames
            (unsharded runs always use "default").
        coord_specs : Mapping, optional
            ``{name: {"unit": str, "dim": str}}`` for every coordinate
            (:func:`instrument.coords.coord_specs`), stored in the ``coords`` array's
            attributes ``units`` and ``dims`` (:meth:`coord_info` reads them back).

        Raises
        ------
        RunStoreError
            ``path`` exists (and ``overwrite`` is False) or was created by another
            process meanwhile, ``path`` exists and is not
            a run store (a file or another directory: never replaced), the run at
            ``path`` is locked by a writer, the layout is empty, ``shard_frames``
            is not a positive integer or ``compressor`` is unknown, ``coord_specs``
            lacks a coordinate.
        """
        import zarr

        path = Path(path)
        if path.exists() and not overwrite:
            raise RunStoreError(_exists_text(path))
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
        compressors = _frame_compressors(compressor)
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
        if overwrite and path.exists():  # the run checked above: renamed aside, removed
            remove_replaced_run(path)
        try:
            creator = claim_run_dir(path)
        except FileExistsError:  # another process created it since the check above
            raise RunStoreError(_exists_text(path, meanwhile=True)) from None
        try:  # the layout; a failure removes this call's own half-made run
            group = zarr.open_group(str(path), mode="w-", zarr_format=3)
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
            group.attrs.update(jsonable({
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
        return store

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> RunStore:
        """Open an existing run, read-only (``"r"``, safe while another process writes)
        or for writing (``"r+"``, to resume or add products).

        Raises
        ------
        RunStoreError
            No run at ``path``, or of another schema version.
        """
        import zarr

        path = Path(path)
        if mode not in ("r", "r+"):
            raise RunStoreError(f"mode must be 'r' or 'r+', got {mode!r}")
        outer = next((p for p in [*path.parents, *path.absolute().parents]
                      if is_run_store(p)), None)
        if outer is not None and not is_run_store(path):
            raise RunStoreError(
                f"{path} is inside the run store {outer}, not a run itself; give the run's "
                f"folder: {outer}")
        if not (path / "zarr.json").is_file():
            raise RunStoreError(f"no run store at {path} (expected a directory with zarr.json)")
        try:
            group = zarr.open_group(str(path), mode=mode, zarr_format=3)
        except (ValueError, KeyError, TypeError) as exc:  # JSONDecodeError is a ValueError
            raise RunStoreError(
                f"{path}/zarr.json is damaged ({type(exc).__name__}: {exc}); restore it from a "
                "backup copy of the run (the frames are not affected)") from None
        return cls(path, group, writable=mode == "r+")

    def refresh(self) -> dict:
        """Re-read the attributes (another process may have changed them)."""
        import zarr

        self._group = zarr.open_group(str(self.path), mode="r+" if self.writable else "r",
                                      zarr_format=3)
        self.attrs = dict(self._group.attrs)
        self.layout_damage = layout_problems(self.path, self.attrs)
        return self.attrs

    # ------------------------------------------------------------------ writer lock
    def lock(self) -> None:
        """Claim the run for this process: create ``RUN.zarr/.lock`` atomically.

        Raises
        ------
        RunStoreError
            Another writer holds the run (its pid and host named), or a stale lock
            is left by a process that is gone (never broken silently: remove it
            after checking no one writes the run).
        """
        self._require_writable()
        self.require_layout(*RUN_ARRAYS)  # never write into arrays described otherwise
        record = {"pid": os.getpid(), "host": socket.gethostname(), "started_utc": utc_now()}
        if not write_lock(self.path, record):
            raise RunStoreError(f"cannot write {self.path}: {lock_problem(self.path)}")
        self._locked = True

    def unlock(self) -> None:
        """Release the lock :meth:`lock` took (nothing if this object holds none)."""
        if getattr(self, "_locked", False):
            (self.path / LOCK_NAME).unlink(missing_ok=True)
            self._locked = False

    def upgrade(self) -> dict[str, list[str]]:
        """Bring a run written before to the current OME-Zarr 0.5 layout, in place.

        Dimension names go on every array that lacks them; each image product stored
        as an array ``products/NAME`` moves into its own image group as
        ``products/NAME/0`` (:func:`instrument.product_nodes.regroup`: directories
        renamed, the run's record of the array's layout renamed with it); the ``ome``
        blocks of the root and of each product group are written, and the one block of
        ``products/`` that listed the images before is removed. Only metadata
        documents (``zarr.json``) are written and directories renamed: no chunk file
        is rewritten, so every checksum still holds. Running it again changes
        nothing (and finishes a move an interruption cut short).

        Returns
        -------
        dict
            ``{"named": [...], "moved": [...]}``: the arrays whose dimension names
            were set (``frames``, ``products/NAME``) and the products moved into
            their groups; both empty for a run already in the current layout.

        Raises
        ------
        RunStoreError
            Read-only store, or another process writes the run (its lock).
        """
        import zarr

        from .ome import product_axes
        from .product_nodes import product_arrays, regroup

        self.lock()
        try:
            named = describe_run(self._group, arrays=True)
            products = zarr.open_group(str(self.path / "products"), mode="r+",
                                       zarr_format=3)
            images = [name for name, (key, arr) in product_arrays(products).items()
                      if key == name and product_axes(name, arr.shape, arr.attrs,
                                                      self.attrs) is not None]
            moved = regroup(products, self.path / "products", images)
            self._group = zarr.open_group(str(self.path), mode="r+", zarr_format=3)
            describe_run(self._group)
            self.refresh()
        finally:
            self.unlock()
        return {"named": named, "moved": moved}

    def lock_owner(self) -> dict | None:
        """The writer's lock record ``{pid, host, started_utc}``, None when unlocked."""
        return read_lock(self.path)

    # ------------------------------------------------------------------ layout
    @property
    def n_frames(self) -> int:
        return int(self._point.size)

    @property
    def n_points(self) -> int:
        return len(self.attrs["plan"]["points"])

    @property
    def frame_shape(self) -> tuple[int, int]:
        return tuple(self._group["frames"].shape[1:])

    @property
    def shard_frames(self) -> int | None:
        """Frames per shard file of a sharded (video) run, None for one frame per file."""
        shards = self._group["frames"].shards
        return None if shards is None else int(shards[0])

    @property
    def frame_dtype(self) -> np.dtype:
        """The run's frame dtype (the camera's)."""
        return np.dtype(self._group["frames"].dtype)

    @property
    def coord_names(self) -> list[str]:
        return list(self._coord_names)

    @property
    def tags(self) -> list[str]:
        return list(self.attrs["tags"])

    @property
    def status(self) -> str:
        return str(self.attrs["status"])

    def tag_of(self, index: int) -> str:
        """The tag the plan declared for frame ``index``."""
        return self.tags[int(self._tag[index])]

    def frame_range(self, point: int) -> range:
        """Frame indices of plan point ``point``."""
        idx = np.flatnonzero(self._point == point)
        if idx.size == 0:
            raise RunStoreError(f"the run has no point {point} (0..{self.n_points - 1})")
        return range(int(idx[0]), int(idx[-1]) + 1)

    # ------------------------------------------------------------------ progress
    def done(self, frames: range | None = None) -> np.ndarray:
        """Bool flags of the frames fully written: all (n_frames,), or a ``range``.

        Each flag is its own chunk (one file): read a range when only a point's frames
        matter.
        """
        sel = slice(None) if frames is None else slice(frames.start, frames.stop)
        return self._bookkeeping("done", sel).astype(bool)

    def _bookkeeping(self, name: str, sel: slice) -> np.ndarray:
        """``name`` (``done``, ``crc32``) read at ``sel``, its metadata checked first.

        Raises
        ------
        RunStoreError
            Its metadata differs from the run's record, or a chunk cannot be decoded
            (each such chunk file named, with the repair).
        """
        self.require_layout(name)
        arr = self._group[name]
        try:
            return np.asarray(arr[sel])
        except Exception as exc:  # a corrupt chunk fails to decode
            per = int(arr.chunks[0])
            start, stop, _ = sel.indices(arr.shape[0])
            bad = []
            for k in range(start // per, -(-stop // per)):
                try:
                    arr[k * per:(k + 1) * per]
                except Exception:
                    bad.append(f"{name}/c/{k}")
            what = {"done": "done flags", "crc32": "checksums"}.get(name, name)
            raise RunStoreError(
                f"the {what} of {self.path} cannot be read: {', '.join(bad) or name} "
                f"{'is' if len(bad) < 2 else 'are'} damaged ({exc}); restore "
                f"{'it' if len(bad) < 2 else 'them'} from a backup copy of the run") from exc

    def require_layout(self, *names: str) -> None:
        """Refuse to use arrays whose metadata differs from the run's record.

        Raises
        ------
        RunStoreError
            The first such array's problem (:mod:`instrument.run_layout`): what its
            ``zarr.json`` says, what the run recorded, the repair.
        """
        for name in names:
            if name in self.layout_damage:
                raise RunStoreError(self.layout_damage[name])

    def points_done(self) -> np.ndarray:
        """(n_points,) bool: points whose frames are all written."""
        done = self.done()
        out = np.ones(self.n_points, bool)
        np.logical_and.at(out, self._point, done)
        return out

    def first_incomplete_point(self) -> int | None:
        """Index of the first point not fully written, None if all are."""
        missing = np.flatnonzero(~self.points_done())
        return int(missing[0]) if missing.size else None

    # ------------------------------------------------------------------ writing
    def _require_writable(self) -> None:
        if not self.writable:
            raise RunStoreError(f"{self.path} is open read-only; open it with mode='r+'")

    def write_frame(self, index: int, image: np.ndarray, coords: Mapping[str, float]) -> None:
        """Store frame ``index``: image, then coordinates, then its done flag.

        Raises
        ------
        RunStoreError
            Read-only store, index out of range, wrong image shape, unknown coordinate,
            or values the run's dtype cannot hold exactly (an integer run refuses
            NaN/inf, non-integer floats and values outside its range instead of
            wrapping or rounding them).
        """
        self._require_writable()
        if not 0 <= index < self.n_frames:
            raise RunStoreError(f"frame {index} is outside the run's 0..{self.n_frames - 1}")
        image = np.asarray(image)
        if image.shape != self.frame_shape:
            raise RunStoreError(f"frame shape {image.shape} differs from the run's "
                                f"{self.frame_shape}; keep the camera ROI/binning fixed")
        unknown = sorted(set(coords) - set(self._coord_names))
        if unknown:
            raise RunStoreError(f"unknown coordinates {unknown}; the run has "
                                f"{self._coord_names}")
        image = self._exact(index, image)
        row = np.array([float(coords.get(n, np.nan)) for n in self._coord_names])
        self._group["frames"][index] = image
        self._group["coords"][index] = row
        if self.has_checksums:
            self._group["crc32"][index] = frame_crc(image, row)
        self._group["done"][index] = 1

    def write_frames(self, start: int, images: np.ndarray, coord_rows: np.ndarray) -> None:
        """Store frames ``start .. start + len(images) - 1`` as one block: images, then
        coordinates, then checksums, then done flags (each a single write).

        Meant for sharded runs, written a whole shard at a time (``start`` a multiple
        of :attr:`shard_frames`, ``len(images)`` equal to it except at the end of a
        recording); any block is stored correctly, a partial shard just costs a
        rewrite of that shard.

        Parameters
        ----------
        start : int
        images : ndarray, (m, rows, cols)
            Cast exactly to the run's dtype (as :meth:`write_frame`).
        coord_rows : ndarray, (m, n_coords) float64
            Coordinates in ``coord_names`` order (NaN where unknown).

        Raises
        ------
        RunStoreError
            Read-only store, block outside the run, wrong image or coordinate shape,
            or values the run's dtype cannot hold exactly.
        """
        self._require_writable()
        images = np.asarray(images)
        rows = np.asarray(coord_rows, np.float64)
        m = images.shape[0] if images.ndim == 3 else -1
        if images.ndim != 3 or images.shape[1:] != self.frame_shape:
            raise RunStoreError(f"frame block shape {images.shape} is not (m, "
                                f"{self.frame_shape[0]}, {self.frame_shape[1]}); keep the "
                                "camera ROI/binning fixed")
        if rows.shape != (m, len(self._coord_names)):
            raise RunStoreError(f"coordinate block shape {rows.shape} is not ({m}, "
                                f"{len(self._coord_names)}) for {self._coord_names}")
        if not (0 <= start and start + m <= self.n_frames) or m == 0:
            raise RunStoreError(f"frames {start}..{start + m - 1} are outside the run's "
                                f"0..{self.n_frames - 1}")
        images = np.stack([self._exact(start + j, im) for j, im in enumerate(images)])
        stop = start + m
        self._group["frames"][start:stop] = images
        self._group["coords"][start:stop] = rows
        if self.has_checksums:
            self._group["crc32"][start:stop] = np.array(
                [frame_crc(im, row) for im, row in zip(images, rows, strict=True)], np.uint32)
        self._group["done"][start:stop] = 1

    def _exact(self, index: int, image: np.ndarray) -> np.ndarray:
        """``image`` cast to the run's dtype, or RunStoreError if that would change a value."""
        dtype = self.frame_dtype
        if image.dtype == dtype:
            return image
        kind = image.dtype.kind
        if kind not in "biuf":
            raise RunStoreError(f"frame {index}: {image.dtype} data cannot be stored in the "
                                f"run's {dtype}; pass a real-valued image")
        if dtype.kind == "f" or np.can_cast(image.dtype, dtype, casting="safe"):
            return image.astype(dtype)
        info = np.iinfo(dtype)
        if kind == "f":
            bad = ~np.isfinite(image)
            if bad.any():
                raise RunStoreError(
                    f"frame {index}: {int(bad.sum())} NaN/inf pixels cannot be stored in the "
                    f"run's {dtype}; fix the source or pass a finite image")
            frac = image[image != np.round(image)]
            if frac.size:
                raise RunStoreError(
                    f"frame {index}: non-integer values (e.g. {frac.flat[0]:g}) cannot be "
                    f"stored exactly in the run's {dtype}; round them "
                    "first or pass the camera's integer frame")
        lo, hi = image.min(), image.max()
        if lo < info.min or hi > info.max:
            raise RunStoreError(
                f"frame {index}: values {lo:g}..{hi:g} are outside the run's {dtype} range "
                f"{info.min}..{info.max} (they would wrap); clip or rescale them first")
        return image.astype(dtype)

    def clear_point(self, point: int) -> None:
        """Mark a point's frames not done (before it is captured again)."""
        self._require_writable()
        r = self.frame_range(point)
        self._group["done"][r.start:r.stop] = 0

    def truncate(self, n_frames: int) -> None:
        """Cut a one-point run (a video) to its first ``n_frames`` frame slots, which
        must all be done: a recording that ended early or lost frames keeps no empty
        slots.

        Raises
        ------
        RunStoreError
            Read-only, a run of several points, or a slot below ``n_frames`` not done.
        """
        self._require_writable()
        n = int(n_frames)
        if self.n_points != 1 or not 0 <= n <= self.n_frames:
            raise RunStoreError(f"cannot cut {self.path} to {n_frames} frames: only a "
                                f"one-point run of at least that many frames can be cut")
        if not self.done(range(0, n)).all():
            raise RunStoreError(f"cannot cut {self.path} to {n} frames: not all are stored")
        for name in RUN_ARRAYS:
            arr = self._group[name]
            arr.resize((n, *arr.shape[1:]))
        record_layout(self._group, self.path, RUN_ARRAYS)
        self.attrs = dict(self._group.attrs)
        self._point, self._tag = self._point[:n], self._tag[:n]
        plan = dict(self.attrs["plan"], frames_per_point=[n])
        self.update_attrs(plan=plan)

    def update_attrs(self, **values: Any) -> None:
        """Set run attributes (status, times, summary, ...)."""
        self._require_writable()
        values = jsonable(values)
        self._group.attrs.update(values)
        self.attrs.update(values)
        if {"camera", "device_settings"} & set(values):  # the pitch or frame interval
            describe_run(self._group)
            self.attrs = dict(self._group.attrs)

    def add_warning(self, text: str) -> None:
        """Append a warning to the run's ``warnings`` attribute."""
        self.update_attrs(warnings=[*self.attrs.get("warnings", []), text])
