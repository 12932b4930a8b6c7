"""The simulated clock advanced from several threads at once (the GUI's LED click while
the camera's grab thread paces the real-time clock): "now" read under the lock, so
an advance never goes back (it raised "SimClock: cannot go back from ...")."""

from __future__ import annotations

import threading

from drivers.simulated.clock import SimClock


def test_concurrent_advances_never_go_back():
    clock = SimClock(realtime=True, max_lag_s=10.0)
    errors: list[BaseException] = []

    def worker() -> None:
        try:
            for _ in range(40):
                clock.advance(0.0005)
        except BaseException as exc:  # noqa: BLE001 (collected, asserted below)
            errors.append(exc)

    threads = [threading.Thread(target=worker) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert errors == []
    assert clock.now_s >= 6 * 40 * 0.0005 - 1e-9
