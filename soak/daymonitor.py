"""What the operator-day run measures in the GUI's own process.

:class:`DayMonitor` runs beside the window on the GUI thread:

* a 10 ms precise timer whose lateness (interval minus 10 ms) tells how long the
  event loop was kept from its timers, split by the phase of the day it fell in;
* the garbage collector's pauses (any thread's collection stops every thread);
* a watchdog thread that, when the timer is more than 100 ms overdue, records what
  the GUI thread was running then (its innermost Python frames, or "waiting in the
  event loop" when none of ours: the process waited for a core or for the GIL held
  by a worker), and once the timer fires again where the GUI thread's time went from
  the kernel's per-thread figures (on a core, waiting for one, blocked;
  :func:`soak.kernelstats.stall_time`), so a slow firing can be told
  from the machine's load (and from a machine that did not run at all: a virtual
  machine its host paused, time the kernel's CPU counters never saw);
* every few seconds, ``sys.getrefcount(None)`` and ``sys.getrefcount(True)`` (a
  leaking Qt binding drains them: -860 a second while streaming under PySide6
  6.12.0) and the process's resident memory.

:meth:`DayMonitor.report` gives per phase the firings, p50 / p99 / max lateness and
seconds, and the samples.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import traceback
from array import array
from collections import deque
from types import FrameType

import numpy as np
from PySide6.QtCore import QElapsedTimer, QObject, Qt, QTimer

from gui.memory import rss_mb

from .hiddenstall import HiddenStallLook
from .kernelstats import (
    LATER_SAMPLES,
    descendant_pids,
    kernel_state,
    look,
    peer_pids,
    stall_time,
    thread_name,
)

__all__ = ["DayMonitor", "HeapTracker", "array_holders", "census", "frozen_garbage"]

TIMER_MS = 10
#: How often the watchdog looks for this process's children (its stall figures count
#: their threads' waits for a core as the machine's, as the X server's), s.
PEERS_EVERY_S = 1.0
#: Innermost functions of a thread that waits (left out of a stall's busy threads).
_WAITING = frozenset({"wait", "get", "sleep", "select", "_wait_for_tstate_lock", "acquire",
                      "accept", "recv", "readline", "poll", "join", "_worker",
                      "_launch_jobs"})


def _short_path(path: str) -> str:
    """``package/module.py`` of a source path (its last two parts)."""
    parts = path.replace("\\", "/").split("/")
    return "/".join(parts[-2:])


def census(top: int = 25) -> dict:
    """Live objects per type (the most numerous), for finding what grows in a long day
    (the operator's day takes one at each pass's stream phase when
    ``DIFFUSERLAB_DAY_CENSUS=1``; a full garbage collection and a walk of the whole
    heap, the objects frozen by :func:`gui.workers.settle_heap` included: 1.6 s on
    the GUI thread for 268 000 objects in a real-window day on a 2-core machine, so a
    day with the census does not measure lateness).

    Parameters
    ----------
    top : int
        How many of the most numerous types to list.

    Returns
    -------
    dict
        ``t_s`` (monotonic clock, s), ``objects`` (tracked by the collector),
        ``frozen`` (of them frozen before the census), ``blocks``
        (``sys.getallocatedblocks``), ``top`` (``{type name: count}``) and
        ``biggest``: the 12 largest lists, dicts, deques and sets with their length,
        the types that refer to them and a sample item; ``arrays``: the NumPy arrays
        alive, by holder (:func:`array_holders`).
    """
    import gc
    from collections import Counter, deque

    gc.collect()
    frozen = gc.get_freeze_count()
    if frozen:  # the frozen objects too (most of a settled heap): unfrozen to be listed,
        gc.unfreeze()  # frozen again with the survivors of the collection above
    objects = gc.get_objects()
    if frozen:
        gc.freeze()
    counts = Counter(type(o).__name__ for o in objects)
    sized = sorted(((len(o), id(o), o) for o in objects
                    if type(o) in (list, dict, deque, set)), key=lambda s: s[:2])[-12:]
    big = []
    for n, _, o in reversed(sized):
        owners = [type(r).__name__ for r in gc.get_referrers(o)[:4] if r is not objects]
        sample = repr(next(iter(o.items() if isinstance(o, dict) else o), None))[:80]
        big.append({"type": type(o).__name__, "len": n, "owners": owners, "sample": sample})
    arrays = array_holders(objects, top=30)
    del objects, sized
    return {"t_s": time.monotonic(), "objects": sum(counts.values()),
            "frozen": frozen,
            "blocks": sys.getallocatedblocks(), "top": dict(counts.most_common(top)),
            "biggest": big, "arrays": arrays}


def _root(a: np.ndarray):
    """The object that owns an array's memory: its last ndarray base, or that array's
    own non-array base (a ``bytes``, ``mmap``, ...)."""
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def array_holders(objects: list | None = None, top: int = 15, *,
                  threads: bool = True) -> dict:
    """The NumPy array memory alive now, by what holds it: for finding which arrays make
    a long day's resident memory (the operator's day takes one with :func:`census`).

    Each array buffer counts once (views count as the array they view), for the first
    holder found: an attribute of an object (``Type.attribute``, also for arrays in a
    list, dict, tuple or deque it holds, two levels down), a local variable of a frame
    object kept after its function (by a traceback, a generator, or a reference like
    the one the day's watchdog once kept: ``frame of function (package/module.py)``), an
    item of another container (the container's type), or a local variable of a thread's
    running function (``thread: function``).

    Parameters
    ----------
    objects : list or None
        The collector's objects (``gc.get_objects()``, taken when None).
    top : int
        How many holders to list.
    threads : bool
        Also look in the running threads' local variables. Reading a running frame's
        locals leaves a snapshot of them in the frame (CPython 3.11 and 3.12) that keeps
        those values alive until the frame ends or is read again, so a day with the
        census holds a little more than one without.

    Returns
    -------
    dict
        ``mb`` (all array buffers found, MiB), ``buffers`` (their number) and
        ``holders``: ``[{"where", "mb", "buffers"}]``, the largest first.
    """
    import gc
    from collections import deque

    stacks = sys._current_frames() if threads else {}
    running: dict[int, FrameType] = {}  # the frames of the running threads' stacks
    for frame in stacks.values():
        while frame is not None:
            running[id(frame)] = frame
            frame = frame.f_back
    # a running frame (and the snapshot of its locals) can be among the collector's
    # objects when something read the stacks before (the watchdog does when the GUI
    # thread is late): it is named by its thread below, never as a frame kept after
    # its function, whatever the load
    skip = set(running) | {id(f.f_locals) for f in running.values()}
    if objects is None:
        objects = gc.get_objects()
    seen: dict[int, tuple[str, int]] = {}

    def add(value, where: str, depth: int = 0, attribute: bool = False) -> None:
        if isinstance(value, np.ndarray):
            root = _root(value)
            if id(root) not in seen:
                seen[id(root)] = (where, int(root.nbytes))
        elif (depth < 2 and isinstance(value, dict | list | tuple | deque)
              and (attribute or not gc.is_tracked(value))):
            # an attribute's container, or one holding only untracked things (never
            # among the collector's objects): its arrays count for this holder
            for v in _items(value, values=True):
                add(v, where, depth + 1, attribute)

    containers = (dict, list, tuple, set, frozenset)
    for o in objects:  # objects' attributes first: they name the holder best
        if isinstance(o, (*containers, type)) or id(o) in skip:
            continue
        name = type(o).__name__
        if isinstance(o, FrameType):  # a traceback's or a generator's frame
            name = f"frame of {o.f_code.co_qualname} ({_short_path(o.f_code.co_filename)})"
        try:  # past a __getattr__ (pydantic's placeholders raise from theirs)
            attrs = object.__getattribute__(o, "__dict__")
        except Exception:  # noqa: BLE001 (no instance dictionary, whatever the reason)
            attrs = None
        if isinstance(attrs, dict):
            for k, v in _items(attrs):
                add(v, f"{name}.{k}", attribute=True)
        for r in gc.get_referents(o):
            add(r, name)
    for o in objects:
        if isinstance(o, containers) and id(o) not in skip:
            for r in _items(o, values=True):
                add(r, type(o).__name__)
    names = {t.ident: t.name for t in threading.enumerate()}
    for ident, frame in stacks.items():
        while frame is not None:
            for v in frame.f_locals.values():
                add(v, f"{names.get(ident, ident)}: {frame.f_code.co_name}")
            frame = frame.f_back
    by: dict[str, list[int]] = {}
    for where, nbytes in seen.values():
        entry = by.setdefault(where, [0, 0])
        entry[0] += nbytes
        entry[1] += 1
    holders = sorted(by.items(), key=lambda kv: -kv[1][0])[:top]
    return {"mb": round(sum(n for _, n in seen.values()) / 2**20, 1), "buffers": len(seen),
            "holders": [{"where": w, "mb": round(n / 2**20, 2), "buffers": c}
                        for w, (n, c) in holders]}


def _items(container, values: bool = False) -> list:
    """A list of a container's items (a dict's ``(key, value)`` pairs, or its values when
    ``values``), taken while other threads may change it: a change during the copy
    (``RuntimeError``) retries, and a container changing every time gives ``[]``."""
    for _ in range(5):
        try:
            if isinstance(container, dict):
                return list(container.values() if values else container.items())
            return list(container)
        except RuntimeError:  # changed size during the copy: another thread's doing
            continue
    return []


def _thread_stacks() -> dict[int, traceback.StackSummary]:
    """Every thread's stack, innermost last, as file, line and function names, keeping
    no frame. A frame object outlives its function with the function's locals: the
    watchdog kept :func:`sys._current_frames` until the next stall, and so a stopped
    ADMM view's solver state, then left it (a frame holding itself through that dict)
    as garbage frozen by :func:`gui.workers.settle_heap` (38 MiB at a 24-minute day's
    end)."""
    frames = sys._current_frames()
    try:
        return {ident: traceback.extract_stack(f) for ident, f in frames.items()}
    finally:
        frames.clear()


def _collect_counted(top: int) -> tuple[int, dict, dict, float]:
    """A full collection that keeps what it finds aside (:data:`gc.DEBUG_SAVEALL`) to
    count it, then frees it: (objects found, ``{type name: count}`` of the most
    numerous, the NumPy arrays they held by holder (:func:`array_holders`), the
    collection's duration in s)."""
    import gc
    from collections import Counter

    flags = gc.get_debug()
    gc.set_debug(flags | gc.DEBUG_SAVEALL)
    try:
        t = time.perf_counter()
        found = gc.collect()
        took_s = time.perf_counter() - t
    finally:
        gc.set_debug(flags)
    saved, gc.garbage[:] = list(gc.garbage), []
    types = Counter(type(o).__name__ for o in saved)
    arrays = array_holders(saved, top=top, threads=False)
    del saved
    gc.collect()
    return found, dict(types.most_common(top)), arrays, took_s


def frozen_garbage(top: int = 12) -> dict:
    """What the garbage collector finds at the end of a long day: the ordinary
    garbage, then what the freezes of :func:`gui.workers.settle_heap` kept.

    A frozen object is never collected: cyclic garbage made of objects that were alive
    at a freeze stays in memory. This collects the ordinary garbage and gives the
    heaps' free pages back, then unfreezes, collects again and trims again. Each
    collection keeps what it finds aside to count it (its types and the NumPy arrays it
    held) before freeing it. The collector then runs as usual (nothing is frozen any
    more).

    Parameters
    ----------
    top : int
        How many of the most numerous types to list per collection.

    Returns
    -------
    dict
        ``frozen`` (objects frozen before); ``garbage``, ``garbage_types`` and
        ``garbage_arrays_mb`` (the ordinary collection: objects found, ``{type name:
        count}`` of the most numerous, NumPy array buffers they held, MiB);
        ``frozen_garbage``, ``types`` and ``arrays_mb`` (the same for the collection
        after unfreezing); ``garbage_array_holders`` and ``array_holders``: what held
        those arrays (:func:`array_holders`); ``rss_mb`` (before), ``rss_mb_collected``
        (after the ordinary collection and a trim), ``rss_mb_after`` (after the frozen
        garbage is freed and a trim), ``collect_s`` (the second collection's duration, s).
    """
    import gc

    from gui.memory import trim_now

    before = rss_mb()
    frozen = gc.get_freeze_count()
    garbage, garbage_types, garbage_arrays, _ = _collect_counted(top)
    trim_now()
    collected = rss_mb()
    gc.unfreeze()
    found, types, arrays, collect_s = _collect_counted(top)
    trim_now()
    return {"frozen": frozen, "garbage": garbage, "garbage_types": garbage_types,
            "garbage_arrays_mb": garbage_arrays["mb"],
            "garbage_array_holders": garbage_arrays["holders"],
            "frozen_garbage": found, "types": types, "arrays_mb": arrays["mb"],
            "array_holders": arrays["holders"], "rss_mb": before,
            "rss_mb_collected": collected, "rss_mb_after": rss_mb(), "collect_s": collect_s}


class DayMonitor(QObject):
    """Lateness per phase and reference-count / memory samples (module docstring).

    Parameters
    ----------
    sample_s : float
        Seconds between refcount and memory samples.
    """

    def __init__(self, sample_s: float = 5.0, parent=None) -> None:
        super().__init__(parent)
        self.clock = QElapsedTimer()
        self.phase = "start"
        #: Which pass through the day's middle is running (0: the first, the warm-up).
        self.loop = 0
        self._last_ns: int | None = None
        #: Lateness per phase, s: packed doubles (8 bytes a firing; a list of floats
        #: took 32, ~11 MB in an hour: the monitor's own growth counted in the RSS).
        self.lateness: dict[str, array] = {}
        self.phase_seconds: dict[str, float] = {}
        self._phase_t0 = time.monotonic()
        self.samples: list[dict] = []
        self.timer = QTimer(self)
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.setInterval(TIMER_MS)
        self.timer.timeout.connect(self._fired)
        self.sampler = QTimer(self)
        self.sampler.setInterval(int(sample_s * 1000))
        self.sampler.timeout.connect(self.sample)
        self.t0 = time.monotonic()
        self.gc_ms: dict[int, array] = {}
        #: Firings later than 100 ms and collections longer than 50 ms, in time order.
        self.events: list[dict] = []
        self._gc_t0: float | None = None
        #: What the GUI thread ran during stalls (:meth:`_watch`), in time order.
        self.stalls: list[dict] = []
        #: The processes whose threads the stall figures look at besides this one's:
        #: the X server and this process's children (refreshed each PEERS_EVERY_S).
        self.peers: tuple[str, ...] = ()
        self._gui_thread = threading.get_ident()
        self._gui_tid = threading.get_native_id()
        self._last_fired = time.monotonic()
        self._gaps: deque[tuple[float, float]] = deque()  # (fired before, fired after)
        self._watching = threading.Event()

    def _gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._gc_t0 = time.perf_counter()
        elif self._gc_t0 is not None:
            ms = 1e3 * (time.perf_counter() - self._gc_t0)
            g = info.get("generation", 0)
            self.gc_ms.setdefault(g, array("d")).append(ms)
            self._gc_t0 = None
            if ms > 50:
                self.events.append({"t_s": round(time.monotonic() - self.t0, 2),
                                    "what": f"gc gen{g}", "ms": round(ms, 1),
                                    "phase": self.phase})

    def start(self) -> None:
        import gc

        gc.callbacks.append(self._gc)
        self.clock.start()
        self._last_ns = None
        self._gui_thread = threading.get_ident()
        self._gui_tid = threading.get_native_id()
        # the figures at the start: a stall that begins before the watchdog's first look
        # (the GUI thread importing, holding the GIL, as the window opens) is measured
        # from here, not as 0 ms on a core and 0 ms waiting for one (all "ours")
        self._last_fired = time.monotonic()
        self._start_tick = look(self._gui_tid, {self._gui_tid}, peer_pids(),
                                at=self._last_fired)
        self.timer.start()
        self.sampler.start()
        self.sample()
        self._hidden = HiddenStallLook()  # faulthandler's look when the watchdog cannot run
        #: Where faulthandler writes every thread's stack when the watchdog cannot run.
        self.dump_path = self._hidden.path
        self._watching.set()
        threading.Thread(target=self._watch, name="day-watchdog", daemon=True).start()

    def _watch(self) -> None:
        """Every 20 ms: when the timer is over 100 ms overdue, record the GUI thread's
        innermost frames once per stall (the threads' names that were running Python
        too), in :attr:`stalls`; once it has fired again, the stall's length and where
        the GUI thread's time went (:func:`stall_time`), also for a stall the watchdog
        could not see live (it waits for the GIL too: a GUI thread descheduled holding
        it holds the watchdog); such a stall's stacks are faulthandler's, taken without
        the GIL (:mod:`soak.hiddenstall`)."""
        gui_tid, own_tid, servers = self._gui_tid, threading.get_native_id(), peer_pids()
        # ticks between stalls: (time, GUI schedstat, others' (on a core, waiting),
        # accounted CPU seconds), the first taken by start() on the GUI thread
        quiet: deque = deque([self._start_tick], maxlen=16)
        hidden = self._hidden
        try:
            self._watch_until_stopped(hidden, gui_tid, own_tid, servers, quiet)
        finally:
            hidden.close()

    def _watch_until_stopped(self, hidden: HiddenStallLook, gui_tid: int, own_tid: int,
                             servers: tuple[str, ...], quiet: deque) -> None:
        peers, peers_at = servers, -1.0  # the X server, and this process's children
        seen: dict[float, dict] = {}  # the records opened live, by the firing before them
        sampled_for = None
        while self._watching.is_set():
            time.sleep(0.02)
            hidden.tick()
            gaps = []
            while self._gaps:
                gaps.append(self._gaps.popleft())
            if time.monotonic() - peers_at >= PEERS_EVERY_S:  # the bench host, live, batch
                peers, peers_at = servers + descendant_pids(), time.monotonic()
                self.peers = peers
            tick = look(gui_tid, {gui_tid, own_tid}, peers)
            now, last = tick[0], self._last_fired
            for t0, t1 in gaps:
                record = seen.pop(t0, None)
                if record is None and len(self.stalls) < 2000:
                    record = {"t_s": round(t0 - self.t0, 2), "phase": self.phase,
                              "gui_stack": [], "threads": [], "seen_live": False}
                    self._hidden_look(record, hidden.claim(t0, t1))
                    self.stalls.append(record)
                if record is not None:
                    base = [q for q in quiet if q[0] <= t0] or list(quiet)[:1] or [tick]
                    before = base[-1]
                    paused = 0.0  # wall time between the ticks the CPUs were not accounted
                    if before[3] is not None and tick[3] is not None:  # less the readings'
                        paused = 1e3 * ((tick[4] - before[4]) - (tick[3] - before[3])  # doubt
                                        - (tick[5] + before[5]))
                    record.update(stall_time(1e3 * (t1 - t0), before[1], tick[1],
                                             before[2], tick[2], paused_ms=paused,
                                             names=lambda key: thread_name(*key)))
            if now - last < 0.1 + TIMER_MS / 1000.0:
                quiet.append(tick)
                continue
            if sampled_for == last:  # the same stall: where things are, once a second
                self._resample(seen.get(last), now - last, gui_tid, servers)
                continue
            sampled_for = last
            stacks = {ident: [(f.filename, f.lineno, f.name) for f in stack]
                      for ident, stack in _thread_stacks().items()}
            if len(self.stalls) < 2000:
                record = {"t_s": round(time.monotonic() - self.t0, 2), "phase": self.phase,
                          **self._where(stacks), "gui_kernel": kernel_state(gui_tid),
                          "later": []}
                # this thread waited for the GIL through the stall: what it sees now is
                # after the block, faulthandler's look is from within it
                self._hidden_look(record, hidden.claim(last, now))
                self.stalls.append(record)
                seen[last] = record

    def _where(self, stacks: dict[int, list[tuple[str, int, str]]]) -> dict:
        """A stall record's ``gui_stack`` (the GUI thread's innermost frames) and
        ``threads`` (the other threads whose innermost frame is not a wait), from every
        thread's ``(file, line, function)`` frames, innermost last."""
        names = {t.ident: t.name for t in threading.enumerate()}
        busy = [f"{names.get(ident, ident)}@{_short_path(st[-1][0])}:{st[-1][1]}:{st[-1][2]}"
                for ident, st in stacks.items()
                if ident not in (self._gui_thread, threading.get_ident()) and st
                and st[-1][2] not in _WAITING]
        return {"gui_stack": [f"{_short_path(f)}:{n}:{fn}"
                              for f, n, fn in stacks.get(self._gui_thread, [])[-6:]],
                "threads": busy}

    def _hidden_look(self, record: dict, stacks: dict | None) -> None:
        """Fill a stall's record that the watchdog could not take live from
        faulthandler's look (:mod:`soak.hiddenstall`), ``seen_by: "faulthandler"``."""
        if not stacks:
            return
        record.update(self._where(stacks), seen_by="faulthandler")
        record.pop("gui_kernel", None)  # a live look's was taken after the block

    def _resample(self, record: dict | None, into_s: float, gui_tid: int,
                  peers: tuple[str, ...]) -> None:
        """Add to a long stall's record, once a second (at most
        :data:`~soak.kernelstats.LATER_SAMPLES`),
        where the GUI thread is then (its system call and innermost frame) and where
        each peer process's main thread is (the X server's)."""
        later = None if record is None else record.get("later")
        if later is None or len(later) >= LATER_SAMPLES or \
                into_s < (len(later) + 1) * 1.0:
            return
        frames = _thread_stacks().get(self._gui_thread, [])
        later.append({"after_s": round(into_s, 1), "gui": kernel_state(gui_tid),
                      "gui_frame": (f"{_short_path(frames[-1].filename)}:{frames[-1].lineno}:"
                                    f"{frames[-1].name}") if frames else None,
                      "peers": {thread_name(p, int(p)): kernel_state(int(p), p)
                                for p in peers}})

    def stop(self) -> None:
        import gc

        self._watching.clear()
        if self._gc in gc.callbacks:
            gc.callbacks.remove(self._gc)
        self.timer.stop()
        self.sampler.stop()
        self.set_phase("end")

    def set_phase(self, name: str) -> None:
        """The lateness measured from now on counts for phase ``name``."""
        now = time.monotonic()
        self.phase_seconds[self.phase] = self.phase_seconds.get(self.phase, 0.0) + (
            now - self._phase_t0)
        self.phase, self._phase_t0 = name, now
        self.sample()

    def _fired(self) -> None:
        fired, before = time.monotonic(), self._last_fired
        self._last_fired = fired
        if fired - before >= 0.1 + TIMER_MS / 1000.0:
            self._gaps.append((before, fired))  # a stall: the watchdog measures it
        now = self.clock.nsecsElapsed()
        if self._last_ns is not None:
            late = max((now - self._last_ns) / 1e9 - TIMER_MS / 1000.0, 0.0)
            self.lateness.setdefault(self.phase, array("d")).append(late)
            if late > 0.1:  # when the event loop was held: compared with the GC's pauses
                self.events.append({"t_s": round(time.monotonic() - self.t0, 2),
                                    "what": "late", "ms": round(1e3 * late, 1),
                                    "phase": self.phase})
        self._last_ns = now

    def sample(self) -> dict:
        """Take one refcount and memory sample (also at every phase change)."""
        from gui.memory import heap_mb

        s = {"t_s": time.monotonic() - self.t0, "phase": self.phase, "loop": self.loop,
             "none_refs": sys.getrefcount(None), "true_refs": sys.getrefcount(True),
             "rss_mb": rss_mb(), "py_blocks": sys.getallocatedblocks()}
        s.update({f"heap_{k}": v for k, v in (heap_mb() or {}).items()})
        self.samples.append(s)
        return s

    def report(self) -> dict:
        """``{"phases": {name: {firings, p50_ms, p99_ms, max_ms, seconds}}, "samples":
        [...], "worst_p99_ms", "worst_max_ms"}``."""
        phases = {}
        for name, values in self.lateness.items():
            ms = 1e3 * np.asarray(values)
            phases[name] = {"firings": int(ms.size),
                            "p50_ms": float(np.percentile(ms, 50)),
                            "p99_ms": float(np.percentile(ms, 99)),
                            "max_ms": float(ms.max()),
                            "seconds": round(self.phase_seconds.get(name, 0.0), 1)}
        gc_stats = {f"gen{g}": {"count": len(v), "max_ms": float(max(v)),
                                "total_ms": float(sum(v))} for g, v in self.gc_ms.items()}
        return {"timer_ms": TIMER_MS, "phases": phases, "samples": self.samples, "gc": gc_stats,
                "slow_events": self.events[-400:], "stalls": self.stalls[-400:],
                "worst_p99_ms": max((p["p99_ms"] for p in phases.values()), default=0.0),
                "worst_max_ms": max((p["max_ms"] for p in phases.values()), default=0.0)}


class HeapTracker:
    """Where the Python heap grows from one pass of the day to the next (tracemalloc).

    Off unless the environment sets ``DIFFUSERLAB_TRACEMALLOC`` (the frames of traceback
    kept per allocation, e.g. 8): tracing slows every allocation, so the lateness and
    lost frames of a traced day do not count (a 12-minute traced day lost 166 frames and
    was up to 1.7 s late; untraced days lose none). :meth:`mark` at each
    pass's start takes a snapshot (the first starts the tracing: the warm-up pass is
    left out); :meth:`report` compares the first snapshot with the last, by traceback.
    NumPy's array buffers are traced; Qt's own (C++) allocations are not.
    """

    def __init__(self) -> None:
        self.frames = int(os.environ.get("DIFFUSERLAB_TRACEMALLOC", "0") or 0)
        self.first = self.last = None

    def mark(self) -> None:
        """A pass starts: snapshot (the first call starts tracing)."""
        import tracemalloc

        if self.frames <= 0:
            return
        if not tracemalloc.is_tracing():
            tracemalloc.start(self.frames)
            return
        snap = tracemalloc.take_snapshot().filter_traces(
            [tracemalloc.Filter(False, tracemalloc.__file__)])
        if self.first is None:
            self.first = snap
        self.last = snap

    def report(self, top: int = 15) -> list[dict]:
        """The ``top`` tracebacks whose memory grew most between the first and the last
        snapshot: ``{"mb", "count", "where"}`` (innermost frames last); empty when off."""
        if self.first is None or self.last is self.first:
            return []
        stats = self.last.compare_to(self.first, "traceback")
        return [{"mb": round(st.size_diff / 2 ** 20, 2), "count": st.count_diff,
                 "where": [f"{f.filename.rsplit('site-packages/', 1)[-1]}:{f.lineno}"
                           for f in st.traceback][-6:]}
                for st in sorted(stats, key=lambda st: -st.size_diff)[:top]]

