"""Shared slots name the process that made them, and the next slot made removes those a
killed process left in /dev/shm (instrument.acquisition.shared_slot.reclaim_orphaned_slots)."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import textwrap
import threading

import pytest

from instrument.acquisition.shared_slot import SHM_DIR, SharedImageSlot, slot_owner

pytestmark = pytest.mark.skipif(not (os.path.isdir(SHM_DIR) and os.path.isdir("/proc")),
                                reason="POSIX shared memory listed in /dev/shm (Linux)")

#: Hang guard, s.
HANG_S = 60.0


def _maker(tmp_path, **popen) -> tuple[subprocess.Popen, str]:
    """A process that makes a slot (as the window makes a live view's, or the bench
    process its frames'), prints its name and holds it until its stdin closes."""
    script = tmp_path / "maker.py"
    script.write_text(textwrap.dedent(f"""
        import sys
        sys.path[:0] = {sys.path!r}
        import numpy as np
        from instrument.acquisition.shared_slot import SharedImageSlot
        slot = SharedImageSlot(64)
        slot.write(np.zeros((2, 3), np.uint16))
        print(slot.name, flush=True)
        sys.stdin.read()
        slot.close()
        """))
    proc = subprocess.Popen([sys.executable, str(script)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, **popen)
    lines: queue.SimpleQueue = queue.SimpleQueue()
    threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
    try:
        name = lines.get(timeout=HANG_S).strip()
    except queue.Empty:
        proc.kill()
        pytest.fail(f"the slot's maker printed nothing for {HANG_S:.0f} s")
    return proc, name


def _start_ticks(pid: int) -> int:
    with open(f"/proc/{pid}/stat", "rb") as f:
        return int(f.read().rsplit(b")", 1)[1].split()[19])


def test_a_slot_is_named_after_the_process_that_made_it():
    slot = SharedImageSlot(64)
    try:
        assert slot_owner(slot.name) == (os.getpid(), _start_ticks(os.getpid()))
    finally:
        slot.close()
    assert slot_owner("dlab-0123456789ab") is None  # a name that does not say


def test_the_next_slot_removes_a_killed_processs_slots_and_no_running_ones(tmp_path):
    # killed with its whole session, resource tracker included (a window's terminal
    # closed hard, a test run killed): nothing is left to remove its slot
    dead, dead_name = _maker(tmp_path, start_new_session=True)
    os.killpg(dead.pid, signal.SIGKILL)
    dead.wait(HANG_S)
    assert dead_name in os.listdir(SHM_DIR)  # left behind
    live, live_name = _maker(tmp_path)
    # the running maker's pid, but another start time: a process that had the pid before
    reused = f"dlab-{live.pid}-{_start_ticks(live.pid) + 1}-00ff00ff"
    from multiprocessing import shared_memory

    shared_memory.SharedMemory(reused, create=True, size=64).close()
    try:
        slot = SharedImageSlot(64)  # a bench process or live view starting
        slot.close()
        left = os.listdir(SHM_DIR)
        assert dead_name not in left and reused not in left
        assert not [n for n in left if (slot_owner(n) or (None,))[0] == dead.pid]
        assert live_name in left
    finally:
        live.stdin.close()
        live.wait(HANG_S)
    assert live_name not in os.listdir(SHM_DIR)  # its maker removed it itself
