"""Memory the GUI's process frees goes back to the system (glibc's allocator).

The window runs for hours and its worker threads allocate and free frame-sized
arrays (0.1-10 MB: frames, reconstructions, FFT buffers) at video rate. glibc raises
its mmap threshold each time such a block is freed (up to 32 MB), so later blocks of
that size come from the threads' heaps (arenas) instead of fresh mappings, and a heap
holding one live block above many free ones cannot shrink: in the operator's day the
resident memory grew 30-50 % over 6-13 minutes, of which ``malloc_trim(0)`` gave back
~200 MB at once (measured: 1106 -> 911 MB), with no Python object left alive.

:func:`configure_allocator` fixes the mmap threshold (blocks of 128 KiB or more are
mapped on their own and unmapped when freed; the dynamic raise is off) and
:func:`trim_soon` hands the free pages of every heap back after a long job, on a
thread of its own, started with the window (``malloc_trim`` takes the heaps' locks,
never the GIL). Elsewhere
than glibc both do nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import threading

__all__ = ["MMAP_THRESHOLD_BYTES", "configure_allocator", "trim_now", "trim_soon"]

log = logging.getLogger(__name__)

#: Blocks of this size or more are mapped on their own (glibc's initial threshold).
MMAP_THRESHOLD_BYTES = 128 * 1024
#: ``mallopt`` parameter numbers (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

_libc: ctypes.CDLL | None = None
_trimming = threading.Lock()


def _glibc() -> ctypes.CDLL | None:
    global _libc
    if _libc is None:
        name = ctypes.util.find_library("c")
        try:
            lib = ctypes.CDLL(name or "libc.so.6")
            lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            lib.malloc_trim.argtypes = [ctypes.c_size_t]
        except (OSError, AttributeError):
            return None
        _libc = lib
    return _libc


def configure_allocator(mmap_threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at ``mmap_threshold_bytes`` (and the heap trim
    threshold at twice that), so freed frame-sized blocks go back to the system.

    Returns
    -------
    bool
        True when the allocator took the settings (glibc), False elsewhere.
    """
    lib = _glibc()
    if lib is None:
        return False
    _start_trimmer()
    ok = lib.mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold_bytes)) == 1
    ok &= lib.mallopt(_M_TRIM_THRESHOLD, 2 * int(mmap_threshold_bytes)) == 1
    if not ok:
        log.warning("the allocator refused the mmap threshold; memory freed by the "
                    "GUI's threads may stay with the process")
    return ok


def trim_now() -> bool:
    """Give the free pages of every heap back to the system (``malloc_trim(0)``);
    True if some were. Blocks the calling thread (tens of ms for a 1 GB heap)."""
    lib = _glibc()
    if lib is None:
        return False
    with _trimming:
        return bool(lib.malloc_trim(0))


_trim_wanted = threading.Event()
_trimmer: threading.Thread | None = None


def _trim_when_asked() -> None:
    while True:
        _trim_wanted.wait()
        _trim_wanted.clear()
        trim_now()


def trim_soon() -> None:
    """:func:`trim_now` on the trimming thread (started once, by
    :func:`configure_allocator` or here): the caller never waits for a thread to
    start (``Thread.start`` held the GUI thread in the soak)."""
    if _glibc() is None:
        return
    _start_trimmer()
    _trim_wanted.set()


def _start_trimmer() -> None:
    global _trimmer
    if _trimmer is None:
        _trimmer = threading.Thread(target=_trim_when_asked, name="malloc-trim", daemon=True)
        _trimmer.start()
