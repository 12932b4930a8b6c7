"""gui.gcthread: the window's garbage collection runs on the GUI thread only."""

from __future__ import annotations

import gc
import threading

from tests.gui.conftest import wait_for


class _Cycle:
    """An object in a reference cycle that notes the thread it was destroyed on."""

    died_on: list[int] = []

    def __init__(self) -> None:
        self.me = self

    def __del__(self) -> None:
        _Cycle.died_on.append(threading.get_ident())


def _garbage_from_a_worker() -> None:
    """In a worker thread: drop cycles past the collector's threshold, as a Job thread
    or the frame reader does all day."""

    def work() -> None:
        for _ in range(3 * gc.get_threshold()[0]):
            _Cycle()

    t = threading.Thread(target=work, name="worker")
    t.start()
    t.join(60)
    assert not t.is_alive()


def test_a_cycle_made_and_dropped_in_a_worker_dies_on_the_gui_thread(qapp):
    """CPython collects in the thread whose allocation crosses the threshold, so a Qt
    object in a cycle could be destroyed from a worker, a segfault in PySide6 (the
    emulated operator day's GUI process ended on SIGSEGV, run K). Pinned, the worker's
    garbage waits for the GUI thread's timer."""
    from gui.gcthread import pin_to_gui_thread

    gc.collect()
    _Cycle.died_on.clear()
    collector = pin_to_gui_thread(qapp)
    try:
        assert not gc.isenabled()
        _garbage_from_a_worker()
        assert _Cycle.died_on == []  # the worker's allocations collected nothing
        wait_for(qapp, lambda: _Cycle.died_on, 60.0, "the GUI thread's collection")
        assert set(_Cycle.died_on) == {threading.main_thread().ident}
        assert collector.collections[0] >= 1
    finally:
        collector.stop()
    assert gc.isenabled()


def test_without_the_pin_the_worker_collects(qapp):
    """The control: CPython's own collector destroys the worker's cycle on the worker
    (what the pin prevents), so the test above can fail."""
    gc.collect()
    _Cycle.died_on.clear()
    assert gc.isenabled()
    _garbage_from_a_worker()
    assert _Cycle.died_on and _Cycle.died_on[0] != threading.main_thread().ident

