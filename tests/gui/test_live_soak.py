"""Live ADMM in a real window, measured from outside (:mod:`soak.live_soak`):
Xvfb with the xcb platform, openbox, the real ``diffuserlab gui`` with its live
reconstruction in a process of its own, and a key and a click sent through the X
server every few seconds whose effect this test's process sees on the screen.

The lateness and delay goals are the hour-long soak's (``python -m
soak.live_soak``, figures in the operator guide); here a crash, a live
reconstruction in the window's process, an error, a key or a click that never shows,
or a window that hangs fail the test. The delays are printed, not judged: they depend
on the machine's load."""

from __future__ import annotations

import math

import pytest

#: The GUI thread held this long is a hang (a hang guard: 1 s stretched by the tests'
#: factor, 10 s, is within what a loaded host can stall a window that works).
HANG_GUARD_S = 60.0


def test_live_admm_in_a_real_window_answers_keys_and_clicks(tmp_path, monkeypatch):
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    from soak.live_soak import print_figures, run_live_soak

    report = run_live_soak(minutes=2.0, probe_s=5.0, work=str(tmp_path / "soak"))
    f = report["figures"]
    print_figures(f)
    assert not report["crashed"] and not report.get("failure"), (
        report.get("failure"), report["stderr_tail"])
    assert report["completed"] == ["live ADMM started", "soak"]
    live = f["live"]
    assert live["in_process"] == "LiveReconstructionProcess"  # not a thread of the window
    assert live["child"]["pid"] != live["gui_pid"] and live["errors"] == 0
    # it kept reconstructing and showing (how many in the 2 minutes is the host's speed:
    # more than 10 failed at load; rates are the hour-long soak's)
    assert live["reconstructed"] >= 2 and live["frames_shown"] >= 2, live
    assert f["probe_rounds"] >= 1
    for kind in ("key_ms", "backspace_ms", "click_ms", "escape_ms"):
        # each shows on the screen: in one probe at least (a probe gives up after 5 s,
        # which a loaded host's late window can pass; none seen is a key lost)
        assert any(p[kind] is not None for p in report["probes"]), (kind, report["probes"])
    assert f["max_ms"] < 1000.0 * HANG_GUARD_S, "the window hung"


def test_the_figures_judge_each_goal():
    from soak.live_soak import GOALS, figures

    probe = {"key_ms": 12.0, "backspace_ms": 9.0, "click_ms": 20.0, "escape_ms": 8.0,
             "load_1min": 2.5}
    report = {"phases": {"soak": {"seconds": 60.0, "firings": 5000, "p50_ms": 0.2,
                                  "p99_ms": 30.0, "max_ms": 120.0}},
              "probes": [probe, {**probe, "click_ms": 150.0, "load_1min": 4.5}],
              "crashed": False}
    f = figures(report)
    assert f["goals_met"] == {"max_ms": True, "p99_ms": True, "visible_ms": False,
                              "load": False, "no_crash": True}
    assert f["click_ms"]["over_100"] == 1 and f["click_ms"]["max"] == 150.0
    assert f["load_1min"] == {"min": 2.5, "median": 3.5, "max": 4.5}
    report["probes"].append({**probe, "key_ms": None})  # never seen: JSON's null
    f = figures(report)
    assert f["key_ms"]["max"] == math.inf and f["key_ms"]["over_100"] == 1
    assert not f["goals_met"]["visible_ms"]
    report["phases"]["soak"]["max_ms"] = GOALS["max_ms"]
    assert not figures(report)["goals_met"]["max_ms"]
    report["failure"] = "StepFailed: the bench did not open"
    assert not figures(report)["goals_met"]["no_crash"]


@pytest.mark.parametrize("missing", ["phases", "probes"])
def test_a_soak_without_measurements_meets_no_goal(missing):
    from soak.live_soak import figures

    report = {"phases": {"soak": {"seconds": 60.0, "firings": 5000, "p50_ms": 0.2,
                                  "p99_ms": 30.0, "max_ms": 120.0}},
              "probes": [{"key_ms": 12.0, "backspace_ms": 9.0, "click_ms": 20.0,
                          "escape_ms": 8.0, "load_1min": 1.0}]}
    report[missing] = {} if missing == "phases" else []
    met = figures(report)["goals_met"]
    assert not all(met.values())
    if missing == "phases":
        assert not met["max_ms"] and not met["p99_ms"]
    else:
        assert not met["visible_ms"] and not met["load"]


def test_beside_busy_loops_the_goal_is_a_stall_under_a_second():
    from soak.live_soak import GOALS, figures

    report = {"phases": {"soak": {"seconds": 60.0, "firings": 5000, "p50_ms": 0.4,
                                  "p99_ms": 80.0, "max_ms": 900.0}},
              "probes": [{"key_ms": 150.0, "backspace_ms": 9.0, "click_ms": 20.0,
                          "escape_ms": 8.0, "load_1min": 6.5}],
              "crashed": False, "busy_processes": 3}
    f = figures(report)
    assert f["busy_processes"] == 3
    assert f["goals_met"] == {"max_ms_beside_busy": True, "no_crash": True}
    report["phases"]["soak"]["max_ms"] = GOALS["busy_max_ms"]
    assert figures(report)["goals_met"]["max_ms_beside_busy"] is False


def test_busy_loops_spin_until_the_block_ends():
    import os
    import time

    from soak.live_soak import busy_loops

    def cpu_s(pid: int) -> float:
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    with busy_loops(2) as pids:
        assert len(pids) == 2
        # each in a session of its own (another program's), unless asked for the soak's
        assert all(os.getsid(p) == p for p in pids)
        deadline = time.monotonic() + 120.0  # hang guard: each has used some CPU
        while not all(cpu_s(p) > 0.05 for p in pids):
            assert time.monotonic() < deadline, "the busy loops never ran"
            time.sleep(0.05)
    for pid in pids:  # killed and reaped
        assert not os.path.exists(f"/proc/{pid}")


def test_busy_loops_in_the_soaks_session_on_request():
    import os

    from soak.live_soak import busy_loops

    with busy_loops(1, own_session=False) as pids:
        assert os.getsid(pids[0]) == os.getsid(0)


def test_the_admm_wait_fails_only_without_progress():
    from soak.live_soak import progressing
    from soak.operator_day import StepFailed

    now, count = [0.0], [0]
    ready = progressing(lambda: count[0], 10, 300.0, clock=lambda: now[0])
    for step in range(1, 11):  # one reconstruction every 200 s: slow, never stalled
        now[0], count[0] = 200.0 * step, step
        assert not ready()
    count[0] = 11
    assert ready()
    stalled = progressing(lambda: 3, 10, 300.0, clock=lambda: now[0])
    assert not stalled()
    now[0] += 300.0
    assert not stalled()  # exactly the bound: not yet
    now[0] += 1.0
    with pytest.raises(StepFailed, match="no progress for 300 s"):
        stalled()


def test_the_soak_lasts_its_own_minutes_after_a_slow_set_up():
    from soak.live_soak import soak_end

    assert soak_end(100.0, 160.0, 10.0, None) == 700.0  # the day's minutes, as before
    assert soak_end(100.0, 160.0, 10.0, 10.0) == 760.0  # ten minutes of soak
    assert soak_end(100.0, 160.0, 30.0, 10.0) == 1900.0  # the longer of the two
