"""Which 3D solve fits the memory it may use, or why none does (Kuo 2020, Ch. 4).

:func:`recon.reconstruct` of a PSF stack asks :func:`memory_plan` which plan of the
solve fits (:data:`PLANS`, fastest first): the in-memory solver asked for (whole
padded volumes, :func:`recon.volume.estimate_memory_bytes`), streamed 3D FISTA over
plane slabs (:mod:`recon.volume.streamed`, the iterates on the sensor's field of
view) transforming a chunk of planes at a time, or the same one plane at a time.
Each plan's estimate is this process's peak resident set: what it holds now
(:func:`process_baseline_bytes`, the solvers' compiled kernels loaded) plus the
plan's arrays and :data:`SOLVE_OVERHEAD_BYTES` (less the PSF stack, which a streamed
solve frees once its spectra are made). The first plan within ``--memory-limit`` (or
within what the machine has available now) runs; with a limit below every plan the
solve is refused before any work (:class:`recon.errors.ReconInputError`), naming the
smallest limit that would do and what lowers it (a fixed weight, more binning, fewer
planes). With an automatic weight the streamed solve runs the held-out path of
:mod:`recon.auto` over the slabs (:func:`recon.volume.streamed_auto.auto_streamed`),
whose copies of the iterates the estimate counts. ``diffuserlab benchmark
memory-limit`` checks that the measured peak stays within the limit.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from ..auto.volume import VOLUME_RULES
from ..errors import ReconInputError
from ..fft import fast_padded_shape
from ..operators import padded_grid
from .operator import CHUNK_BYTES, estimate_memory_bytes
from .slab import VolumeSlab, warm_up
from .streamed import (
    PATH_SENSOR_IMAGES,
    LocalSlabs,
    StreamedModel,
    peak_rss_bytes,
    slab_fista,
    streamed_memory_bytes,
)
from .streamed_auto import auto_streamed, path_copies

__all__ = ["ADMM_VOLUMES", "AUTO_VOLUMES", "ONE_PLANE_CHUNK_BYTES", "PLANS", "SOLVE_OVERHEAD_BYTES",
           "available_memory_bytes",
           "current_rss_bytes", "in_memory_bytes", "memory_plan", "plan_estimates",
           "process_baseline_bytes", "solve_streamed"]

#: Padded float32 volumes the in-memory 3D ADMM holds at its peak (with TV): 11, i.e.
#: 44 bytes per padded voxel plus 2 for the spectra, against the ~45 measured on
#: ``recon3d``.
ADMM_VOLUMES = 11

#: Padded float32 volumes the in-memory automatic weight adds to 3D ADMM's: the 6 of
#: ``recon.volume.xp_admm3d.auto3d_extra_bytes`` (the path's kept estimates, the
#: final solve's best iterate, the fit measurement) and one of temporaries (measured
#: on ``recon3d``), besides a second copy of the PSF spectra (the fit plan's operator).
AUTO_VOLUMES = 7

#: What a solve adds to the process that its arrays leave out, bytes: the first loads
#: of its other kernels and modules, FFT plans, and writing the outputs (``recon3d``:
#: 1-26 MB beyond the arrays at 256 x 256 x 8 and 512 x 512 x 16, the larger on the
#: automatic weight's path; ``diffuserlab benchmark memory-limit``).
SOLVE_OVERHEAD_BYTES = 32 * 2**20

#: The plans of a 3D solve in one process, in the order they are preferred: the
#: in-memory solver asked for, streamed 3D FISTA transforming a chunk of planes at a
#: time (:data:`recon.volume.operator.CHUNK_BYTES`), and the same one plane at a time
#: (the smallest FFT temporaries, the slowest).
PLANS = ("in-memory", "streamed", "streamed, one plane at a time")

#: ``chunk_bytes`` that makes every chunk of a streamed solve one plane.
ONE_PLANE_CHUNK_BYTES = 1


def available_memory_bytes() -> int:
    """Memory the machine has available now (Linux ``MemAvailable``; elsewhere the free
    physical pages), bytes."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def current_rss_bytes() -> int:
    """This process's resident set size now, bytes (``/proc/self/statm``; elsewhere the
    peak so far)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return peak_rss_bytes()


def process_baseline_bytes() -> int:
    """This process's resident set with the 3D solvers' numba kernels loaded, bytes:
    what every plan's estimate starts from.

    Loads the streamed slab's kernels first (:func:`recon.volume.slab.warm_up`, from
    numba's on-disk cache once compiled): the first kernels a process loads bring
    numba's compiler with them, about 55 MB, which would otherwise land inside the
    solve, above the estimate.
    """
    warm_up()
    return current_rss_bytes()


def in_memory_bytes(method: str, auto: bool, sensor_shape: tuple[int, int], n_z: int) -> int:
    """Estimated peak bytes of the in-memory 3D solve's arrays: FISTA's 5 padded
    volumes or ADMM's :data:`ADMM_VOLUMES` (the automatic weight's path runs ADMM and
    adds :data:`AUTO_VOLUMES` and a second copy of the spectra), plus the spectra and
    buffers (:func:`recon.volume.estimate_memory_bytes`)."""
    extra = AUTO_VOLUMES if auto else 0
    volumes = 5 if method == "fista" and not auto else ADMM_VOLUMES + extra
    est = estimate_memory_bytes(tuple(sensor_shape), n_z, volumes=volumes)
    return int(est["total"] + (est["psf_spectra"] if auto else 0))


def plan_estimates(method: str, auto, sensor_shape: tuple[int, int], n_z: int, *,
                   baseline_bytes: int = 0, stack_bytes: int = 0) -> list[dict]:
    """Every plan of :data:`PLANS` for one solve, with its arrays and estimated peak.

    Parameters
    ----------
    method : {"admm", "fista"}
        The in-memory solver asked for.
    auto : bool or str
        An automatic weight (truthy; ``"tv"`` or ``"l1"`` names it).
    sensor_shape : (rows, cols)
        After binning.
    n_z : int
    baseline_bytes : int
        This process's resident set now (:func:`process_baseline_bytes`).
    stack_bytes : int
        The normalised PSF stack's bytes, part of ``baseline_bytes``: a streamed solve
        frees it once the slabs hold the spectra.

    Returns
    -------
    list of dict
        In the order of :data:`PLANS` (the one-plane plan left out where a chunk is one
        plane already): ``plan`` (its name), ``streamed`` (bool), ``chunk_bytes`` (the
        streamed slabs'; None in memory), ``arrays_bytes``
        (:func:`in_memory_bytes` or :func:`recon.volume.streamed.streamed_memory_bytes`
        with the automatic weight's copies) and ``estimate_bytes`` (the process's peak:
        ``baseline_bytes`` plus the arrays and :data:`SOLVE_OVERHEAD_BYTES`, less
        ``stack_bytes`` when streamed).
    """
    base = int(baseline_bytes) + SOLVE_OVERHEAD_BYTES
    need = in_memory_bytes(method, bool(auto), sensor_shape, n_z)
    plans = [{"plan": PLANS[0], "streamed": False, "chunk_bytes": None,
              "arrays_bytes": need, "estimate_bytes": base + need}]
    copies = path_copies(VOLUME_RULES[auto if auto in VOLUME_RULES else "tv"]) if auto else 0
    for name, chunk in zip(PLANS[1:], (CHUNK_BYTES, ONE_PLANE_CHUNK_BYTES), strict=True):
        arrays = streamed_memory_bytes(tuple(sensor_shape), n_z, chunk_bytes=chunk,
                                       path_copies=copies)["total"]
        if plans[-1]["streamed"] and arrays == plans[-1]["arrays_bytes"]:
            continue  # a chunk was one plane already
        plans.append({"plan": name, "streamed": True, "chunk_bytes": chunk,
                      "arrays_bytes": arrays,
                      "estimate_bytes": base - int(stack_bytes) + arrays})
    return plans


def memory_plan(method: str, auto, sensor_shape: tuple[int, int], n_z: int,
                memory_limit_bytes: int | None = None, *, baseline_bytes: int = 0,
                stack_bytes: int = 0, bin_factor: int, sharded: bool = False,
                streamable: bool = True) -> dict:
    """The plan of a 3D solve that fits the memory it may use, and why.

    The first plan of :func:`plan_estimates` whose estimate is within the ceiling:
    ``memory_limit_bytes`` (the most this process's resident set may reach), or
    without one this process's resident set plus what the machine has available now.

    Parameters
    ----------
    method : {"admm", "fista"}
    auto : bool or str
        An automatic weight (in memory: the 3D ADMM path; streamed: the same path over
        the slabs, :mod:`recon.volume.streamed_auto`); ``"tv"`` or ``"l1"`` names it.
    sensor_shape : (rows, cols)
        After binning.
    n_z : int
    memory_limit_bytes : int, optional
        The most this process's resident set may reach, bytes; None: what it holds
        plus :func:`available_memory_bytes` now.
    baseline_bytes : int
        This process's resident set now (:func:`process_baseline_bytes`).
    stack_bytes : int
        The normalised PSF stack's bytes (freed by a streamed solve).
    bin_factor : int
        The binning asked for (the refusal suggests twice it).
    sharded : bool
        The slabs live in dask workers (their memory is the workers'): streamed,
        whatever fits here, never refused.
    streamable : bool
        False: the in-memory plan is the only one (a prior other than TV).

    Returns
    -------
    dict
        ``streamed`` (bool), ``plan`` (its name in :data:`PLANS`), ``chunk_bytes``,
        ``estimate_bytes`` (the chosen plan's), ``in_memory_bytes`` (the in-memory
        plan's arrays), ``baseline_bytes``, ``limit_bytes``, ``limit_source``
        (``"--memory-limit"`` or ``"available"``), ``ceiling_bytes`` (what the
        estimates were held against), ``plans`` (:func:`plan_estimates`), ``fits``
        (False only without a limit: nothing fits what is available, and the smallest
        plan runs) and ``reason`` (one sentence).

    Raises
    ------
    ReconInputError
        A limit that is not a positive number of bytes; a limit below every plan's
        estimate (one line: the smallest plan's estimate, the smallest limit that
        would do, and what lowers it).
    """
    plans = plan_estimates(method, auto, sensor_shape, n_z, baseline_bytes=baseline_bytes,
                           stack_bytes=stack_bytes)
    if memory_limit_bytes is None:
        limit, source = available_memory_bytes(), "available"
        ceiling = int(baseline_bytes) + limit
    else:
        if isinstance(memory_limit_bytes, bool) or not memory_limit_bytes > 0:
            raise ReconInputError(f"memory limit {memory_limit_bytes!r}: give a positive "
                                  "size, e.g. --memory-limit 16GB")
        limit, source = int(memory_limit_bytes), "--memory-limit"
        ceiling = limit
    candidates = plans if streamable or sharded else plans[:1]
    fitting = [p for p in candidates if p["estimate_bytes"] <= ceiling]
    smallest = min(candidates, key=lambda p: p["estimate_bytes"])
    if sharded:
        chosen = plans[1]
    elif fitting:
        chosen = fitting[0]
    elif source == "available":
        chosen = smallest
    else:
        raise ReconInputError(_refusal(method, auto, sensor_shape, n_z, limit, candidates,
                                       baseline_bytes, stack_bytes, bin_factor))
    reason = _reason(method, auto, sensor_shape, n_z, plans, chosen, limit, source,
                     ceiling - limit)
    if sharded:
        reason += "; sharded over the dask workers as asked"
    return {"streamed": chosen["streamed"], "plan": chosen["plan"],
            "chunk_bytes": chosen["chunk_bytes"], "estimate_bytes": chosen["estimate_bytes"],
            "in_memory_bytes": plans[0]["arrays_bytes"], "baseline_bytes": int(baseline_bytes),
            "limit_bytes": limit, "limit_source": source, "ceiling_bytes": ceiling,
            "plans": plans, "fits": bool(fitting) or sharded, "reason": reason}


def _gb(n: float) -> str:
    return f"{n / 1e9:.2f} GB"


def _reason(method, auto, sensor_shape, n_z, plans, chosen, limit, source, held) -> str:
    """One sentence: which plan runs and why (the plans before it did not fit); ``held``
    is what this process holds now where the limit is what is available."""
    pad = fast_padded_shape(tuple(sensor_shape))
    what = f"the in-memory 3D {method.upper()} on {n_z} planes padded to {pad[0]}x{pad[1]}"
    if source == "available":
        beyond = plans[0]["estimate_bytes"] - held
        what += (f" needs about {_gb(beyond)} beyond what this process holds, "
                 f"{'less' if beyond <= limit else 'more'} than the {_gb(limit)} available")
    else:
        fits = plans[0]["estimate_bytes"] <= limit
        what += (f" needs about {_gb(plans[0]['estimate_bytes'])} with this process, "
                 f"{'within' if fits else 'more than'} the {_gb(limit)} given by "
                 "--memory-limit")
    if not chosen["streamed"]:
        return what
    how = "a chunk" if chosen["plan"] == PLANS[1] else "one"
    text = (f"{what}: streamed 3D FISTA (planes transformed {how} at a time, iterates on "
            "the sensor's field of view"
            + ("; the automatic weight by the held-out path over the slabs" if auto else "")
            + f"), estimated {_gb(chosen['estimate_bytes'])} with this process")
    if chosen["plan"] == PLANS[2]:
        text += f" (in chunks of planes {_gb(plans[1]['estimate_bytes'])})"
    if source == "available" and chosen["estimate_bytes"] - held > limit:
        text += ("; no plan fits what is available: the smallest runs and may swap or be "
                 "stopped (a --memory-limit refuses it instead)")
    return text


def _smallest(method, auto, shape, n_z, baseline_bytes, stack_bytes, streamable) -> int:
    """The smallest estimate of the plans a solve may run, bytes."""
    plans = plan_estimates(method, auto, shape, n_z, baseline_bytes=baseline_bytes,
                           stack_bytes=stack_bytes)
    return min(p["estimate_bytes"] for p in (plans if streamable else plans[:1]))


def _refusal(method, auto, sensor_shape, n_z, limit, plans, baseline_bytes, stack_bytes,
             bin_factor) -> str:
    """The one line that refuses a limit below every plan: the smallest plan's estimate,
    the smallest limit that would do, and what lowers the need."""
    rows, cols = (int(n) for n in sensor_shape)
    streamable = len(plans) > 1
    small = min(plans, key=lambda p: p["estimate_bytes"])
    name = (f"the in-memory 3D {method.upper()}" if not small["streamed"] else
            "streamed 3D FISTA " + ("a chunk of planes at a time" if small["plan"] == PLANS[1]
                                    else "one plane at a time"))
    options = []
    if auto:
        fixed = _smallest(method, False, sensor_shape, n_z, baseline_bytes, stack_bytes,
                          streamable)
        options.append(f"a fixed --{auto if auto in VOLUME_RULES else 'tv'} weight "
                       f"({_gb(fixed)})")
    if min(rows, cols) >= 4:
        binned = _smallest(method, auto, (rows // 2, cols // 2), n_z, baseline_bytes,
                           stack_bytes // 4, streamable)
        options.append(f"--bin {2 * int(bin_factor)} ({_gb(binned)})")
    fewer = _most_planes(method, auto, sensor_shape, n_z, limit, baseline_bytes, stack_bytes,
                         streamable)
    if fewer:
        options.append(f"at most {fewer[0]} of the {n_z} planes ({_gb(fewer[1])})")
    need = small["estimate_bytes"]
    return (f"--memory-limit {_gb(limit)} is below every plan of this 3D solve ({n_z} "
            f"planes of {rows}x{cols}{', automatic weight' if auto else ''}): the smallest, "
            f"{name}, is estimated at {_gb(need)} (this process now {_gb(baseline_bytes)}, "
            f"plus {_gb(small['arrays_bytes'])} of arrays and "
            f"{_gb(SOLVE_OVERHEAD_BYTES)} of the solve's other loads"
            f"{', less the PSF stack' if small['streamed'] else ''}); give --memory-limit "
            f"{math.ceil(need / 1e7) / 100:.2f}GB or more"
            + (f", or lower the need: {', '.join(options)}" if options else ""))


def _most_planes(method, auto, sensor_shape, n_z, limit, baseline_bytes, stack_bytes,
                 streamable):
    """The most planes (fewer than ``n_z``) whose smallest plan fits ``limit``, and that
    plan's estimate; None if not even one plane fits."""
    def est(k):
        return _smallest(method, auto, sensor_shape, k, baseline_bytes,
                         stack_bytes * k // n_z, streamable)

    lo, hi = 0, n_z - 1  # est(lo) fits (lo 0: none known yet); more than hi do not
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if est(mid) <= limit:
            lo = mid
        else:
            hi = mid - 1
    return (lo, est(lo)) if lo >= 1 else None


def solve_streamed(held: list, b: np.ndarray, *, iterations: int, tv: float, l1: float,
                   depths=None, slab_group=None, announce=None, auto: dict | None = None,
                   chunk_bytes: int = CHUNK_BYTES, baseline_bytes: int | None = None
                   ) -> tuple:
    """Streamed 3D FISTA on a normalised stack, with its memory estimate and peak; with
    ``auto``, its weight chosen by the held-out path over the slabs.

    Parameters
    ----------
    held : list
        One element, the normalised PSF stack (ndarray, float32, (n_z, rows, cols),
        :func:`recon.volume.normalize_psf_stack`); the list is emptied once the
        slabs hold the spectra, so the stack is freed if the caller holds no other
        reference.
    b : ndarray, float32, (rows, cols)
        Scaled measurement.
    iterations : int
        Iterations (with ``auto``: of the fixed-weight run the path replaces; the path
        and its run-on take at most 3.5x as many).
    tv, l1 : float
        Fixed weights (with ``auto``, the one it chooses is not used).
    depths : list of float, optional
    slab_group : callable, optional
        ``slab_group(h, psf_scale) -> group``: slabs elsewhere (dask workers,
        :func:`instrument.processing.volume_shards.ShardedSlabs`); default one slab here.
    announce : callable, optional
        ``announce(line)``: the estimate, before the solve (e.g. ``print``).
    auto : dict, optional
        The automatic weight: ``noise`` (the frame's :class:`recon.auto.noise.NoiseModel`
        in the units of ``b``), ``regulariser`` ("tv" or "l1") and ``other`` (the other
        weight, fixed), for :func:`recon.volume.streamed_auto.auto_streamed`.
    chunk_bytes : int
        The slabs' chunk of planes transformed at once (:func:`memory_plan`'s
        ``chunk_bytes``; :data:`ONE_PLANE_CHUNK_BYTES`: one plane); slabs here only.
    baseline_bytes : int, optional
        This process's resident set, the stack included (:func:`memory_plan`'s
        ``baseline_bytes``, so that the estimate is the plan's); default measured now.

    Returns
    -------
    result : SolveResult
        ``x`` on the sensor grid (n_z, rows, cols).
    model : StreamedModel
    memory : dict
        ``estimate_bytes`` (the process's resident set at the start, or
        ``baseline_bytes``, plus
        :func:`~recon.volume.streamed.streamed_memory_bytes` of the slabs it holds,
        the path's copies of the iterates and sensor images included with ``auto``),
        ``arrays`` (that estimate's parts), ``baseline_rss_bytes``, ``peak_rss_bytes``
        (measured after the solve) and ``peak_over_estimate``; for slabs elsewhere
        the estimate is per worker (``per_worker``); with ``auto`` and the slabs here,
        ``path_copies_peak_bytes`` (the most the path's copies held at once, measured).
    record : dict or None
        With ``auto``: the automatic weight's record
        (:func:`~recon.volume.streamed_auto.auto_streamed`).
    """
    h = held[0]
    n_z, rows, cols = h.shape
    baseline = current_rss_bytes() if baseline_bytes is None else int(baseline_bytes)
    t0 = time.perf_counter()
    group = (LocalSlabs([VolumeSlab(h, 0, n_z, 1.0, chunk_bytes=chunk_bytes)])
             if slab_group is None
             else slab_group(h, 1.0))
    plan = ([(s.start, s.stop) for s in group.slabs] if slab_group is None
            else list(group.plan))
    copies = 0 if auto is None else path_copies(VOLUME_RULES[auto["regulariser"]])
    if slab_group is None:
        arrays = streamed_memory_bytes((rows, cols), n_z, path_copies=copies,
                                       chunk_bytes=chunk_bytes)
        # the stack is freed once the spectra are made: no part of the solve's peak
        estimate = baseline - h.nbytes + arrays["total"] + SOLVE_OVERHEAD_BYTES
        where = "this process"
    else:
        arrays = streamed_memory_bytes((rows, cols), max(z - a for a, z in plan),
                                       path_copies=copies)
        # the loop holds sensor images (the path's too) and, at the end, the gathered
        # estimate
        estimate = baseline + (12 + (PATH_SENSOR_IMAGES if auto else 0) + n_z) * b.nbytes
        where = (f"the loop, and {arrays['total'] / 1e9:.2f} GB of arrays in each of "
                 f"{len(plan)} slabs' workers")
    path = ("" if auto is None else
            f", the automatic weight's path: {copies} copies of the iterates "
            f"{arrays['path_copies'] / 1e9:.2f} GB and {PATH_SENSOR_IMAGES:g} sensor images")
    other = sum(arrays[k] for k in ("psf_spectra", "iterates", "path_copies") if k in arrays)
    line = (f"streamed 3D FISTA: {n_z} planes of {rows}x{cols}; estimated peak memory "
            f"{estimate / 1e9:.2f} GB in {where} (per slab: PSF spectra "
            f"{arrays['psf_spectra'] / 1e9:.2f} GB, iterates x, y, v "
            f"{arrays['iterates'] / 1e9:.2f} GB{path}, buffers "
            f"{(arrays['total'] - other) / 1e9:.2f} GB; "
            f"process before {baseline / 1e9:.2f} GB)")
    if announce is not None:
        announce(line)
    held.clear()
    del h
    record = None
    try:
        if auto is None:
            result = slab_fista(group, b, iterations=iterations, tv=tv, l1=l1, nonneg=True)
        else:
            result, record = auto_streamed(group, b, iterations=iterations, **auto)
    finally:
        if hasattr(group, "close"):
            group.close()
    saved = (None if auto is None or slab_group is not None
             else sum(s.peak_saved_bytes for s in group.slabs))
    del group
    result.params["seconds_setup_and_solve"] = time.perf_counter() - t0
    pad, _, crop = padded_grid((rows, cols))
    model = StreamedModel(n_z, (rows, cols), pad, crop, "sensor", plan, depths, arrays)
    peak = peak_rss_bytes()
    memory = {"estimate_bytes": int(estimate), "arrays": arrays,
              "baseline_rss_bytes": int(baseline), "peak_rss_bytes": peak,
              "peak_over_estimate": peak / estimate, "estimate_line": line,
              "slabs_elsewhere": slab_group is not None}
    if saved is not None:
        memory["path_copies_peak_bytes"] = int(saved)
    return result, model, memory, record
