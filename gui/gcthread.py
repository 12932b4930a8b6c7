"""Python's cyclic garbage collector, run on the GUI thread only.

CPython collects in whichever thread's allocation crosses the collector's threshold. In
the window that is often a worker: a :class:`gui.workers.Job` thread, the bench
client's frame reader, zarr's event loop. A Qt object caught in a reference cycle is then
destroyed from that thread, while the GUI thread may be using it; PySide6 queues such a
deletion for the main thread (``Shiboken::BindingManager::runDeletionInMainThread``),
and the test suite saw exactly that crash (a segfault; see ``tests/gui/conftest.py``).
:func:`pin_to_gui_thread` turns the automatic collector off and runs the same
generational collections from a timer on the GUI thread, so every cycle dies there.
The pattern is the one calibre and pyqtgraph (``pyqtgraph.util.garbage_collector``) use.
"""

from __future__ import annotations

import gc

from PySide6.QtCore import QObject, QTimer

__all__ = ["CHECK_MS", "GuiThreadCollector", "pin_to_gui_thread"]

#: How often the GUI thread looks at the collector's counts. Objects made meanwhile by
#: any thread wait for the next look (100 ms of allocations: a few MB at most).
CHECK_MS = 100


class GuiThreadCollector(QObject):
    """Runs the collector's generations from a GUI-thread timer, as CPython would have
    run them automatically (a generation is collected when its count passes its
    threshold, :func:`gc.get_threshold`; the oldest due generation is collected with
    the younger ones).

    Parameters
    ----------
    parent : QObject
        The object on the GUI thread that owns the timer (the application).
    interval_ms : int
        Period of the check in ms.

    Attributes
    ----------
    collections : list of int
        Collections run so far, per generation (0, 1, 2).
    """

    def __init__(self, parent: QObject, interval_ms: int = CHECK_MS) -> None:
        super().__init__(parent)
        self.collections = [0, 0, 0]
        self._was_enabled = gc.isenabled()
        gc.disable()
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self.check)
        self._timer.start()

    def check(self) -> int | None:
        """Collect the oldest generation whose count passed its threshold, with the
        younger ones; returns that generation, or None when none was due."""
        counts, thresholds = gc.get_count(), gc.get_threshold()
        for gen in (2, 1, 0):
            if thresholds[gen] and counts[gen] > thresholds[gen]:
                gc.collect(gen)
                self.collections[gen] += 1
                return gen
        return None

    def stop(self) -> None:
        """Stop the timer and give the collection back to CPython (as it was)."""
        self._timer.stop()
        if self._was_enabled:
            gc.enable()


def pin_to_gui_thread(app: QObject) -> GuiThreadCollector:
    """Turn the automatic collector off and collect from ``app``'s thread (call on the
    GUI thread, before the workers start). Returns the collector (keep it; its
    :meth:`~GuiThreadCollector.stop` undoes this)."""
    return GuiThreadCollector(app)
