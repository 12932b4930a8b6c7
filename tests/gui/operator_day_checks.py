"""What every operator-day run must show (shared by the simulated and emulated tests)."""

from __future__ import annotations

import os

#: Steps both days must complete.
COMMON_STEPS = ("connect", "stream", "stage", "leds", "calibration with pause, abort, resume",
                "live Wiener", "live ADMM", "recording 200 frames with live reconstruction",
                "batch", "results with slider steps", "image tools and a snapshot",
                "unplug and Reconnect", "shortcuts", "quit asked while recording")
#: A freeze, not a speed goal (the goals are the soak benchmark's): the Results panel
#: used to hold the event loop 5-50 s per slider step. Stretched by :func:`load_factor`.
FREEZE_MS = 3000.0
#: A binding that leaks None loses ~860 references a second while streaming.
LEAK_PER_MIN = -20000.0


def load_factor(report: dict) -> float:
    """How much busier than its cores the machine was around the day: the larger 1-minute
    load average (at the start and the end) over the core count, at least 1. A wait for
    a core or for the GIL held by a worker that waits for one (the workers run at nice
    10) grows with it: the README's command beside two busy loops (load 5.5 on 2 cores)
    saw the event loop held past ``FREEZE_MS`` with no freeze of ours."""
    la = report.get("load_avg") or {}
    loads = [v[0] for v in (la.get("start"), la.get("end")) if v]
    return max(1.0, max(loads, default=0.0) / (os.cpu_count() or 1))


def check_day(report: dict, figures: dict, extra_steps: tuple[str, ...] = ()) -> None:
    assert not report["crashed"], (report["returncode"], report["stderr_tail"][-3000:])
    assert report["tracebacks"] == 0, report["stderr_tail"][-3000:]
    assert report.get("platform") == "xcb", report.get("platform")
    assert figures["failure"] is None, (figures["failure"], report["work"])
    missing = [s for s in (*COMMON_STEPS, *extra_steps) if s not in figures["completed"]]
    assert not missing, missing
    assert figures["lost_frames"] == 0, report["records"]
    assert not [ln for ln in report["log_errors"] if "bug" in ln], report["log_errors"]
    q = report["quit_run"]
    assert q["status"] == "stopped" and q["lock"] is None and q["problems"] == [], q
    assert q["frames_done"] >= 10, q
    assert report["worst_max_ms"] < FREEZE_MS * load_factor(report), (report["load_avg"],
                                                                        report["phases"])
    assert figures.get("none_drift_per_min", 0.0) > LEAK_PER_MIN, figures
    assert report["xinput_errors"] == [], report["xinput_errors"]
