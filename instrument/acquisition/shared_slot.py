"""A newest-only image slot in shared memory, for one writer and one reader process.

Frames go from the GUI's process to the live reconstruction's process, and results
back, through :class:`SharedImageSlot`: a ``multiprocessing.shared_memory`` block
holding two image buffers, their metadata and two counters. Neither side ever waits
for the other. The writer fills the buffer the newest image is *not* in and then
publishes it; the reader copies the newest buffer and keeps the copy only if the
writer did not start overwriting that buffer meanwhile (a sequence lock over two
buffers: Lameter 2005, "Effective synchronization on Linux/NUMA systems"). A reader
that loses that race tries again; a writer never blocks, so a slow or descheduled
reader (a process at a lower priority) cannot hold up the camera, and a slow writer
cannot hold up the window.

The counters are 8-byte aligned integers written after (``published``) and before
(``writing``) the buffer they guard. That order is all the reader relies on, which
x86-64 keeps for plain stores and loads (total store order); on weakly ordered
processors (ARM) a torn image could pass the check. Every image carries its frame's
metadata (index, timestamps, and up to :data:`META_FIELDS` numbers).

A slot's name says which process made it: ``dlab-<pid>-<start>-<token>``, ``start``
being the process's start time (clock ticks after boot, ``/proc/<pid>/stat``; 0 where
there is no ``/proc``), so a process that later gets the same pid is not taken for
it. A process killed outright (a window, a live view, a test) leaves its slots in
``/dev/shm`` when multiprocessing's resource tracker died with it; every new slot
first removes those whose maker is gone (:func:`reclaim_orphaned_slots`; this user's
only, never a running process's).
"""

from __future__ import annotations

import logging
import math
import os
import re
import secrets
from multiprocessing import resource_tracker, shared_memory

import numpy as np

__all__ = ["META_FIELDS", "SHM_DIR", "SharedImageSlot", "SlotImage", "owned_block_name",
           "reclaim_orphaned_slots", "slot_owner"]

log = logging.getLogger(__name__)

#: Where POSIX shared memory is listed (Linux).
SHM_DIR = "/dev/shm"
_NAME = re.compile(r"dlab-(\d+)-(\d+)-[0-9a-f]+")

#: Numbers of metadata each image carries (float64).
META_FIELDS = 12
_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.float32),
           np.dtype(np.float64))
_HEADER = 5  # ndim, rows, cols, channels, dtype code
_ROW = _HEADER + META_FIELDS


def _process_start(pid: int) -> tuple[int, str] | None:
    """``(start, state)`` of process ``pid`` from ``/proc/<pid>/stat`` (start: clock
    ticks after boot; state: ``R``, ``S``, ``Z``...), None when there is no such
    process (or no ``/proc``)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return int(fields[19]), fields[0].decode()  # fields 22 and 3 of proc(5)


def owned_block_name() -> str:
    """A new shared memory name that says this process made it
    (``dlab-<pid>-<start>-<token>``, the module docstring), for a block of its own
    that :func:`reclaim_orphaned_slots` removes once this process has ended (a
    :class:`SharedImageSlot`'s, or a result block handed to another process).

    Returns
    -------
    str
        Unique (a random 32-bit token); no leading slash.
    """
    pid = os.getpid()
    start = _process_start(pid)
    return f"dlab-{pid}-{start[0] if start else 0}-{secrets.token_hex(4)}"


def slot_owner(name: str) -> tuple[int, int] | None:
    """``(pid, start)`` of the process that made slot ``name`` (``start``: its start
    time, clock ticks after boot, 0 where unknown); None for a name that does not say
    (another program's, or a slot made before names said)."""
    match = _NAME.fullmatch(name)
    return None if match is None else (int(match[1]), int(match[2]))


def _owner_alive(pid: int, start: int) -> bool:
    """Whether the maker ``(pid, start)`` of a slot runs (without ``/proc``: assumed)."""
    now = _process_start(pid)
    if now is None:
        return not os.path.isdir("/proc")
    return now[1] not in "ZX" and (start == 0 or now[0] == start)


def _unlink(entry: os.DirEntry) -> None:
    """Remove the shared memory ``entry``: attached, then unlinked, so this process's
    resource tracker registers and unregisters it (a bare unlink would unregister a
    name it never had: an error in the tracker's output)."""
    try:
        shm = shared_memory.SharedMemory(name=entry.name)
    except ValueError:  # empty: its maker died before sizing it, before registering it
        os.unlink(entry.path)
        return
    try:
        shm.unlink()
    except FileNotFoundError:  # another process removed it meanwhile, after we attached
        resource_tracker.unregister(f"/{entry.name}", "shared_memory")
        raise
    finally:
        shm.close()


def reclaim_orphaned_slots() -> list[str]:
    """Remove the slots whose maker has ended (see the module docstring).

    Only slots named as :class:`SharedImageSlot` names them, owned by this user, whose
    maker is not running (no such process, a zombie, or another process that got its
    pid since: its start time differs). A process still attached to one keeps its
    mapping; the name goes. Where the system lists no shared memory in
    :data:`SHM_DIR` (not Linux), nothing is done.

    Returns
    -------
    list of str
        The names removed.
    """
    try:
        entries = list(os.scandir(SHM_DIR))
    except OSError:
        return []
    removed = []
    uid = os.geteuid()
    for entry in entries:
        owner = slot_owner(entry.name)
        try:
            if owner is None or entry.stat().st_uid != uid or _owner_alive(*owner):
                continue
            _unlink(entry)
        except OSError as exc:  # removed meanwhile, or not ours to remove
            log.debug("shared slot %s left: %s", entry.name, exc)
            continue
        removed.append(entry.name)
    if removed:
        log.info("removed %d shared slot(s) of ended processes: %s", len(removed),
                 ", ".join(removed))
    return removed


class SlotImage:
    """One image read from a slot: ``image`` (a private copy), ``meta`` (float64,
    (:data:`META_FIELDS`,)) and ``sequence`` (1 for the first image written)."""

    __slots__ = ("image", "meta", "sequence")

    def __init__(self, image: np.ndarray, meta: np.ndarray, sequence: int) -> None:
        self.image, self.meta, self.sequence = image, meta, sequence


class SharedImageSlot:
    """Newest-only image slot in shared memory (see the module docstring).

    Parameters
    ----------
    capacity_bytes : int
        Largest image (``nbytes``) the slot takes.
    name : str, optional
        Attach to the slot of this name (made by another process); default: make a
        new one, named after this process (the maker unlinks it on :meth:`close`; the
        slots of ended makers are removed first, :func:`reclaim_orphaned_slots`).

    Raises
    ------
    ValueError
        ``capacity_bytes`` < 1.
    FileNotFoundError
        No slot of that ``name`` (its maker closed it).

    Examples
    --------
    >>> import numpy as np
    >>> slot = SharedImageSlot(64)
    >>> slot.write(np.arange(6, dtype=np.uint16).reshape(2, 3), meta=[7.0])
    1
    >>> other = SharedImageSlot(64, name=slot.name)   # another process attaches so
    >>> got = other.read()
    >>> got.image.tolist(), float(got.meta[0]), got.sequence
    ([[0, 1, 2], [3, 4, 5]], 7.0, 1)
    >>> other.close(); slot.close()
    """

    def __init__(self, capacity_bytes: int, name: str | None = None) -> None:
        capacity = int(capacity_bytes)
        if capacity < 1:
            raise ValueError(f"capacity_bytes={capacity_bytes!r}: give at least 1 byte")
        self.capacity = int(math.ceil(capacity / 64) * 64)
        header = 8 * (2 + 2 * _ROW)
        size = header + 2 * self.capacity
        self._owner = name is None
        if self._owner:
            reclaim_orphaned_slots()
            name = owned_block_name()
            self._shm = shared_memory.SharedMemory(name=name, create=True, size=size)
        else:
            self._shm = shared_memory.SharedMemory(name=name)
            if self._shm.size < size:
                self._shm.close()
                raise ValueError(f"shared slot {name} holds {self._shm.size} bytes, fewer "
                                 f"than {size} for {capacity} per image")
        buf = self._shm.buf
        # counters: [0] published sequence, [1] sequence being written
        self._counters = np.ndarray((2,), np.int64, buf, 0)
        self._rows = np.ndarray((2, _ROW), np.float64, buf, 16)
        self._data = [np.ndarray((self.capacity,), np.uint8, buf, header + i * self.capacity)
                      for i in range(2)]
        if self._owner:
            self._counters[:] = 0
        self.name = name
        self._written = int(self._counters[0])

    @property
    def sequence(self) -> int:
        """The newest published image's sequence number (0: none yet)."""
        return int(self._counters[0])

    def write(self, image: np.ndarray, meta=()) -> int:
        """Publish a copy of ``image`` with ``meta``; returns its sequence number.

        Only one process (one thread) may write to a slot.

        Raises
        ------
        ValueError
            ``image`` larger than the slot's capacity, of more than 3 dimensions, of a
            dtype other than uint8, uint16, float32 or float64, or more than
            :data:`META_FIELDS` metadata.
        """
        image = np.asarray(image)
        if image.dtype not in _DTYPES:
            raise ValueError(f"a shared slot takes uint8, uint16, float32 or float64 images, "
                             f"not {image.dtype}")
        if image.ndim not in (2, 3) or image.nbytes > self.capacity:
            raise ValueError(f"image of shape {image.shape} ({image.nbytes} bytes) does not "
                             f"fit the slot: 2D or 3D, at most {self.capacity} bytes")
        meta = np.asarray(meta, np.float64).ravel()
        if meta.size > META_FIELDS:
            raise ValueError(f"at most {META_FIELDS} metadata, got {meta.size}")
        n = self._written + 1
        b = n % 2
        self._counters[1] = n  # from here the reader of n - 2's buffer discards its copy
        shape = image.shape + (1,) * (3 - image.ndim)
        row = self._rows[b]
        row[:_HEADER] = (image.ndim, *shape, _DTYPES.index(image.dtype))
        row[_HEADER:] = 0.0
        row[_HEADER:_HEADER + meta.size] = meta
        self._data[b][:image.nbytes] = np.ascontiguousarray(image).view(np.uint8).ravel()
        self._counters[0] = n
        self._written = n
        return n

    def read(self, after: int = 0, attempts: int = 8) -> SlotImage | None:
        """A copy of the newest image if its sequence number is above ``after``.

        Never waits for the writer: a copy the writer overwrote meanwhile is read
        again, up to ``attempts`` times.

        Returns
        -------
        SlotImage or None
            None when nothing newer than ``after`` was published, or every attempt
            raced the writer (the next call gets a newer image).
        """
        for _ in range(attempts):
            n = int(self._counters[0])
            if n <= after:
                return None
            row = self._rows[n % 2].copy()
            ndim, rows, cols, chans, code = (int(v) for v in row[:_HEADER])
            dtype = _DTYPES[code]
            shape = (rows, cols) if ndim == 2 else (rows, cols, chans)
            nbytes = rows * cols * chans * dtype.itemsize
            data = self._data[n % 2][:nbytes].copy()
            if int(self._counters[1]) < n + 2:  # the writer did not reach this buffer
                return SlotImage(data.view(dtype).reshape(shape), row[_HEADER:], n)
        return None

    def close(self) -> None:
        """Detach (and, in the process that made the slot, remove it)."""
        self._counters = self._rows = None
        self._data = []
        self._shm.close()
        if self._owner:
            try:
                self._shm.unlink()
            except FileNotFoundError:
                pass
