"""Which 3D solve fits: the in-memory solvers or the streamed one (Kuo 2020, Ch. 4).

:func:`recon.reconstruct` of a PSF stack asks :func:`memory_plan` whether the
in-memory plan (whole padded volumes, :func:`recon.volume.estimate_memory_bytes`)
fits the memory it may use (``memory_limit_bytes``, or what the machine has
available now); if not, :func:`solve_streamed` runs 3D FISTA over plane slabs
(:mod:`recon.volume.streamed`) with the iterates on the sensor's field of view,
prints its memory estimate before the solve and records the measured peak. With an
automatic weight the streamed solve runs the held-out path of :mod:`recon.auto` over
the slabs (:func:`recon.volume.streamed_auto.auto_streamed`), whose copies of the
iterates the estimate counts.
"""

from __future__ import annotations

import os
import time

import numpy as np

from ..auto.volume import VOLUME_RULES
from ..errors import ReconInputError
from ..fft import fast_padded_shape
from ..operators import padded_grid
from .operator import estimate_memory_bytes
from .slab import VolumeSlab
from .streamed import (
    PATH_SENSOR_IMAGES,
    LocalSlabs,
    StreamedModel,
    peak_rss_bytes,
    slab_fista,
    streamed_memory_bytes,
)
from .streamed_auto import auto_streamed, path_copies

__all__ = ["ADMM_VOLUMES", "available_memory_bytes", "current_rss_bytes", "in_memory_bytes",
           "memory_plan", "solve_streamed"]

#: Padded float32 volumes the in-memory 3D ADMM holds at its peak (with TV): 11, i.e.
#: 44 bytes per padded voxel plus 2 for the spectra, against the ~45 measured on
#: ``recon3d`` (the automatic weight keeps two more estimates).
ADMM_VOLUMES = 11


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


def in_memory_bytes(method: str, auto: bool, sensor_shape: tuple[int, int], n_z: int) -> int:
    """Estimated peak bytes of the in-memory 3D solve: FISTA's 5 padded volumes or
    ADMM's :data:`ADMM_VOLUMES` (2 more with the automatic weight's path), plus the
    spectra and buffers (:func:`recon.volume.estimate_memory_bytes`)."""
    volumes = 5 if method == "fista" and not auto else ADMM_VOLUMES + (2 if auto else 0)
    return int(estimate_memory_bytes(tuple(sensor_shape), n_z, volumes=volumes)["total"])


def memory_plan(method: str, auto: bool, sensor_shape: tuple[int, int], n_z: int,
                memory_limit_bytes: int | None = None) -> dict:
    """Whether the in-memory 3D solve fits, and why.

    Parameters
    ----------
    method : {"admm", "fista"}
    auto : bool
        An automatic weight (in memory: the 3D ADMM path; streamed: the same path over
        the slabs, :mod:`recon.volume.streamed_auto`).
    sensor_shape : (rows, cols)
        After binning.
    n_z : int
    memory_limit_bytes : int, optional
        What the solve may use; None: :func:`available_memory_bytes` now.

    Returns
    -------
    dict
        ``streamed`` (bool), ``in_memory_bytes``, ``limit_bytes``, ``limit_source``
        (``"--memory-limit"`` or ``"available"``), ``reason`` (one sentence).

    Raises
    ------
    ReconInputError
        A limit that is not a positive number of bytes.
    """
    need = in_memory_bytes(method, auto, sensor_shape, n_z)
    if memory_limit_bytes is None:
        limit, source = available_memory_bytes(), "available"
    else:
        if isinstance(memory_limit_bytes, bool) or not memory_limit_bytes > 0:
            raise ReconInputError(f"memory limit {memory_limit_bytes!r}: give a positive "
                                  "size, e.g. --memory-limit 16GB")
        limit, source = int(memory_limit_bytes), "--memory-limit"
    streamed = need > limit
    pad = fast_padded_shape(tuple(sensor_shape))
    what = (f"the in-memory 3D {method.upper()} on {n_z} planes padded to {pad[0]}x{pad[1]} "
            f"needs about {need / 1e9:.1f} GB, {'more' if streamed else 'less'} than the "
            f"{limit / 1e9:.1f} GB "
            f"{'given by --memory-limit' if source != 'available' else 'available'}")
    reason = (f"{what}: streamed 3D FISTA (planes transformed one chunk at a time, iterates "
              "on the sensor's field of view"
              + ("; the automatic weight by the held-out path over the slabs)" if auto else ")")
              if streamed else what)
    return {"streamed": streamed, "in_memory_bytes": need, "limit_bytes": limit,
            "limit_source": source, "reason": reason}


def solve_streamed(held: list, b: np.ndarray, *, iterations: int, tv: float, l1: float,
                   depths=None, slab_group=None, announce=None, auto: dict | None = None,
                   limit_bytes: int | None = None) -> tuple:
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
        :func:`instrument.volume_shards.ShardedSlabs`); default one slab here.
    announce : callable, optional
        ``announce(line)``: the estimate, before the solve (e.g. ``print``).
    auto : dict, optional
        The automatic weight: ``noise`` (the frame's :class:`recon.auto.noise.NoiseModel`
        in the units of ``b``), ``regulariser`` ("tv" or "l1") and ``other`` (the other
        weight, fixed), for :func:`recon.volume.streamed_auto.auto_streamed`.
    limit_bytes : int, optional
        The memory the solve may use (:func:`memory_plan`'s ``limit_bytes``): the
        estimate line says when the slabs' arrays alone exceed it (and, with
        ``auto``, what a fixed weight's would need); the solve runs all the same.

    Returns
    -------
    result : SolveResult
        ``x`` on the sensor grid (n_z, rows, cols).
    model : StreamedModel
    memory : dict
        ``estimate_bytes`` (the process's resident set at the start plus
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
    baseline = current_rss_bytes()
    t0 = time.perf_counter()
    group = (LocalSlabs([VolumeSlab(h, 0, n_z, 1.0)]) if slab_group is None
             else slab_group(h, 1.0))
    plan = ([(s.start, s.stop) for s in group.slabs] if slab_group is None
            else list(group.plan))
    copies = 0 if auto is None else path_copies(VOLUME_RULES[auto["regulariser"]])
    if slab_group is None:
        arrays = streamed_memory_bytes((rows, cols), n_z, path_copies=copies)
        # the stack is freed once the spectra are made: no part of the solve's peak
        estimate = baseline - h.nbytes + arrays["total"]
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
    if limit_bytes is not None and slab_group is None and arrays["total"] > limit_bytes:
        fixed = streamed_memory_bytes((rows, cols), n_z)["total"]
        line += (f"; its arrays alone are more than the {limit_bytes / 1e9:.2f} GB limit"
                 + ("" if auto is None else f" (with a fixed --tv, {fixed / 1e9:.2f} GB)"))
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
