"""A timer subscribed while another thread advances a real-time clock fires during that
advance (issue 67: a stream started while the simulated stage was moving delivered no
frame until the move ended, ~70 s: subscribing waited on the lock the advance held
through its real-time sleep)."""

from __future__ import annotations

import threading

from drivers.simulated.clock import SimClock


def test_a_timer_subscribed_during_a_real_time_advance_fires_within_it():
    clock = SimClock(realtime=True)
    advancing, done, fired = threading.Event(), threading.Event(), threading.Event()

    def move():  # a stage's wait: the clock advanced by the move's 6 s, in real time
        advancing.set()
        clock.advance(6.0)
        done.set()

    mover = threading.Thread(target=move, daemon=True)
    mover.start()
    assert advancing.wait(10.0)
    subscribed = threading.Event()
    events = [clock.now_s + 0.05]  # a camera's next frame, 50 ms of simulated time on

    def fire(t: float) -> None:
        events.clear()
        fired.set()

    def subscribe():  # as a camera's stream starts: its timer, then a resync
        clock.subscribe(lambda: events[0] if events else None, fire)
        clock.resync()
        subscribed.set()

    threading.Thread(target=subscribe, daemon=True).start()
    assert subscribed.wait(5.0), "subscribing waited for the whole advance"
    assert fired.wait(5.0), "the timer did not fire during the advance"
    assert not done.is_set()  # fired while the 6 s advance still ran
    mover.join(10.0)
    assert clock.now_s >= 6.0
