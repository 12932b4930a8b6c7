"""Checksums and the writer's lock file of a run store (:mod:`instrument.runstore`).

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

__all__ = ["LOCK_NAME", "RunStoreError", "frame_crc", "lock_problem", "pid_alive",
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
        json.dump(record, fh)
    return True
