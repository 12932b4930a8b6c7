"""3D FISTA sharded by plane slabs over dask.distributed workers (Kuo 2020, Eq. 4.4-4.5).

:func:`recon.volume.streamed.slab_fista` drives plane slabs
(:class:`recon.volume.slab.VolumeSlab`); here each slab is a dask **actor**: a
long-lived object in one worker holding its planes' PSF spectra and iterates for
the whole solve. Per iteration only sensor-sized images cross: each slab's partial
image to the loop, the weighted residual to each slab, and the TV boundary planes
(``v`` of a slab's first and last plane, ``y`` of its first) between neighbours,
through the loop. :class:`ShardedSlabs` counts the array bytes of every message to
and from each worker (``bytes_moved``).

The PSF stack reaches the workers either as a Zarr store chunked by plane (a path
every worker can read: each worker reads only its planes) or as NumPy slabs sent
once when the actors are made.

A worker lost mid-solve stops the solve with :class:`ShardLostError` (which worker,
which planes, what happened); nothing is written, and a rerun rebuilds the slabs.

The automatic weight's held-out path (:func:`recon.volume.streamed_auto.auto_streamed`,
what ``recon3d --scheduler`` runs with its default ``--tv auto``) takes a
:class:`ShardedSlabs` as it takes slabs in one process: the held-out mask stays in the
loop (it weights the summed image and the residual there, never sent), the path's
copies of the iterates stay in each worker beside its planes
(:meth:`recon.volume.slab.VolumeSlab.save`; a worker then holds
:func:`recon.volume.streamed.streamed_memory_bytes` of its slab with
``path_copies``), and per window of 10 iterations only the held-out score's partial
images and the copies' names cross besides the iterations' images.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path

import numpy as np

from diffuserlab.errors import InputError
from recon.operators import checked_sensor_weights
from recon.volume.operator import CHUNK_BYTES
from recon.volume.slab import VolumeSlab
from recon.volume.streamed import plan_slabs, slab_fista

__all__ = ["ShardLostError", "ShardedSlabs", "StoredSlab", "local_cluster", "sharded_fista3d",
           "slab_workers"]

log = logging.getLogger(__name__)

#: Seconds one slab call may take before the solve is declared stuck (a 64-plane
#: slab of 4096 x 4096 FFTs takes about a minute on 2 cores).
CALL_TIMEOUT_S = 3600.0

#: dask settings of a cluster that holds actors: their memory is neither spillable
#: nor freed by pausing, so the worker's spill / pause thresholds are off; the
#: nanny still ends a worker at 95 % of its memory limit.
ACTOR_MEMORY_CONFIG = {"distributed.worker.memory.target": False,
                       "distributed.worker.memory.spill": False,
                       "distributed.worker.memory.pause": False}


class ShardLostError(InputError):
    """A worker holding a slab was lost (or stopped answering) during a sharded solve."""


class StoredSlab(VolumeSlab):
    """A :class:`~recon.volume.slab.VolumeSlab` whose worker reads its planes from a Zarr
    store (a path or URL every worker can open; only planes ``start:stop`` are read)."""

    def __init__(self, store: str, start: int, stop: int, psf_scale: float, **kwargs):
        import zarr

        super().__init__(zarr.open_array(store, mode="r"), start, stop, psf_scale, **kwargs)


def _nbytes(obj) -> int:
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, list | tuple):
        return sum(_nbytes(o) for o in obj)
    return 0


class ShardedSlabs:
    """Plane slabs as dask actors, one or more per worker: :func:`slab_fista`'s group.

    Parameters
    ----------
    client : distributed.Client
    stack : str or ndarray
        A Zarr store of the PSF stack chunked by plane (path or URL; each worker
        reads its planes) or the stack itself (each slab's planes sent once).
    psf_scale : float
        Divisor of the stack (:func:`recon.volume.normalize_psf_stack`'s scale).
    n_z : int, optional
        Planes (read from the store or the array when omitted).
    slabs : int, optional
        Number of slabs (default: one per worker), assigned to the workers in turn.
    padded_shape, sensor_weights, support, chunk_bytes
        As :class:`recon.volume.slab.VolumeSlab`.
    timeout_s : float
        Longest one slab call may take.

    Attributes
    ----------
    plan : list of (start, stop)
    workers : list of str
        The worker address of each slab.
    bytes_moved : list of int
        Array bytes sent to and received from each slab so far.

    Raises
    ------
    ShardLostError
        No workers, or a worker failed while its slab was built.
    """

    def __init__(self, client, stack, psf_scale: float, *, n_z: int | None = None,
                 slabs: int | None = None, padded_shape=None, sensor_weights=None,
                 support: str = "sensor", chunk_bytes: int = CHUNK_BYTES,
                 timeout_s: float = CALL_TIMEOUT_S):
        workers = sorted(client.scheduler_info()["workers"])
        if not workers:
            raise ShardLostError("the dask cluster has no workers; start some "
                                 "(dask worker SCHEDULER) and rerun")
        stored = isinstance(stack, str | Path)
        if n_z is None:
            if stored:
                import zarr

                n_z = zarr.open_array(str(stack), mode="r").shape[0]
            else:
                n_z = stack.shape[0]
        self.plan = plan_slabs(n_z, len(workers) if slabs is None else slabs)
        self.workers = [workers[i % len(workers)] for i in range(len(self.plan))]
        self.timeout_s = float(timeout_s)
        self.iteration = 0
        opts = {"padded_shape": padded_shape, "sensor_weights": sensor_weights,
                "support": support, "chunk_bytes": chunk_bytes}
        futures = []
        for (a, z), addr in zip(self.plan, self.workers, strict=True):
            if stored:
                f = client.submit(StoredSlab, str(stack), a, z, psf_scale, actor=True,
                                  workers=[addr], allow_other_workers=False, **opts)
            else:
                f = client.submit(VolumeSlab, np.ascontiguousarray(stack[a:z]), 0, z - a,
                                  psf_scale, actor=True, workers=[addr],
                                  allow_other_workers=False, **opts)
            futures.append(f)
        self.bytes_moved = [0 if stored else int(stack[a:z].nbytes) for a, z in self.plan]
        self._futures = futures
        self.actors = []
        for i, f in enumerate(futures):
            try:
                self.actors.append(f.result(timeout=self.timeout_s))
            except Exception as exc:
                raise self._lost(i, "while its slab was built", exc) from None

    def __len__(self) -> int:
        return len(self.actors)

    def _lost(self, i: int, when: str, exc: BaseException) -> ShardLostError:
        a, z = self.plan[i]
        return ShardLostError(
            f"dask worker {self.workers[i]} holding planes {a}..{z - 1} was lost {when} "
            f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else 'no message'});"
            " the solve stopped and nothing was written; rerun (the slabs are rebuilt from "
            "the stack)")

    def call(self, method: str, args: list[tuple] | None = None) -> list:
        """Call ``method`` on every slab at once and wait for all; counts the bytes.

        Raises
        ------
        ShardLostError
            A worker died, the connection broke, or a call outlived ``timeout_s``.
        """
        args = args if args is not None else [()] * len(self.actors)
        pending = [getattr(actor, method)(*a) for actor, a in
                   zip(self.actors, args, strict=True)]
        out = []
        for i, (fut, a) in enumerate(zip(pending, args, strict=True)):
            try:
                res = fut.result(timeout=self.timeout_s)
            except Exception as exc:  # CommClosedError, a killed worker, a timeout ...
                raise self._lost(i, f"at iteration {self.iteration + 1} ({method})",
                                 exc) from None
            self.bytes_moved[i] += _nbytes(a) + _nbytes(res)
            out.append(res)
        if method == "prox":
            self.iteration += 1
        return out

    def gather(self, out: np.ndarray | None, which: str = "x") -> np.ndarray:
        """The estimate: each slab's ``x`` (or saved copy ``which``) fetched in turn into
        ``out`` (n_z, L0, L1)."""
        parts = self.call("estimate_shape")
        if out is None:
            out = np.empty((sum(p[0] for p in parts), *parts[0][1:]), np.float32)
        for i, ((a, z), actor) in enumerate(zip(self.plan, self.actors, strict=True)):
            try:
                out[a:z] = actor.estimate(which).result(timeout=self.timeout_s)
            except Exception as exc:
                raise self._lost(i, "while the estimate was gathered", exc) from None
            self.bytes_moved[i] += out[a:z].nbytes
        return out

    def close(self) -> None:
        """Release the actors (their workers free the slabs' memory)."""
        for f in self._futures:
            f.release()
        self.actors, self._futures = [], []


@contextlib.contextmanager
def slab_workers(scheduler: str | None, timeout_s: float = 30.0):
    """Context: the ``slab_group`` factory of a sharded 3D solve on the workers of the
    dask scheduler at ``scheduler`` (``recon3d --scheduler``), or None without one.

    Yields ``slab_group(h, psf_scale) -> ShardedSlabs`` (one slab per worker,
    :func:`recon.volume.api.reconstruct_stack`); the client is closed on the way out.

    Raises
    ------
    instrument.runs.runstore.RunStoreError
        Not a scheduler address, or nothing answers there
        (``instrument.processing.batch.check_scheduler``).
    """
    if scheduler is None:
        yield None
        return
    from .batch import _client, check_scheduler

    check_scheduler(scheduler)
    client, _ = _client(None, scheduler, timeout_s)
    try:
        yield lambda h, psf_scale: ShardedSlabs(client, h, psf_scale)
    finally:
        client.close()


def local_cluster(workers: int, memory_limit: str | int, *, threads_per_worker: int = 1):
    """A LocalCluster of worker processes for slab actors, and its client.

    Parameters
    ----------
    workers : int
    memory_limit : str or int
        Per worker (e.g. ``"10GB"``); spill and pause are off (:data:`ACTOR_MEMORY_CONFIG`).
    threads_per_worker : int

    Returns
    -------
    client, cluster
    """
    import dask
    from dask.distributed import Client, LocalCluster

    with dask.config.set(ACTOR_MEMORY_CONFIG):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker,
                               processes=True, memory_limit=memory_limit,
                               dashboard_address=":0", host="127.0.0.1")
    return Client(cluster), cluster


def sharded_fista3d(client, stack, b: np.ndarray, *, psf_scale: float = 1.0,
                    slabs: int | None = None, support: str = "sensor", sensor_weights=None,
                    padded_shape=None, chunk_bytes: int = CHUNK_BYTES,
                    timeout_s: float = CALL_TIMEOUT_S, on_slab=None, **solver):
    """3D FISTA with the planes sharded over the client's workers.

    Parameters
    ----------
    client : distributed.Client
    stack : str or ndarray
        Zarr store path (chunked by plane) or the PSF stack, (n_z, rows, cols).
    b : ndarray, float32, (rows, cols)
        Scaled measurement.
    psf_scale : float
    slabs : int, optional
        Default one per worker.
    support, sensor_weights, padded_shape, chunk_bytes
        As :class:`recon.volume.slab.VolumeSlab`.
    timeout_s : float
    on_slab : callable, optional
        ``on_slab(start, stop, x_slab)`` for each slab's estimate in turn, instead of
        gathering the whole volume here (``SolveResult.x`` is then None): the loop
        never holds more than one slab of it.
    **solver
        :func:`recon.volume.streamed.slab_fista`'s keywords.

    Returns
    -------
    SolveResult
        As :func:`~recon.volume.streamed.slab_fista`; ``params`` adds ``workers``
        (each slab's), ``slab_planes`` and ``seconds_setup`` (building the slabs).

    Raises
    ------
    ShardLostError
        A worker lost mid-solve (nothing is returned or written).
    """
    t0 = time.perf_counter()
    w = None if sensor_weights is None else checked_sensor_weights(sensor_weights, b.shape)
    group = ShardedSlabs(client, stack, psf_scale, slabs=slabs, padded_shape=padded_shape,
                         sensor_weights=w, support=support, chunk_bytes=chunk_bytes,
                         timeout_s=timeout_s)
    setup = time.perf_counter() - t0
    log.info("sharded 3D FISTA: %d slabs %s on %s (%.1f s to build)", len(group), group.plan,
             group.workers, setup)
    try:
        result = slab_fista(group, b, sensor_weights=w, gather=on_slab is None, **solver)
        if on_slab is not None:
            for i, (a, z) in enumerate(group.plan):
                try:
                    x = group.actors[i].estimate().result(timeout=group.timeout_s)
                except Exception as exc:
                    raise group._lost(i, "while the estimate was gathered", exc) from None
                on_slab(a, z, x)
                del x
    finally:
        group.close()
    result.params.update(workers=group.workers, slab_planes=group.plan,
                         seconds_setup=setup)
    return result
