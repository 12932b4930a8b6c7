"""Run storage: one Zarr v3 store per run (docs/architecture.md, "Storage").

Layout of ``RUN.zarr``::

    zarr.json            attributes: schema and software versions, plan (name, params,
                         points, frame tags), bench config and device settings
                         snapshots, operator note, status, start/end times, resumes,
                         warnings, ``created_by`` (the creating process: pid, host,
                         token; instrument.runs.run_paths); ``arrays``: each array's
                         shape, dtype, chunks, codecs and fill value as written
                         (instrument.runs.run_layout; ``products/`` keeps the same for
                         its products); ``described``: the ``ome`` block and the
                         arrays' dimension names as written
                         (instrument.runs.run_description; likewise)
    frames               (n_frames, rows, cols) camera dtype, one frame per chunk
    coords               (n_frames, n_coords) float64, one row per chunk; column names
                         in its attribute ``names`` (stage positions, LED, SLM pattern
                         id, exposure, gain, timestamps, saturation count, ...), their
                         units and dimension names in ``units`` and ``dims``
                         ({name: str}, from instrument.runs.coords); Zarr dimension names
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
                         before the image groups; :mod:`instrument.runs.product_nodes` reads
                         either); the array's attribute ``crc32``: CRC-32 per plane
                         (first axis) of a 3-D product, of the whole array otherwise
    dimension_names, ome every array names its dimensions (the frames' first axis
                         ``t`` for a video, named for what a sweep's points vary
                         otherwise, shared by the per-frame arrays); the root's and each
                         product group's ``ome`` attribute describe them as OME-Zarr
                         0.5 images (:mod:`instrument.runs.ome`; ``runs upgrade`` adds them
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

import logging
import os
import socket
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .ome import describe_run
from .run_creation import FRAME_COMPRESSORS, SCHEMA_VERSION, create_run, software_version, utc_now
from .run_integrity import (
    LOCK_NAME,
    DamagedFrameError,
    RunStoreError,
    lock_problem,
    read_lock,
    write_lock,
)
from .run_layout import RUN_ARRAYS, layout_problems
from .run_paths import discard_partial_run, is_run_store, product_location
from .run_products import ProductsMixin
from .run_reading import FrameRecord, RunReadingMixin
from .run_writing import RunWritingMixin

__all__ = ["FRAME_COMPRESSORS", "SCHEMA_VERSION", "DamagedFrameError", "FrameRecord", "RunStore",
           "RunStoreError", "discard_partial_run", "is_run_store", "product_location",
           "software_version", "utc_now"]

log = logging.getLogger(__name__)

#: Schema versions this diffuserlab reads (1: no checksums).
READABLE_SCHEMAS = (1, 2)

#: Attributes every run's zarr.json holds (a store lacking one is damaged).
REQUIRED_ATTRS = ("schema_version", "software_version", "status", "plan", "tags",
                  "bench_config", "device_settings", "note", "resumes", "warnings", "summary")
REQUIRED_PLAN_ATTRS = ("name", "params", "points", "frames_per_point")


class RunStore(ProductsMixin, RunReadingMixin, RunWritingMixin):
    """A run's Zarr v3 store: create, write frames, read (also while being written).

    Use :meth:`create` for a new run and :meth:`open` for an existing one.

    Attributes
    ----------
    path : pathlib.Path
    attrs : dict
        The run's attributes (a snapshot; :meth:`refresh` re-reads them).
    layout_damage : dict
        ``{array: problem line}`` for each array whose metadata differs from what the
        run recorded when it wrote it (:mod:`instrument.runs.run_layout`); such arrays are
        never read or written (:meth:`require_layout`), :meth:`verify` lists them.
    creation_token : str or None
        Set on the store :meth:`create` returns: the token its run records as its
        creator's (:data:`instrument.runs.run_paths.CREATOR_ATTR`), the proof
        :func:`instrument.runs.run_paths.discard_partial_run` asks for; None on a store
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
    # a new run's store with its whole layout (instrument.runs.run_creation, documented there)
    create = classmethod(create_run)

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
        """Claim the run for this process: create ``RUN.zarr/.lock`` atomically (nothing
        when this store holds it already: a run created with ``keep_lock``).

        Raises
        ------
        RunStoreError
            Another writer holds the run (its pid and host named), or a stale lock
            is left by a process that is gone (never broken silently: remove it
            after checking no one writes the run).
        """
        if getattr(self, "_locked", False):  # held already (RunStore.create keep_lock)
            return
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
        ``products/NAME/0`` (:func:`instrument.runs.product_nodes.regroup`: directories
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
            The first such array's problem (:mod:`instrument.runs.run_layout`): what its
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
