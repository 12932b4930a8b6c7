"""A second client of a bench process in a process of its own (a notebook beside the
window), driven from a test through queues: each call runs a function of this module
there with that process's :class:`~instrument.bench.bench_process.BenchClient` and returns
what it returned, or the text of what it raised. Nothing waits on the clock but the
hang guard."""

from __future__ import annotations

import multiprocessing
import queue

from instrument.bench.bench_process import BenchClient

#: Longest wait, s, for the other process to answer (a hang guard, not a pace).
HANG_S = 90.0


def _serve(address, authkey, name: str, calls, replies, connect: bool = False) -> None:
    try:
        client = (BenchClient.connect(name=name) if connect else
                  BenchClient(address=address, authkey=authkey, name=name))
    except Exception as exc:  # noqa: BLE001 (the test reads it)
        replies.put(("error", f"{type(exc).__name__}: {exc}"))
        return
    handles: dict = {}
    replies.put(("ok", client.name))
    try:
        while True:
            item = calls.get()
            if item is None:
                break
            fn, args = item
            try:
                replies.put(("ok", fn(client, handles, *args)))
            except Exception as exc:  # noqa: BLE001 (the test reads it)
                replies.put(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        client.close()


class OtherClient:
    """A :class:`BenchClient` connected to ``address`` from a spawned process.

    ``connect``: by the connection file (:meth:`BenchClient.connect`) instead.
    ``call(fn, *args)`` runs ``fn(client, handles, *args)`` there (``handles``: a dict
    kept between calls) and returns ``("ok", value)`` or ``("error", "Type: text")``.
    """

    def __init__(self, address, authkey, name: str = "the notebook", *,
                 connect: bool = False) -> None:
        ctx = multiprocessing.get_context("spawn")
        self.calls, self.replies = ctx.Queue(), ctx.Queue()
        self.process = ctx.Process(target=_serve, args=(address, authkey, name, self.calls,
                                                        self.replies, connect), daemon=True)
        self.process.start()
        kind, self.name = self._reply()
        assert kind == "ok", self.name

    def _reply(self):
        try:
            return self.replies.get(timeout=HANG_S)
        except queue.Empty:
            raise AssertionError(f"the other client did not answer within {HANG_S:.0f} s") \
                from None

    def call(self, fn, *args):
        self.calls.put((fn, args))
        return self._reply()

    def value(self, fn, *args):
        """``call``'s value; its error fails the test."""
        kind, value = self.call(fn, *args)
        assert kind == "ok", value
        return value

    def close(self) -> None:
        if self.process.is_alive():
            self.calls.put(None)
            self.process.join(HANG_S)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()


# -- what the other client does (run there by reference) ------------------------------
def start(client, handles, name: str, params: dict) -> int:
    """Start job ``name``; its id (the handle kept)."""
    job = client.start_job(name, params)
    handles[job.id] = job
    return job.id


def wait_recorded(client, handles, job_id: int, more_than: int) -> int:
    """Wait for a progress of job ``job_id`` with more than ``more_than`` frames
    recorded; that count."""
    event = handles[job_id].wait_for(
        lambda e: e.kind == "progress" and e.data["recorded"] > more_than, HANG_S)
    return event.data["recorded"]


def stop(client, handles, job_id: int) -> None:
    handles[job_id].stop()


def result(client, handles, job_id: int):
    """Job ``job_id``'s result (its error raised)."""
    return handles[job_id].result(HANG_S)


def jobs(client, handles) -> list[dict]:
    """Every job the bench process lists, as plain dicts."""
    return [{"id": i.id, "name": i.name, "state": i.state, "owner": i.owner,
             "holds": list(i.holds)} for i in client.jobs()]


def stop_by_id(client, handles, job_id: int) -> None:
    """Stop a job this client did not start, by its id."""
    client.job(job_id).stop()


def follow(client, handles, job_id: int) -> list[tuple]:
    """Every event of job ``job_id`` (started by another client), from the first kept
    to its end: ``(seq, kind, data)``."""
    return [(e.seq, e.kind, e.data) for e in client.job(job_id).events(HANG_S)]
