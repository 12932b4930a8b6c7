"""Runs left open by a bench process that was killed, closed by the client that started it.

A bench process killed outright (SIGKILL, the OOM killer) cannot close the run its job
was writing: the run stays ``recording`` (or ``running``) with the process's writer
lock, and every later writer is refused. The client that started the bench process
(:class:`instrument.bench.bench_process.BenchClient`: the window, ``bench serve``) knows which
runs its bench process writes (each job's ``out`` or ``path``, from the bench's
``job`` events) and, once that process is gone, knows their writer is gone too: it
closes each of them (:func:`close_orphaned_run`): status ``interrupted``, the error
saying why, ``closed_by`` recording who closed it, when and why, the lock removed,
every frame stored kept. It touches a run only while the lock is still that dead
process's, on this host.
"""

from __future__ import annotations

import socket
import threading
from pathlib import Path

__all__ = ["OPEN_STATUSES", "close_orphaned_run", "run_path_of"]

#: Statuses of a run whose writer is at work.
OPEN_STATUSES = ("recording", "running", "created")

#: One closer at a time in this process: the window closes a run from the job that was
#: following it and from its close of the ended bench's client, on two threads; the
#: first closes it (check, write, lock removed), the second then finds it closed.
_closing = threading.Lock()


def run_path_of(params: dict) -> str | None:
    """The run a job writes, from its parameters (``out`` of a recording or the mask
    alignment, ``path`` of a calibration run); None: none."""
    for key in ("out", "path"):
        value = params.get(key)
        if isinstance(value, str | Path) and str(value):
            return str(value)
    return None


def close_orphaned_run(path: str | Path, *, writer_pid: int, closed_by: str,
                       why: str) -> bool:
    """Close run ``path`` whose writer, process ``writer_pid``, is gone.

    Parameters
    ----------
    path : str or path
        The run store.
    writer_pid : int
        The bench process that wrote it (now ended).
    closed_by : str
        Who closes it (``the window (pid 812)``).
    why : str
        Why (``the bench process (pid 813) that wrote it was killed (SIGKILL)``).

    Returns
    -------
    bool
        True when closed; False when there was nothing to close: no run there, the
        run not open, or its lock not that process's (another writer, released,
        another host) or that process still alive.
    """
    path = Path(path)
    with _closing:
        return _close(path, writer_pid, closed_by, why)


def _close(path: Path, writer_pid: int, closed_by: str, why: str) -> bool:
    """:func:`close_orphaned_run`, under :data:`_closing`."""
    from ..runs.run_integrity import LOCK_NAME, pid_alive, read_lock
    from ..runs.runstore import RunStore, RunStoreError, utc_now

    lock = read_lock(path) if path.is_dir() else None
    if (not lock or lock.get("pid") != int(writer_pid)
            or lock.get("host") != socket.gethostname() or pid_alive(int(writer_pid))):
        return False
    try:
        store = RunStore.open(path, "r+")
    except RunStoreError:
        return False
    if store.status not in OPEN_STATUSES:
        return False
    frames = int(store.done().sum())
    # one write of zarr.json (RunStore.update_attrs): status never without closed_by
    store.update_attrs(status="interrupted", error=f"interrupted: {why}", ended_utc=utc_now(),
                       closed_by={"by": closed_by, "why": why, "utc": utc_now(),
                                  "frames_kept": frames})
    (path / LOCK_NAME).unlink(missing_ok=True)
    return True
