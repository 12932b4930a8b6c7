"""Closing a local dask cluster without its workers' shutdown race on the console.

A ``LocalCluster`` closes by retiring its workers, then stopping the scheduler. A
worker whose heartbeat to the scheduler is in flight while the scheduler drops its
connection logs ``Failed to communicate with scheduler during heartbeat.`` with a
``CommClosedError`` traceback (``distributed.worker``, ERROR), though nothing failed:
the batch has finished and its frames are stored. On a busy machine that is common
(seen in the emulated operator day's batch step at load 16, the worker still alive
4 s into its close). An operator reads a traceback as a failure, so as its cluster
closes each worker is first told to drop that one message (:func:`quiet_heartbeat_failure`,
run on every worker); every other record of the workers still reaches the console.

Two more ways a finished batch used to end badly under load, both seen in the emulated
operator day beside three busy loops (load 9-25):

- zarr's exit hook stops its I/O thread's event loop and waits 0.2 s for it; a worker
  process starved of a core misses that, and its exit printed "Thread did not finish
  cleanly" and a ``RuntimeError: Cannot close a running event loop`` traceback. Each
  worker now stops that loop itself before the cluster closes, waiting up to
  :data:`WORKER_STOP_S` (:func:`stop_zarr_io`), so the hook finds nothing to do.
- distributed gives each worker process 5 s to exit when its cluster closes, then kills
  it and waits 5 s more, and raises ``TimeoutError`` out of ``LocalCluster.close``:
  the batch, whose frames were all stored, was reported as failed with an "unexpected
  error". The workers are now closed first with :data:`WORKER_STOP_S` each, and a
  close that still runs out of time is logged as a warning, never raised.
"""

from __future__ import annotations

import logging

__all__ = ["HEARTBEAT_FAILURE", "WORKER_STOP_S", "close_local_cluster", "prepare_worker_exit",
           "quiet_heartbeat_failure", "stop_zarr_io"]

#: What ``distributed.worker`` logs when a heartbeat meets a closed scheduler.
HEARTBEAT_FAILURE = "Failed to communicate with scheduler during heartbeat."

#: How long, s, a worker process of a closing local cluster may take to stop (zarr's
#: I/O loop, then the process itself): a hang guard, not a wait.
WORKER_STOP_S = 60.0

log = logging.getLogger(__name__)


class _HeartbeatFailureFilter(logging.Filter):
    """Drops :data:`HEARTBEAT_FAILURE` records, and only them."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.getMessage() != HEARTBEAT_FAILURE


def quiet_heartbeat_failure() -> None:
    """In a dask worker process (``client.run``): from now on ``distributed.worker``
    drops :data:`HEARTBEAT_FAILURE` records; its other records are kept. Once per
    process (a second call adds nothing)."""
    logger = logging.getLogger("distributed.worker")
    if not any(isinstance(f, _HeartbeatFailureFilter) for f in logger.filters):
        logger.addFilter(_HeartbeatFailureFilter())


def stop_zarr_io(timeout_s: float = WORKER_STOP_S) -> bool:
    """Stop zarr's I/O thread and close its event loop in this process, waiting up to
    ``timeout_s`` for the thread (zarr's own exit hook waits 0.2 s, then closes the
    still-running loop with a traceback). zarr starts them again when next used.

    Parameters
    ----------
    timeout_s : float
        The longest wait for the I/O thread, s.

    Returns
    -------
    bool
        True when nothing is left running (or zarr never started its loop here).
    """
    try:
        from zarr.core import sync
    except ImportError:  # pragma: no cover - zarr is a dependency
        return True
    loop_box, thread_box = getattr(sync, "loop", None), getattr(sync, "iothread", None)
    if not loop_box or loop_box[0] is None or not thread_box:
        return True
    with sync._get_lock():
        loop, thread = loop_box[0], thread_box[0]
        if loop is None:
            return True
        loop.call_soon_threadsafe(loop.stop)
        if thread is not None:
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("zarr's I/O thread did not stop within %g s", timeout_s)
                return False
        loop.close()
        loop_box[0] = None
        thread_box[0] = None
    return True


def prepare_worker_exit() -> None:
    """In a dask worker process whose cluster is about to close (``client.run``):
    :func:`quiet_heartbeat_failure` and :func:`stop_zarr_io`."""
    quiet_heartbeat_failure()
    stop_zarr_io()


async def _close_workers(workers, timeout_s: float) -> None:
    """Close ``workers`` (the cluster's nannies) at once, each given ``timeout_s``."""
    import asyncio

    results = await asyncio.gather(*(w.close(timeout=timeout_s) for w in workers),
                                   return_exceptions=True)
    for worker, result in zip(workers, results, strict=True):
        if isinstance(result, BaseException):
            log.warning("a batch worker did not close cleanly (%s): %s",
                        getattr(worker, "address_safe", worker), result or type(result).__name__)


def close_local_cluster(client, cluster) -> None:
    """Close ``client`` and the local ``cluster`` it was made with (either may be None).

    Each worker still answering is told first to drop its heartbeat-failure record
    (:func:`quiet_heartbeat_failure`); a worker that does not answer (killed, ended)
    changes nothing, and the cluster is closed all the same.

    Parameters
    ----------
    client : distributed.Client or None
    cluster : distributed.LocalCluster or None
        A cluster this process started (not a scheduler it connected to: its workers
        are not ours to change).
    """
    try:
        if client is not None and cluster is not None:
            try:
                client.run(prepare_worker_exit, on_error="ignore")
            except Exception as exc:  # noqa: BLE001 (the workers' own state: closed anyway)
                log.debug("could not prepare the workers for closing: %s", exc)
    finally:
        try:
            if client is not None:
                client.close()
        finally:
            if cluster is not None:
                _close_cluster(cluster)


def _close_cluster(cluster) -> None:
    """Close ``cluster``: its worker processes first, each given :data:`WORKER_STOP_S`
    (distributed's own close gives them 5 s), then the rest; running out of time is a
    warning (the batch's results are stored by then), never an error."""
    try:
        workers = list(getattr(cluster, "workers", {}).values())
        if workers:
            cluster.sync(_close_workers, workers, WORKER_STOP_S)
    except Exception as exc:  # noqa: BLE001 (closed again below, whatever is left)
        log.warning("closing the batch's workers: %s", exc or type(exc).__name__)
    try:
        cluster.close(timeout=2 * WORKER_STOP_S)
    except TimeoutError:
        log.warning("the batch's local dask cluster did not close within %g s; its "
                    "results are stored, and its worker processes were told to stop",
                    2 * WORKER_STOP_S)
