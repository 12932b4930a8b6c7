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
"""

from __future__ import annotations

import logging

__all__ = ["HEARTBEAT_FAILURE", "close_local_cluster", "quiet_heartbeat_failure"]

#: What ``distributed.worker`` logs when a heartbeat meets a closed scheduler.
HEARTBEAT_FAILURE = "Failed to communicate with scheduler during heartbeat."

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
                client.run(quiet_heartbeat_failure, on_error="ignore")
            except Exception as exc:  # noqa: BLE001 (the workers' own state: closed anyway)
                log.debug("could not quiet the workers before closing: %s", exc)
    finally:
        try:
            if client is not None:
                client.close()
        finally:
            if cluster is not None:
                cluster.close()
