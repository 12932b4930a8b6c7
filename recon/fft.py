"""FFT helpers shared by the forward models, solvers and benchmarks.

All transforms go through :mod:`scipy.fft` with ``workers=os.cpu_count()`` (see
docs/architecture.md), or fewer inside :func:`limited_threads` (a thread that must
leave cores to others, e.g. live reconstruction next to a recorder); the FFT floor
used to state speed as a ratio is measured here.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import TypeVar

import numpy as np
import scipy.fft as sfft

#: FFT threads of each transform: one per CPU (``os.cpu_count()``, so the value is the
#: machine's), unless the calling thread caps its own (:func:`limited_threads`).
#:
#: :meta hide-value:
WORKERS = os.cpu_count() or 1

log = logging.getLogger(__name__)

_limit = threading.local()

T = TypeVar("T")
R = TypeVar("R")


def fft_workers() -> int:
    """FFT workers of the calling thread: :data:`WORKERS`, or the cap of an enclosing
    :func:`limited_threads`."""
    return getattr(_limit, "n", WORKERS)


def check_threads(n) -> int:
    """``n`` as a thread count in [1, os.cpu_count()], else ReconInputError naming it."""
    from .errors import ReconInputError

    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= WORKERS:
        raise ReconInputError(f"threads={n!r}: give an integer from 1 to {WORKERS} "
                              "(this machine's cores)")
    return n


@contextlib.contextmanager
def limited_threads(n: int) -> Iterator[None]:
    """Context manager: the calling thread's FFTs (:func:`rfftn`, :func:`irfftn`) and
    numba kernels use at most ``n`` threads; other threads are unaffected (numba's
    thread count is per thread too).

    Raises
    ------
    ReconInputError
        ``n`` is not an integer in [1, os.cpu_count()].
    """
    from .jit import set_num_threads, thread_count

    check_threads(n)
    before_fft, before_numba = fft_workers(), thread_count()
    _limit.n = n
    set_num_threads(min(n, before_numba))
    try:
        yield
    finally:
        _limit.n = before_fft
        set_num_threads(before_numba)


def map_jobs(fn: Callable[[T], R], items: Sequence[T], *,
             on_done: Callable[[int, R], None] | None = None) -> list[R]:
    """``fn(item)`` for every item, as many at once as the calling thread's FFT workers
    (:func:`fft_workers`), each job's FFTs and numba kernels on one thread, and BLAS
    on one thread in the whole process while they run (threadpoolctl; restored after).

    Independent jobs of small transforms share the cores better than the threads of
    one transform do: on the shared 2-core machine, the calibration's binned PSF
    estimates (135 x 240) cost 6.6-6.8 s of CPU on one FFT thread and 9.5-14.8 s on two
    (docs/real-data.md). A single job, or a thread capped at one worker, runs in the
    caller's thread as it is. The results are those of the jobs run one by one (an
    FFT's result does not depend on its thread count).

    Parameters
    ----------
    fn : callable
        One job; called from worker threads, so it must not share mutable state with
        the other jobs.
    items : sequence
        The jobs' arguments.
    on_done : callable, optional
        ``on_done(index, result)`` in the caller's thread as each job ends, in the
        order they end (progress).

    Returns
    -------
    list
        ``fn(item)`` per item, in the items' order.

    Raises
    ------
    Exception
        The first job's error, once the jobs already running have ended (those not
        started are cancelled).
    """
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    from threadpoolctl import threadpool_limits

    items = list(items)
    threads = min(fft_workers(), len(items))
    results: list = [None] * len(items)
    if threads <= 1:
        for i, item in enumerate(items):
            results[i] = fn(item)
            if on_done is not None:
                on_done(i, results[i])
        return results

    def job(item):
        with limited_threads(1):
            return fn(item)

    # BLAS (OpenBLAS: one thread count for the whole process) on one thread while the
    # jobs run: its idle threads spin, and in the calibration's PSF estimates they
    # doubled the CPU time for the same wall time (docs/real-data.md)
    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(
            max_workers=threads, thread_name_prefix="recon-job") as pool:
        index = {pool.submit(job, item): i for i, item in enumerate(items)}
        pending = set(index)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in sorted(done, key=index.get):
                if future.exception() is not None:
                    for other in pending:
                        other.cancel()
                    raise future.exception()
                results[index[future]] = future.result()
                if on_done is not None:
                    on_done(index[future], results[index[future]])
    return results


#: Set by :func:`fix_allocator_thresholds`: the process chose its own thresholds.
_thresholds_fixed = False


def _set_thresholds(mmap_threshold_bytes: int, trim_threshold_bytes: int) -> bool:
    """glibc's mmap and heap-trim thresholds (``mallopt``); False where refused or not
    glibc on Linux."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
        return bool(libc.mallopt(m_mmap_threshold, int(mmap_threshold_bytes))
                    and libc.mallopt(m_trim_threshold, int(trim_threshold_bytes)))
    except (OSError, AttributeError):
        return False


def fix_allocator_thresholds(mmap_threshold_bytes: int) -> bool:
    """Fix glibc's mmap threshold (the heap trim threshold at twice it), and keep
    :func:`retain_freed_memory` from changing them again in this process.

    For a process that runs for hours (``gui.memory.configure_allocator`` offers
    it): blocks of ``mmap_threshold_bytes`` or more are mapped on their own and given
    back when freed, so the heaps do not fragment (in the GUI's operator day, 7 MB
    free in the heaps at the passes' starts against 117-207 MB with this module's
    thresholds), at the price of page faults on every FFT buffer (the live ADMM view
    ran at 12 fps instead of 20-21). Holds whether this module was imported before
    or after.

    Parameters
    ----------
    mmap_threshold_bytes : int
        Blocks of this size or more are mapped on their own, bytes.

    Returns
    -------
    bool
        True when the allocator took the thresholds (glibc on Linux).
    """
    global _thresholds_fixed
    _thresholds_fixed = True
    return _set_thresholds(mmap_threshold_bytes, 2 * int(mmap_threshold_bytes))


def retain_freed_memory() -> bool:
    """Keep freed large blocks in the heap instead of returning them to the kernel.

    Every solver iteration frees and reallocates FFT outputs of the same sizes
    (scipy.fft cannot write into a given buffer). With glibc's defaults the freed
    blocks go back to the kernel and each iteration page-faults the memory in
    again: ~4300 minor faults per ADMM iteration at 1200 x 1600 (17 MB zeroed by the
    kernel, several ms). Raising glibc's mmap and trim thresholds (mallopt) makes
    the reuse fault-free. Process-wide and glibc-only; elsewhere this is a no-op.
    Called once, when this module is imported (:data:`RETAINS_FREED_MEMORY`). Set
    ``DIFFUSERLAB_DEFAULT_MALLOC=1`` to leave the allocator alone; after
    :func:`fix_allocator_thresholds` this does nothing.

    Returns
    -------
    bool
        True when the thresholds were set.
    """
    if _thresholds_fixed or os.environ.get("DIFFUSERLAB_DEFAULT_MALLOC") == "1":
        return False
    ok = _set_thresholds(256 * 2**20, 2**30)
    log.debug("glibc mallopt thresholds raised: %s", ok)
    return ok


#: Whether importing this module raised glibc's allocator thresholds
#: (:func:`retain_freed_memory`; False off glibc or with ``DIFFUSERLAB_DEFAULT_MALLOC=1``).
#:
#: :meta hide-value:
RETAINS_FREED_MEMORY = retain_freed_memory()


def fast_padded_shape(shape: tuple[int, ...], factor: int = 2) -> tuple[int, ...]:
    """Smallest fast real-FFT lengths of at least ``factor`` times each axis.

    Parameters
    ----------
    shape : tuple of int
        Sensor shape (rows, cols) or any n-d shape.
    factor : int
        Padding factor; 2 removes the circular wrap of Eq. 3.4 (Kuo 2020, Sec. 3.1).

    Returns
    -------
    tuple of int
        Padded shape whose every length is a 5-smooth number (fast for pocketfft).
    """
    return tuple(int(sfft.next_fast_len(factor * int(n), real=True)) for n in shape)


def rfftn(x: np.ndarray, axes=(-2, -1)) -> np.ndarray:
    """Real FFT over ``axes`` with the thread's workers (:func:`fft_workers`);
    float32 in gives complex64 out."""
    return sfft.rfftn(x, axes=axes, workers=fft_workers())


def irfftn(x: np.ndarray, shape: tuple[int, ...], axes=(-2, -1), *,
           overwrite_x: bool = False) -> np.ndarray:
    """Inverse real FFT over ``axes`` to real lengths ``shape`` (:func:`fft_workers`);
    ``overwrite_x`` lets the transform use ``x`` as its scratch (its content is then
    undefined), saving a copy of the spectrum."""
    return sfft.irfftn(x, s=shape, axes=axes, workers=fft_workers(), overwrite_x=overwrite_x)


def time_ffts(shape: tuple[int, ...], *, real: bool = True, stacks: tuple[int, ...] = (1,),
              repeats: int = 15, warmup: int = 2) -> float:
    """Median wall time of a fixed set of FFTs at ``shape``: the one FFT-floor timer.

    Every speed figure of the project is a ratio to such a floor, measured in the
    same process as the solver (the machine is shared and noisy):

    * ``real=True``: for each ``n`` in ``stacks``, a float32 stack ``(n, *shape)``
      (just ``shape`` when ``n == 1``) goes through rfftn + irfftn over the axes of
      ``shape`` (a batched pair; ``n`` pairs of transforms). The 2D solvers' floor
      is ``stacks=(1,)`` (:func:`fft_pair_seconds`), the 3D one
      ``stacks=(n_z, 1)`` (:func:`recon.volume.fft_floor_seconds`).
    * ``real=False``: one in-place complex64 ``fftn`` (``norm="ortho"``) per plane
      of each stack (the hologram optimiser's unit, ``instrument.benchmarks.hologram``).

    All transforms use :data:`WORKERS` threads.

    Parameters
    ----------
    shape : tuple of int
        Transform shape, e.g. the padded (rows, cols).
    real : bool
        Real pairs (True) or forward complex transforms (False).
    stacks : tuple of int
        Stack sizes (planes) transformed per timed repetition, each >= 1.
    repeats : int
        Timed repetitions (at least one); the median is returned.
    warmup : int
        Untimed repetitions first (plans, page faults).

    Returns
    -------
    float
        Seconds per repetition.
    """
    rng = np.random.default_rng(0)
    axes = tuple(range(-len(shape), 0))
    bufs = []
    for n in stacks:
        full = tuple(shape) if n == 1 else (n, *shape)
        if real:
            bufs.append(rng.random(full, dtype=np.float32))
        else:
            buf = np.empty(full, np.complex64)
            buf.real = rng.standard_normal(full, dtype=np.float32)
            buf.imag = 0.0
            bufs.append(buf)

    def once():
        for buf in bufs:
            if real:
                irfftn(rfftn(buf, axes), shape, axes)
            else:
                sfft.fftn(buf, axes=axes, norm="ortho", overwrite_x=True, workers=WORKERS)

    for _ in range(warmup):
        once()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        once()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def fft_pair_seconds(shape: tuple[int, ...], repeats: int = 15) -> float:
    """Median wall time of one rfft2 + irfft2 pair at ``shape`` in float32.

    This is the "FFT floor" of the 2D solvers: every iteration needs at least this,
    so speed is stated as ``seconds_per_iteration / fft_pair_seconds``, measured in
    the same process (:func:`time_ffts` with one real pair, two warm-up pairs).

    Parameters
    ----------
    shape : tuple of int
        Padded 2D shape (rows, cols).
    repeats : int
        Number of timed pairs; the median is returned.

    Returns
    -------
    float
        Seconds per pair.
    """
    return time_ffts(shape, repeats=repeats)
