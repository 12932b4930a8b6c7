"""The kernel's figures the day's watchdog reads (Linux ``/proc``): each thread's time
on a core and waiting for one, its name, the system call it waits in, the machine's
accounted CPU time, and :func:`stall_time`, where a stall of the GUI thread's event loop
went (ours, the machine's load, or a machine that did not run).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["LATER_SAMPLES", "PEERS_ENV", "accounted_s", "descendant_pids", "kernel_state", "look",
           "peer_pids", "schedstat", "stall_time", "thread_name", "thread_times"]


#: Processes whose threads the GUI thread may wait on (the X server: a round trip to a
#: server kept from a core blocks the GUI thread), ``pid,pid``; set by the day's runner.
PEERS_ENV = "DIFFUSERLAB_DAY_PEER_PIDS"


def schedstat(tid: int, pid: str = "self") -> tuple[int, int] | None:
    """(ns on a core, ns runnable but waiting for one) of a thread so far (Linux's
    ``/proc/PID/task/TID/schedstat``); None where the kernel gives none."""
    try:
        with open(f"/proc/{pid}/task/{tid}/schedstat", "rb") as f:
            on_cpu, waiting = f.read().split()[:2]
        return int(on_cpu), int(waiting)
    except (OSError, ValueError):
        return None


def thread_times(skip: set[int], peers: tuple[str, ...] = ()
                 ) -> dict[tuple[str, int], tuple[int, int]]:
    """(ns on a core, ns waiting for one) so far of each thread of this process (but
    ``skip``) and of the ``peers`` processes, by (process, thread)."""
    out = {}
    for pid in ("self", *peers):
        try:
            tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        except OSError:
            continue
        for tid in tids:
            st = None if pid == "self" and tid in skip else schedstat(tid, pid)
            if st is not None:
                out[pid, tid] = st
    return out


def thread_name(pid: str, tid: int) -> str:
    """A thread's name: its Python name in this process, else the kernel's (``comm``),
    prefixed by the process's for a peer; the number where neither can be read."""
    if pid == "self":
        for t in threading.enumerate():
            if t.native_id == tid:
                return t.name
    try:
        with open(f"/proc/{pid}/task/{tid}/comm") as f:
            name = f.read().strip()
        if pid != "self":
            with open(f"/proc/{pid}/comm") as f:
                name = f"{f.read().strip()}/{name}"
        return name
    except OSError:
        return str(tid)


#: Most samples a long stall's record takes after the first, one a second.
LATER_SAMPLES = 30

#: x86-64 system call numbers a blocked GUI thread is seen in (``/proc/.../syscall``).
_SYSCALLS = {"0": "read", "1": "write", "7": "poll", "23": "select", "202": "futex",
             "232": "epoll_wait", "270": "pselect6", "271": "ppoll", "281": "epoll_pwait",
             "230": "clock_nanosleep", "35": "nanosleep"}


def kernel_state(tid: int, pid: str = "self") -> str | None:
    """Where a thread (of this process, or of process ``pid``) is in the kernel now:
    ``running``, or the system call it waits in (``futex``: a lock, the GIL or a mutex;
    ``poll``: a socket, the X server's) with its wait channel; None where Linux does
    not say."""
    try:
        with open(f"/proc/{pid}/task/{tid}/syscall") as f:
            call = f.read().split()
        with open(f"/proc/{pid}/task/{tid}/wchan") as f:
            wchan = f.read().strip()
    except OSError:
        return None
    if not call or call[0] == "running":
        return "running"
    name = _SYSCALLS.get(call[0], f"syscall {call[0]}")
    return f"{name} ({wchan})" if wchan and wchan != "0" else name


def peer_pids() -> tuple[str, ...]:
    """The pids of :data:`PEERS_ENV`."""
    return tuple(p for p in os.environ.get(PEERS_ENV, "").split(",") if p.strip().isdigit())


def descendant_pids(pid: int | None = None) -> tuple[str, ...]:
    """The pids of every process below ``pid`` (default this one): its children, theirs,
    and so on, from each process's parent in ``/proc/PID/stat``. The window's bench
    host, live and batch processes are such children, and the GUI thread waits on the
    bench host's replies: a host kept from a core makes that wait the machine's too."""
    root = os.getpid() if pid is None else int(pid)
    parent: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                stat = f.read()
            parent[int(entry)] = int(stat[stat.rindex(b")") + 2:].split()[1])
        except (OSError, ValueError, IndexError):
            continue  # ended meanwhile
    found, todo = [], [root]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        found += kids
        todo += kids
    return tuple(str(c) for c in sorted(found))


def accounted_s() -> float | None:
    """Seconds each CPU has been accounted for so far (every state of ``/proc/stat``'s
    ``cpu`` line, idle and steal included, over the CPUs); None where there is none.

    Between two readings it grows as the wall clock does, unless the machine did not
    run: a virtual machine paused by its host (the kernel then logs "workqueue lockup
    ... stuck for 42s") misses those seconds while its CPUs were busy.
    """
    try:
        with open("/proc/stat", "rb") as f:
            fields = f.readline().split()[1:9]
        return sum(int(v) for v in fields) / os.sysconf("SC_CLK_TCK") / (os.cpu_count() or 1)
    except (OSError, ValueError):
        return None


def look(gui_tid: int, skip: set[int], peers: tuple[str, ...] = (),
         at: float | None = None) -> tuple:
    """One look at the kernel's figures, for :func:`stall_time` between two looks.

    Returns
    -------
    tuple
        ``(when, gui, others, accounted, accounted_at, doubt_s)``: ``when`` the
        monotonic time by which every figure had been read (``at`` when given: a look
        taken on the GUI thread itself, which did nothing between ``at`` and it);
        ``gui`` the GUI thread's :func:`schedstat`; ``others`` :func:`thread_times`
        of every thread but ``skip`` (and of ``peers``); ``accounted`` :func:`accounted_s`
        and ``accounted_at`` the monotonic time of that reading, within ``doubt_s``
        (half the time the reading took: a reader kept from a core between the clock
        and ``/proc/stat`` must not read as a paused machine). A stall's first look is
        one whose ``when`` is at or before the stall began; its last one is taken after
        it ended.
    """
    gui = schedstat(gui_tid)
    others = thread_times(skip, peers)
    t_a = time.monotonic()
    accounted = accounted_s()
    t_b = time.monotonic()
    return (t_b if at is None else at, gui, others, accounted, 0.5 * (t_a + t_b),
            0.5 * (t_b - t_a))


def stall_time(ms: float, gui0, gui1, others0: dict, others1: dict,
               paused_ms: float = 0.0, names: Callable[[Any], str] | None = None) -> dict:
    """Where a stall's time went, from the kernel's figures at its start and end.

    ``gui_cpu_ms``: the GUI thread on a core (our code, Python or Qt's);
    ``gui_runqueue_ms``: runnable, waiting for a core (the machine); the rest it was blocked
    (a lock, the GIL, a call). ``others_runqueue_ms``: the longest any other thread of the
    process (or of a peer: the X server, the window's bench host) waited for a core
    meanwhile (a GIL holder, or a server the GUI thread waits on, descheduled makes the GUI
    thread's block the machine's too). ``busiest``: the other thread that was on a core
    longest meanwhile and for how long (``names(key)`` names it; the likeliest holder of
    what the GUI thread waited for). ``paused_ms``: the time the machine did not run at all
    (its CPUs unaccounted, :func:`accounted_s`), at most the stall. ``ours_ms``: the stall
    less the machine's share, what a freeze of ours would show whatever the load, never
    less than the GUI thread's own time on a core in it, and never more than the time the
    machine ran; a thread absent from the first look was born in the stall and counts
    from zero. Only ``ms`` (and ``paused_ms``) where the kernel
    gives no per-thread figures. ``gui0``/``gui1`` are the GUI thread's :func:`schedstat`,
    ``others0``/``others1`` :func:`thread_times` (ns on a core, ns waiting for one, by
    thread), at the stall's start and end.
    """
    out = {"ms": round(ms, 1)}
    paused = min(max(0.0, paused_ms), ms)
    if paused:
        out["paused_ms"] = round(paused, 1)
    if gui0 is None or gui1 is None:
        return out
    cpu, queue = (gui1[0] - gui0[0]) / 1e6, (gui1[1] - gui0[1]) / 1e6
    # a thread born in the stall (absent from the first look) spent all its time in it:
    # the launcher that forks a process holding the GIL, unseen, made its wait for a core
    # read as a block of ours (run J5: 944.9 of a 1705.6 ms stall)
    deltas = {t: (v[0] - others0.get(t, (0, 0))[0], v[1] - others0.get(t, (0, 0))[1])
              for t, v in others1.items()}
    others = max((d[1] for d in deltas.values()), default=0) / 1e6
    blocked = max(0.0, ms - cpu - queue)
    # the figures span from the look before the stall to the look after it, a little
    # more than the stall: the GUI thread's wait for a core in that margin must not
    # take the stall's own CPU time off what is ours (measured: 1652.7 ms, 402.6 on a
    # core and 1263.7 queued read as 389.0 ours)
    mine = max(min(cpu, ms), ms - queue - min(blocked, others))
    out.update(gui_cpu_ms=round(cpu, 1), gui_runqueue_ms=round(queue, 1),
               others_runqueue_ms=round(others, 1),
               ours_ms=round(max(0.0, min(mine, ms - paused)), 1))
    if deltas:
        key = max(deltas, key=lambda t: deltas[t][0])
        if deltas[key][0] > 0:
            who = names(key) if names is not None else str(key)
            out["busiest"] = f"{who} {deltas[key][0] / 1e6:.1f} ms on a core"
    return out
