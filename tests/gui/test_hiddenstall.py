"""faulthandler's look at a stall the day's watchdog cannot see (:mod:`soak.hiddenstall`):
the GIL held by a blocked thread stops the watchdog too."""

from __future__ import annotations

import os
import threading

from tests.gui.test_daymonitor import _ended_stall


def _blocked_holding_the_gil(fd: int) -> None:
    """Stands for a call on the GUI thread that blocks keeping the GIL (a binding's call
    that does not release it): ``read(2)`` through :class:`ctypes.PyDLL`, which keeps it."""
    import ctypes

    buf = ctypes.create_string_buffer(1)
    ctypes.PyDLL(None).read(fd, buf, 1)


def test_a_stall_holding_the_gil_is_seen_by_faulthandler(qapp, wait):
    """The watchdog cannot run while the GUI thread blocks holding the GIL (run F3: a
    4.0 s stall recorded with no stack); faulthandler's thread can. The block ends when
    another process sees faulthandler's dump written (an event, not a time)."""
    import subprocess
    import sys

    from PySide6.QtCore import QTimer

    from soak.daymonitor import DayMonitor
    from soak.soak import _stall_causes

    monitor = DayMonitor(sample_s=1.0)
    monitor.start()
    r, w = os.pipe()
    try:
        path = monitor.dump_path
        # writes a byte once the dump file is not empty (gives up after ~600 s)
        watcher = subprocess.Popen(
            [sys.executable, "-c", "import os, sys, time\n"
             "for _ in range(12000):\n"
             f"    if os.path.getsize({path!r}) > 0: break\n"
             "    time.sleep(0.05)\n"
             f"os.write({w}, b'x')\n"], pass_fds=(w,))
        QTimer.singleShot(50, lambda: _blocked_holding_the_gil(r))
        held = _ended_stall(monitor, "_blocked_holding_the_gil")
        wait(held, 600, "the stall's end")
        watcher.wait(60)
    finally:
        monitor.stop()
        os.close(r)
        os.close(w)
    stall = held()
    assert stall["seen_by"] == "faulthandler", stall
    assert stall["gui_stack"][-1].endswith("_blocked_holding_the_gil"), stall
    # no bound on its length from HIDDEN_AFTER_S: a loaded host can run the watchdog's
    # last arming well before the block began (run J5: 701.9 ms, armed earlier)
    (cause, n), = [c for c in _stall_causes([stall])]
    assert "_blocked_holding_the_gil" in cause and "faulthandler" in cause, cause



def test_faulthandlers_look_goes_to_the_stall_it_was_taken_in():
    """A look is written after its arming ran out and read later; a stall that ended
    before that (the load's, handled in the same turn as the block's) does not get it."""
    import time

    from soak.hiddenstall import HIDDEN_AFTER_S, HiddenStallLook

    look = HiddenStallLook()
    try:
        look.tick()  # armed now
        armed = time.monotonic()
        with open(look.path, "a") as dump:  # what faulthandler writes, as it writes it
            dump.write(f'Timeout (0:00:01)!\nThread {threading.get_ident():#x} (most recent '
                       'call first):\n  File "/x/gui/app.py", line 7 in held\n')
        look.tick()
        read = time.monotonic()
        assert look.claim(armed - 5.0, armed - 4.0) is None  # ended before it was written
        assert look.claim(read + 1.0, read + 2.0) is None  # began after it was read
        stacks = look.claim(armed, armed + HIDDEN_AFTER_S + 0.01)
        assert stacks == {threading.get_ident(): [("/x/gui/app.py", 7, "held")]}, stacks
        assert look.claim(armed, read) is None  # once
    finally:
        look.close()
