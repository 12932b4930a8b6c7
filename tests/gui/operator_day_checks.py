"""What every operator-day run must show (shared by the simulated and emulated tests)."""

from __future__ import annotations

#: Steps both days must complete.
COMMON_STEPS = ("connect", "stream", "stage", "leds", "calibration with pause, abort, resume",
                "live Wiener", "live ADMM", "recording 200 frames with live reconstruction",
                "batch", "results with slider steps", "image tools and a snapshot",
                "unplug and Reconnect", "shortcuts", "quit asked while recording")
#: A freeze, not a speed goal (the goals are the soak benchmark's): the Results panel
#: used to hold the event loop 5-50 s per slider step. Judged on each stall's
#: ``ours_ms`` (:func:`soak.kernelstats.stall_time`): the stall less the
#: time the GUI thread, or the thread it waited for, spent waiting for a core, so the
#: verdict does not depend on the machine's load (beside two busy loops the event loop
#: waited 18.5 s for a core with no freeze of ours), nor on its host (a virtual machine
#: its host paused -- the kernel logged both CPUs stuck 42 s -- ran none of it).
FREEZE_MS = 3000.0
#: A binding that leaks None loses ~860 references a second while streaming.
LEAK_PER_MIN = -20000.0


def freezes(report: dict) -> list[dict]:
    """The watchdog's stalls in which our code held the GUI thread ``FREEZE_MS`` or more
    (each stall's share that was not a wait for a core nor a pause of the machine)."""
    return [st for st in report.get("stalls", [])
            if st.get("ours_ms", st.get("ms", 0.0) - st.get("paused_ms", 0.0)) >= FREEZE_MS]


def check_day(report: dict, figures: dict, extra_steps: tuple[str, ...] = ()) -> None:
    assert not report["crashed"], (report["returncode"], report["stderr_tail"][-3000:])
    assert report["tracebacks"] == 0, report["stderr_tail"][-3000:]
    assert report.get("platform") == "xcb", report.get("platform")
    # Python's collector ran on the GUI thread only (gui.gcthread), and it did run
    assert report["gc_automatic"] is False and sum(report["gc_collections"]) > 0, report
    assert figures["failure"] is None, (figures["failure"], report["work"],
                                        report.get("log_tail"))
    missing = [s for s in (*COMMON_STEPS, *extra_steps) if s not in figures["completed"]]
    assert not missing, missing
    assert figures["lost_frames"] == 0, report["records"]
    assert not [ln for ln in report["log_errors"] if "bug" in ln], report["log_errors"]
    q = report["quit_run"]
    assert q["status"] == "stopped" and q["lock"] is None and q["problems"] == [], q
    assert q["frames_done"] >= 10, q
    assert not freezes(report), (freezes(report), report["load_avg"], report["phases"])
    assert figures.get("none_drift_per_min", 0.0) > LEAK_PER_MIN, figures
    assert report["xinput_errors"] == [], report["xinput_errors"]
