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


def _use_zarr_then_block_its_loop(block_s: float) -> None:
    """In a worker: zarr's I/O loop started (an array written), then kept busy for
    ``block_s`` -- what a worker starved of a core looks like to zarr's exit hook,
    which waits 0.2 s for the loop to stop."""
    import time

    import numpy as np
    import zarr
    from zarr.core import sync

    zarr.create_array(zarr.storage.MemoryStore(), shape=(4,), dtype="f4")[:] = np.ones(4)
    sync.loop[0].call_soon_threadsafe(time.sleep, block_s)


def test_a_worker_whose_zarr_loop_is_slow_to_stop_exits_without_a_traceback(capfd):
    """Before: the operator day's batch step beside busy loops printed "Thread did not
    finish cleanly" and "RuntimeError: Cannot close a running event loop" from zarr's
    exit hook in a worker process, though its frames were stored."""
    client, cluster = _client(1, None, 60.0)
    try:
        client.run(_use_zarr_then_block_its_loop, 1.5)
        close_local_cluster(client, cluster)
    finally:
        if cluster.status.name != "closed":
            cluster.close()
    err = capfd.readouterr().err
    assert "Thread did not finish cleanly" not in err, err
    assert "Cannot close a running event loop" not in err and "Traceback" not in err, err


def test_stopping_zarr_s_loop_leaves_zarr_usable():
    import numpy as np
    import zarr

    from instrument.processing.cluster_close import stop_zarr_io

    zarr.create_array(zarr.storage.MemoryStore(), shape=(2,), dtype="f4")[:] = 1
    assert stop_zarr_io(30.0)
    assert stop_zarr_io(30.0)  # nothing left: still True
    arr = zarr.create_array(zarr.storage.MemoryStore(), shape=(2,), dtype="f4")
    arr[:] = np.arange(2)
    assert arr[:].tolist() == [0.0, 1.0]


def test_a_cluster_that_runs_out_of_time_closing_is_a_warning_not_a_failed_batch(caplog):
    """Before: distributed's 5 s for a worker process to exit ran out at load 25 and its
    TimeoutError failed a batch whose frames were all stored ("unexpected error")."""

    class SlowToClose:  # distributed's LocalCluster.close, as it ended that day
        workers: dict = {}
        closed_with = None

        def close(self, timeout=None):
            self.closed_with = timeout
            raise TimeoutError

    cluster = SlowToClose()
    with caplog.at_level(logging.WARNING, "instrument.processing.cluster_close"):
        close_local_cluster(None, cluster)
    assert cluster.closed_with is not None and cluster.closed_with > 10
    assert "did not close within" in caplog.text
