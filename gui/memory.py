"""Memory the GUI's process frees goes back to the system (glibc's allocator).

The window runs for hours and its worker threads allocate and free frame-sized
arrays (0.1-10 MB: frames, reconstructions, FFT buffers) at video rate. glibc raises
its mmap threshold each time such a block is freed (up to 32 MB), so later blocks of
that size come from the threads' heaps (arenas) instead of fresh mappings, and a heap
holding one live block above many free ones cannot shrink: in the operator's day the
resident memory grew 30-50 % over 6-13 minutes, of which ``malloc_trim(0)`` gave back
~200 MB at once (measured: 1106 -> 911 MB), with no Python object left alive.

:func:`configure_allocator` lets the threads share two heaps instead of one each
(the resident memory then stayed flat over the day's passes), and
:func:`trim_soon` hands the free pages of every heap back after a long job, on a
thread of its own, started with the window (``malloc_trim`` takes the heaps' locks,
never the GIL). That thread also trims unasked: as soon as the heaps' free memory has
risen :data:`TRIM_RISE_MB` above its lowest since the last trim, and at least every
:data:`TRIM_PERIOD_S` seconds.
The mmap threshold stays the solvers' (:mod:`recon.fft` raises it to 256 MB when
imported, so FFT buffers are reused without page faults): fixing it at
:data:`MMAP_THRESHOLD_BYTES` (``configure_allocator(mmap_threshold_bytes=...)``)
gives frame-sized blocks back as they are freed and the heaps stay unfragmented
(7 MB free at an hour's pass starts against 117-207 MB, the resident memory about
100 MB lower) but the live ADMM view ran at 12 fps instead of 20-21 on the 2-core
machine, so the window keeps the solvers' thresholds. Elsewhere than glibc all of this does
nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import threading
import time

__all__ = ["ARENA_MAX", "MMAP_THRESHOLD_BYTES", "TRIM_CHECK_S", "TRIM_PERIOD_S",
           "TRIM_RISE_MB", "arena_count", "configure_allocator", "heap_mb", "rss_mb",
           "trim_now", "trim_soon"]

log = logging.getLogger(__name__)

#: A fixed mmap threshold that keeps the heaps unfragmented (glibc's initial one), for
#: ``configure_allocator(mmap_threshold_bytes=...)``; the window does not set it.
MMAP_THRESHOLD_BYTES = 128 * 1024
#: Heaps (arenas) the process's threads share: glibc's default is 8 per core.
ARENA_MAX = 2
#: Longest time between the trimming thread's unasked trims, s.
TRIM_PERIOD_S = 30.0
#: The trimming thread trims as soon as the heaps' free memory has risen this much
#: above its lowest since the last trim, MB (looked at every :data:`TRIM_CHECK_S`).
TRIM_RISE_MB = 32.0
#: Seconds between the trimming thread's looks at the heaps' free memory.
TRIM_CHECK_S = 2.0
#: ``mallopt`` parameter number of the heap count (glibc's malloc.h); the thresholds
#: are set by :mod:`recon.fft`.
_M_ARENA_MAX = -8


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
        "uordblks", "fordblks", "keepcost")]


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
            if hasattr(lib, "mallinfo2"):  # glibc 2.33+
                lib.mallinfo2.restype = _Mallinfo2
        except (OSError, AttributeError):
            return None
        _libc = lib
    return _libc


def configure_allocator(mmap_threshold_bytes: int | None = None,
                        arena_max: int = ARENA_MAX,
                        trim_period_s: float = TRIM_PERIOD_S,
                        trim_rise_mb: float = TRIM_RISE_MB) -> bool:
    """Let the process's threads share at most ``arena_max`` heaps, start the trimming
    thread, and choose glibc's mmap threshold: the solvers' (the default) or a fixed
    one.

    Each worker thread (a Job, the camera grab, the live reconstruction) gets a heap
    of its own under glibc's default (up to 8 per core), and memory freed in one heap
    stays there: in the 59-minute soak the resident memory at the start of each pass
    grew from 1043 to 1517 MB while the Python heap stayed nearly flat; the same day
    with two heaps (``MALLOC_ARENA_MAX=2``) held 751-789 MB over 7 passes (+1.1 %).
    Call it before the threads start (:func:`gui.app.main` does, first): heaps made
    before stay. The trimming thread gives the heaps' free pages back whenever
    :func:`trim_soon` asks, when the heaps' free memory has risen ``trim_rise_mb`` above
    its lowest since the last trim, and at least every ``trim_period_s`` seconds. In an
    hour's operator day with a trim only every 30 s, the memory freed by a step (the
    image tools: about 100 MB) stayed resident until the next trim, and the pass starts
    wandered between 773 and 864 MB while the heaps' memory in use held at 343-368 MB.

    With ``mmap_threshold_bytes=None`` the thresholds are the solvers'
    (:func:`recon.fft.retain_freed_memory`, 256 MB and 1 GB): FFT buffers are reused
    from the heaps without page faults. With a number, blocks of that size or more
    are mapped on their own and given back when freed (the heap trim threshold is
    twice that), whether :mod:`recon.fft` is imported before or after. Measured on
    the 2-core machine: with 128 KiB the live ADMM view (5 iterations a frame,
    ``python -m soak.benchmark --method admm:5``) ran at 12 fps instead of 20-21, and
    an hour's operator day held 705-796 MB at its pass starts with 7 MB free in the
    heaps, against 812-913 MB and 117-207 MB free with the solvers' thresholds.

    Parameters
    ----------
    mmap_threshold_bytes : int or None
        Fixed mmap threshold, bytes; None keeps the solvers' thresholds.
    arena_max : int
        Heaps the threads share.
    trim_period_s : float
        Longest time between the trimming thread's unasked trims, s (> 0).
    trim_rise_mb : float
        Trim as soon as the heaps' free memory has risen this much above its lowest
        since the last trim, MB (> 0; looked at every :data:`TRIM_CHECK_S` s): memory
        freed since then, resident until a trim.

    Returns
    -------
    bool
        True when the allocator took the settings (glibc), False elsewhere.

    Raises
    ------
    ValueError
        ``trim_period_s`` or ``trim_rise_mb`` is not above 0.
    """
    import recon.fft

    if not trim_period_s > 0:
        raise ValueError(f"trim_period_s must be > 0 s, got {trim_period_s!r}")
    if not trim_rise_mb > 0:
        raise ValueError(f"trim_rise_mb must be > 0 MB, got {trim_rise_mb!r}")
    lib = _glibc()
    if lib is None:
        return False
    ok = lib.mallopt(_M_ARENA_MAX, int(arena_max)) == 1
    _start_trimmer(float(trim_period_s), float(trim_rise_mb))
    if mmap_threshold_bytes is not None:  # holds if recon.fft is imported after
        ok &= recon.fft.fix_allocator_thresholds(mmap_threshold_bytes)
    if not ok:
        log.warning("the allocator refused the GUI's settings; memory freed by the "
                    "GUI's threads may stay with the process")
    return ok


def arena_count() -> int | None:
    """How many heaps (arenas) glibc's allocator has now.

    Returns
    -------
    int or None
        The ``<heap nr=...>`` entries of ``malloc_info``'s report (written to a
        temporary file); None elsewhere than glibc, or when the file cannot be opened.
    """
    import os
    import tempfile

    lib = _glibc()
    if lib is None:
        return None
    lib.fopen.restype = ctypes.c_void_p
    lib.fopen.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
    lib.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    lib.fclose.argtypes = [ctypes.c_void_p]
    fd, path = tempfile.mkstemp(suffix=".xml")
    os.close(fd)
    try:
        fp = lib.fopen(path.encode(), b"w")
        if not fp:
            return None
        lib.malloc_info(0, fp)
        lib.fclose(fp)
        with open(path) as f:
            return f.read().count("<heap nr=")
    finally:
        os.unlink(path)


def heap_mb() -> dict[str, float] | None:
    """What glibc's allocator holds now, summed over its heaps (``mallinfo2``), MB.

    Tells a leak from fragmentation in a long run: memory in use that grows is
    allocated and kept (by Python objects' buffers, Qt, the libraries); free memory
    that grows is held by the heaps and not given back.

    Returns
    -------
    dict or None
        ``in_use_mb`` (blocks allocated from the heaps), ``free_mb`` (free in the
        heaps, still resident unless trimmed) and ``mapped_mb`` (blocks mapped on
        their own, at or above the mmap threshold); None elsewhere than glibc 2.33+.
        Python's small objects (its own arenas) and Qt's mapped images are in none.
    """
    lib = _glibc()
    if lib is None or not hasattr(lib, "mallinfo2"):
        return None
    m = lib.mallinfo2()
    return {"in_use_mb": m.uordblks / 1e6, "free_mb": m.fordblks / 1e6,
            "mapped_mb": m.hblkhd / 1e6}


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


def rss_mb() -> float:
    """Resident memory of this process, MB (Linux ``/proc/self/statm``)."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def _heap_free_mb() -> float | None:
    """The heaps' free memory, MB (:func:`heap_mb`); None without mallinfo2."""
    heap = heap_mb()
    return None if heap is None else heap["free_mb"]


def _trim_when_asked(period_s: float, rise_mb: float) -> None:
    """The trimming thread: trim when asked, when the heaps' free memory rose
    ``rise_mb`` above its lowest since the last trim (memory freed since, resident
    until a trim; looked at every :data:`TRIM_CHECK_S`), and every ``period_s``."""
    low, last = _heap_free_mb(), time.monotonic()
    while True:
        asked = _trim_wanted.wait(min(TRIM_CHECK_S, period_s))
        free = _heap_free_mb()  # None where glibc has no mallinfo2: the period alone
        low = free if low is None or free is None else min(low, free)
        if asked or (free is not None and free - low > rise_mb) or \
                time.monotonic() - last >= period_s:
            _trim_wanted.clear()
            trim_now()
            low, last = _heap_free_mb(), time.monotonic()


def trim_soon() -> None:
    """:func:`trim_now` on the trimming thread (started once, by
    :func:`configure_allocator` or here): the caller never waits for a thread to
    start (``Thread.start`` held the GUI thread in the soak)."""
    if _glibc() is None:
        return
    _start_trimmer()
    _trim_wanted.set()


def _start_trimmer(period_s: float = TRIM_PERIOD_S, rise_mb: float = TRIM_RISE_MB) -> None:
    global _trimmer
    if _trimmer is None:
        _trimmer = threading.Thread(target=_trim_when_asked, args=(period_s, rise_mb),
                                    name="malloc-trim", daemon=True)
        _trimmer.start()
