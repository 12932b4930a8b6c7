"""A local dask cluster closes without its workers' heartbeat race on the console
(instrument.processing.cluster_close): real worker processes, their stderr read at the
file descriptor they inherit."""

from __future__ import annotations

import logging

from instrument.processing.batch import _client
from instrument.processing.cluster_close import HEARTBEAT_FAILURE, close_local_cluster

OTHER_ERROR = "a worker's own error, still shown"


def _log_heartbeat_failure() -> None:
    """In a worker: what distributed.worker logs when its heartbeat meets a closed
    scheduler (logger.exception, with the CommClosedError's traceback)."""
    try:
        raise OSError("in <TCP (closed) ConnectionPool.heartbeat_worker>: Stream is closed")
    except OSError:
        logging.getLogger("distributed.worker").exception(HEARTBEAT_FAILURE)


def _log_other_error() -> None:
    logging.getLogger("distributed.worker").error(OTHER_ERROR)


def test_closing_drops_the_heartbeat_failure_and_keeps_the_workers_other_errors(capfd):
    """Before: the emulated operator day's batch ended with the heartbeat failure's
    traceback on the console (load 16), though its 20 frames were stored."""
    client, cluster = _client(1, None, 60.0)
    try:
        client.run(_log_heartbeat_failure)  # control: a worker's record reaches stderr
        before = capfd.readouterr().err
        assert HEARTBEAT_FAILURE in before and "Traceback" in before, before

        close = client.close

        def logging_then_closing(*args, **kwargs):  # the race, as the cluster closes
            client.run(_log_heartbeat_failure)
            client.run(_log_other_error)
            return close(*args, **kwargs)

        client.close = logging_then_closing
        try:
            close_local_cluster(client, cluster)
        finally:
            del client.close  # the class's again (its __del__ closes too)
    finally:
        if cluster.status.name != "closed":
            cluster.close()
    err = capfd.readouterr().err
    assert OTHER_ERROR in err, err
    assert HEARTBEAT_FAILURE not in err and "Traceback" not in err, err


def test_a_cluster_without_a_client_still_closes():
    client, cluster = _client(1, None, 60.0)
    client.close()
    close_local_cluster(None, cluster)
    assert cluster.status.name == "closed"
