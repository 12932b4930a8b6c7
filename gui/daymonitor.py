"""What the operator-day run measures in the GUI's own process.

:class:`DayMonitor` runs beside the window on the GUI thread:

* a 10 ms precise timer whose lateness (interval minus 10 ms) tells how long the
  event loop was kept from its timers, split by the phase of the day it fell in;
* the garbage collector's pauses (any thread's collection stops every thread);
* every few seconds, ``sys.getrefcount(None)`` and ``sys.getrefcount(True)`` (a
  leaking Qt binding drains them: -860 a second while streaming under PySide6
  6.12.0) and the process's resident memory.

:meth:`DayMonitor.report` gives per phase the firings, p50 / p99 / max lateness and
seconds, and the samples.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
from PySide6.QtCore import QElapsedTimer, QObject, Qt, QTimer

__all__ = ["DayMonitor", "rss_mb"]

TIMER_MS = 10


def rss_mb() -> float:
    """Resident memory of this process, MB (Linux ``/proc/self/statm``)."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


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
        self._last_ns: int | None = None
        self.lateness: dict[str, list[float]] = {}
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
        self.gc_ms: dict[int, list[float]] = {}
        #: Firings later than 100 ms and collections longer than 50 ms, in time order.
        self.events: list[dict] = []
        self._gc_t0: float | None = None

    def _gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._gc_t0 = time.perf_counter()
        elif self._gc_t0 is not None:
            ms = 1e3 * (time.perf_counter() - self._gc_t0)
            g = info.get("generation", 0)
            self.gc_ms.setdefault(g, []).append(ms)
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
        self.timer.start()
        self.sampler.start()
        self.sample()

    def stop(self) -> None:
        import gc

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
        now = self.clock.nsecsElapsed()
        if self._last_ns is not None:
            late = max((now - self._last_ns) / 1e9 - TIMER_MS / 1000.0, 0.0)
            self.lateness.setdefault(self.phase, []).append(late)
            if late > 0.1:  # when the event loop was held: compared with the GC's pauses
                self.events.append({"t_s": round(time.monotonic() - self.t0, 2),
                                    "what": "late", "ms": round(1e3 * late, 1),
                                    "phase": self.phase})
        self._last_ns = now

    def sample(self) -> dict:
        """Take one refcount and memory sample (also at every phase change)."""
        s = {"t_s": time.monotonic() - self.t0, "phase": self.phase,
             "none_refs": sys.getrefcount(None), "true_refs": sys.getrefcount(True),
             "rss_mb": rss_mb()}
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
                "slow_events": self.events[-400:],
                "worst_p99_ms": max((p["p99_ms"] for p in phases.values()), default=0.0),
                "worst_max_ms": max((p["max_ms"] for p in phases.values()), default=0.0)}
