"""Checksums and the writer's lock file of a run store (:mod:`instrument.runs.runstore`).

* CRC-32 (``zlib.crc32``) of a frame's pixels followed by its coordinate row, and
  of each plane of a product, recorded when written and compared on read, so a
  deleted chunk (which zarr reads back as its fill value) or an altered one is
  found instead of read as data;
* ``RUN.zarr/.lock``: JSON ``{pid, host, started_utc}`` of the process writing the
  run, created atomically (``O_CREAT | O_EXCL``); a lock whose process is gone is
  reported as stale, never removed silently.
"""

from __future__ import annotations

import json
import os
import socket
import zlib
from pathlib import Path

import numpy as np

from diffuserlab.errors import InputError
from diffuserlab.jsonio import json_text

__all__ = ["LOCK_NAME", "VERIFY_BLOCK_BYTES", "DamagedFrameError", "RunStoreError",
           "damaged_frames", "frame_crc", "lock_problem", "pid_alive",
           "product_crcs", "read_lock", "write_lock"]


class RunStoreError(InputError):
    """A run store is missing, of another schema, or asked for something it lacks."""


def frame_crc(image: np.ndarray, row: np.ndarray) -> int:
    """CRC-32 of a frame's bytes then its coordinate row (both little-endian).

    Parameters
    ----------
    image : ndarray, (rows, cols), the run's dtype
    row : ndarray, (n_coords,), float64

    Returns
    -------
    int
        Unsigned 32-bit checksum.
    """
    image = np.ascontiguousarray(image, image.dtype.newbyteorder("<"))
    crc = zlib.crc32(image.tobytes())
    return zlib.crc32(np.ascontiguousarray(row, "<f8").tobytes(), crc)


def product_crcs(array: np.ndarray) -> list[int]:
    """CRC-32 per plane of a 3-D array (its chunks), of the whole array otherwise.

    Parameters
    ----------
    array : ndarray, any dtype

    Returns
    -------
    list of int
        One checksum per plane (3-D) or one for the array.
    """
    array = np.asarray(array)
    planes = list(array) if array.ndim == 3 else [array]
    return [zlib.crc32(np.ascontiguousarray(p, p.dtype.newbyteorder("<")).tobytes())
            for p in planes]


#: Name of the writer's lock file inside a run store.
LOCK_NAME = ".lock"


def read_lock(path: Path) -> dict | None:
    """The lock record of run ``path``: None when unlocked, ``{}`` when unreadable."""
    try:
        text = (Path(path) / LOCK_NAME).read_text()
    except FileNotFoundError:
        return None
    try:
        record = json.loads(text)
        return record if isinstance(record, dict) else {}
    except ValueError:
        return {}


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def lock_problem(path: Path) -> str:
    """Why ``path``'s lock stops a writer: held by a live process, stale, or unreadable."""
    lock = Path(path) / LOCK_NAME
    record = read_lock(path)
    if record is None:
        return "its lock vanished meanwhile; try again"
    pid, host = record.get("pid"), record.get("host")
    if not isinstance(pid, int) or not host:
        return (f"{lock} is unreadable (a writer died while creating it?); remove it after "
                "checking no one writes the run")
    if host == socket.gethostname() and not pid_alive(pid):
        return (f"a stale lock: the process {pid} that held it is gone; remove {lock} after "
                "checking no one writes the run")
    return (f"process {pid} on {host} is writing it (since {record.get('started_utc')}); "
            f"wait for it to finish or stop it (if that process is gone, remove {lock})")


def write_lock(path: Path, record: dict) -> bool:
    """Create ``path``'s lock file atomically with ``record`` (JSON).

    Returns
    -------
    bool
        True when created; False when a lock file already exists (see
        :func:`lock_problem` for why).
    """
    try:
        fd = os.open(Path(path) / LOCK_NAME, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w") as fh:
        fh.write(json_text(record))  # created exclusively: no atomic rename here
    return True


class DamagedFrameError(RunStoreError):
    """A done frame's chunk is missing, unreadable or differs from its checksum.

    Attributes
    ----------
    index, point : int
        The frame and its plan point.
    reason : str
        What is wrong with it.
    """

    def __init__(self, path: Path, index: int, point: int, reason: str,
                 video: bool = False) -> None:
        fix = ("a recorded video frame cannot be captured again: restore the run from a "
               "backup copy, or leave the frame out (runs export --frames and recon-run "
               "skip damaged frames)" if video else
               f"re-run that point: diffuserlab calibrate resume {path} BENCH.toml "
               f"--redo {point}")
        super().__init__(f"frame {index} (point {point}) of {path} is damaged: {reason}; {fix}")
        self.index, self.point, self.reason = index, point, reason
        self._init_args = (path, index, point, reason, video)

    def __reduce__(self):  # crosses process boundaries (dask workers) intact
        return type(self), self._init_args


#: Most bytes of frames :func:`damaged_frames` reads at once.
VERIFY_BLOCK_BYTES = 64 * 2 ** 20


def damaged_frames(store, on_progress=None) -> list[DamagedFrameError]:
    """Every done frame of ``store`` whose chunk is missing, unreadable or differs from
    its checksum (:func:`frame_crc`).

    Frames are read in blocks of whole chunks (shards), at most
    :data:`VERIFY_BLOCK_BYTES` a block: one read per block instead of three per frame
    (a 200-frame video of 256 x 320: 0.28 s instead of 1.12 s). A block that cannot be read,
    and a frame whose checksum fails, is read again on its own for the error's reason.

    Parameters
    ----------
    store : instrument.runs.runstore.RunStore
    on_progress : callable, optional
        ``on_progress(checked, total)`` after each done frame.

    Returns
    -------
    list of DamagedFrameError
        As reading each damaged frame raises it; empty when all are intact.
    """
    out = []
    done = np.flatnonzero(store.done())
    if not store.has_checksums or done.size == 0:  # only unreadable chunks to find
        return _damaged_one_by_one(store, done, on_progress, 0, len(done))
    try:
        crcs = np.asarray(store._group["crc32"][:])
        rows = np.asarray(store._group["coords"][:], np.float64)
    except Exception:  # a checksum or coordinate chunk fails to decode: frame by frame
        return _damaged_one_by_one(store, done, on_progress, 0, len(done))
    frames = store._group["frames"]
    per_chunk = int((frames.shards or frames.chunks)[0])
    frame_bytes = int(np.prod(store.frame_shape)) * frames.dtype.itemsize
    step = per_chunk * max(1, VERIFY_BLOCK_BYTES // max(1, per_chunk * frame_bytes))
    checked = 0
    for start in range(0, store.n_frames, step):
        block = done[(done >= start) & (done < start + step)]
        if block.size == 0:
            continue
        try:
            images = np.asarray(frames[int(block[0]):int(block[-1]) + 1])
        except Exception:  # a corrupt chunk fails to decode: frame by frame
            out += _damaged_one_by_one(store, block, on_progress, checked, len(done))
            checked += block.size
            continue
        for i in block:
            if int(crcs[i]) != frame_crc(images[i - block[0]], rows[i]):
                out += _damaged_one_by_one(store, [i], None, 0, 0)
            checked += 1
            if on_progress is not None:
                on_progress(checked, len(done))
    return out


def _damaged_one_by_one(store, indices, on_progress, checked: int, total: int,
                        ) -> list[DamagedFrameError]:
    """The errors :meth:`RunStore._read <instrument.runs.runstore.RunStore>` raises for each
    frame of ``indices`` (``on_progress(checked + k, total)`` after the k-th)."""
    out = []
    for k, i in enumerate(indices, start=checked + 1):
        try:
            store._read(int(i))
        except DamagedFrameError as exc:
            out.append(exc)
        if on_progress is not None:
            on_progress(k, total)
    return out

