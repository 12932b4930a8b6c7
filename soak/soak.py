"""The operator's day in a real window, from the outside: X server, window manager,
emulators, the GUI process, and how it ended.

:func:`run_day` starts Xvfb (unless told to use a display) and a window manager
(openbox, else fluxbox), and for the emulated bench the protocol emulators
(:class:`instrument.devices.emulated_bench.EmulatedBench`, as ``diffuserlab emulators start``
runs them) with their bench file; then it runs ``python -m soak.operator_day`` (the
real ``diffuserlab gui`` on the xcb platform, driven through xdotool), unplugs and
plugs back an emulated device when the operator asks, and waits for the process to
end. It returns the operator's report with what only the outside sees: the exit
status, a "Fatal Python error" or another abort on stderr, and the state of the run
that was recording when the operator pressed Ctrl+Q.

:func:`summarise` turns a report into the figures the soak benchmark prints and the
operator-day tests check: crashes, lost frames, lateness p99 / max per phase,
reference-count drift and memory growth after the warm-up.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

__all__ = ["GOALS", "print_summary", "run_day", "summarise", "x_display"]

#: The goals of the day (issue: 60 minutes, every phase).
GOALS = {"crashes": 0, "lost_frames": 0, "p99_ms": 100.0, "max_ms": 250.0,
         "rss_growth_pct": 10.0, "none_drift_per_min": 60.0}
#: The warm-up is the day's first pass (the bench opening, numba compiling, dask and
#: the libraries imported, caches filled); a day without a second pass falls back to
#: leaving out the samples of the first this many seconds.
WARMUP_S = 120.0
#: Window managers tried, in order.
WINDOW_MANAGERS = ("openbox", "fluxbox")


#: The pid of the Xvfb each open :func:`x_display` started, by display.
X_SERVER_PIDS: dict[str, int] = {}


def peer_env(display: str) -> dict[str, str]:
    """The environment that tells the day's monitor which X server its GUI waits on."""
    from soak.kernelstats import PEERS_ENV

    pid = X_SERVER_PIDS.get(display)
    return {PEERS_ENV: str(pid)} if pid else {}


@contextlib.contextmanager
def x_display(display: str | None = None, size: str = "1600x1000x24"):
    """Context manager: an X display with a window manager running on it, as
    ``(display, window manager's name)``: ``display`` as it is, else a new Xvfb of
    ``size``; both stopped on exit.

    Raises
    ------
    FileNotFoundError
        Xvfb or a window manager is not installed (scripts/system-deps.sh).
    """
    procs: list[subprocess.Popen] = []
    try:
        if display is None:
            xvfb = shutil.which("Xvfb")
            if xvfb is None:
                raise FileNotFoundError(2, "Xvfb is not installed (apt-get install xvfb, "
                                        "see scripts/system-deps.sh)", "Xvfb")
            r, w = os.pipe()
            procs.append(subprocess.Popen([xvfb, "-displayfd", str(w), "-screen", "0", size,
                                           "-nolisten", "tcp"], pass_fds=(w,),
                                          stderr=subprocess.DEVNULL))
            os.close(w)
            with os.fdopen(r) as f:
                number = f.readline().strip()
            if not number:
                raise RuntimeError("Xvfb did not start")
            display = f":{number}"
            X_SERVER_PIDS[display] = procs[0].pid
        env = {**os.environ, "DISPLAY": display}
        wm = next((shutil.which(name) for name in WINDOW_MANAGERS if shutil.which(name)), None)
        if wm is None:
            raise FileNotFoundError(2, "no window manager (apt-get install openbox, see "
                                    "scripts/system-deps.sh)", "openbox")
        procs.append(subprocess.Popen([wm], env=env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        time.sleep(1.0)
        yield display, Path(wm).name
    finally:
        X_SERVER_PIDS.pop(display, None)
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()


def _serve_control(sock: socket.socket, bench) -> threading.Thread:
    """Carry out the operator's ``unplug NAME`` / ``replug NAME`` requests."""

    def serve() -> None:
        with contextlib.suppress(OSError):
            for line in sock.makefile("r"):
                verb, _, name = line.strip().partition(" ")
                emulator = bench.emulators.get(name)
                if emulator is not None and verb in ("unplug", "replug"):
                    getattr(emulator, verb)()
                sock.sendall(b"ok\n")

    thread = threading.Thread(target=serve, name="day-control", daemon=True)
    thread.start()
    return thread


def run_day(*, emulated: bool = False, minutes: float = 5.0, alignment_s: float = 30.0,
            display: str | None = None, work: str | None = None,
            timeout_s: float | None = None) -> dict:
    """Run the operator's day (module docstring); returns the report.

    Parameters
    ----------
    emulated : bool
        The emulated bench (the real drivers on protocol emulators) instead of the
        simulated one.
    minutes : float
        Length of the day (the day's middle repeats while time is left).
    alignment_s : float
        Seconds before the alignment is aborted (0: it runs to the end).
    display : str, optional
        An X display to use (default: a new Xvfb).
    work : str, optional
        Folder for the runs, settings and report (default a temporary folder).
    timeout_s : float, optional
        Longest the GUI process may take (default the day plus 10 minutes).

    Returns
    -------
    dict
        The operator's report (:mod:`soak.operator_day`) plus ``returncode``,
        ``crashed`` (bool), ``stderr_tail``, ``window_manager``, ``quit_run`` (the
        recording's run status and lock after Ctrl+Q) and ``load_avg``.
    """
    from instrument.devices.emulated_bench import EmulatedBench

    work_dir = Path(work or tempfile.mkdtemp(prefix="operator-day-"))
    work_dir.mkdir(parents=True, exist_ok=True)
    report_path = work_dir / "report.json"
    timeout_s = timeout_s or minutes * 60 + 600
    root = Path(__file__).resolve().parents[1]  # the checkout (soak is not installed)
    env = {**os.environ, "QT_QPA_PLATFORM": "xcb",
           "DIFFUSERLAB_GUI_SETTINGS": str(work_dir / "gui.ini"),
           "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "soak.operator_day",
           "--work", str(work_dir / "runs"), "--report", str(report_path),
           "--minutes", str(minutes), "--alignment-s", str(alignment_s)]
    bench = None
    pass_fds: tuple[int, ...] = ()
    ours = theirs = None
    load0 = os.getloadavg()
    t0 = time.monotonic()
    with contextlib.ExitStack() as stack:
        display, wm = stack.enter_context(x_display(display))
        env["DISPLAY"] = display
        env.update(peer_env(display))
        if emulated:
            bench = stack.enter_context(EmulatedBench(work_dir / "ports", time_scale=20.0))
            bench_file = work_dir / "bench-emulated.toml"
            bench_file.write_text(bench.bench_text())
            cmd += ["--bench", str(bench_file)]
            ours, theirs = socket.socketpair()
            stack.callback(ours.close)
            _serve_control(ours, bench)
            pass_fds = (theirs.fileno(),)
            env["DIFFUSERLAB_DAY_CONTROL"] = str(theirs.fileno())
        else:
            cmd += ["--simulate"]
        with open(work_dir / "gui-stderr.log", "w") as err:
            proc = subprocess.Popen(cmd, env=env, cwd=work_dir, stdout=subprocess.DEVNULL,
                                    stderr=err, pass_fds=pass_fds)
            if theirs is not None:
                theirs.close()
            try:
                rc = proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                rc = proc.wait()
    stderr = (work_dir / "gui-stderr.log").read_text(errors="replace")
    report = json.loads(report_path.read_text()) if report_path.exists() else {
        "completed": [], "failure": "no report written (the GUI process ended first)"}
    crashed = rc != 0 or "Fatal Python error" in stderr
    report.update(returncode=rc, crashed=crashed, stderr_tail=stderr[-4000:],
                  tracebacks=stderr.count("Traceback (most recent"),
                  window_manager=wm, wall_s=time.monotonic() - t0, work=str(work_dir),
                  load_avg={"start": load0, "end": os.getloadavg()})
    quit_run = report.get("notes", {}).get("quit_recording")
    if quit_run:
        report["quit_run"] = _run_state(quit_run)
    return report


def _run_state(path: str) -> dict:
    from instrument.runs.runstore import RunStore, RunStoreError

    try:
        store = RunStore.open(path)
        s = store.summary(verify=False)
        return {"status": s["status"], "lock": s["lock"], "frames_done": s["frames_done"],
                "problems": store.verify()}
    except (RunStoreError, OSError) as exc:
        return {"error": str(exc)}


def _print_array_census(taken: list[dict]) -> None:
    """The NumPy arrays alive at each pass's stream phase (``DIFFUSERLAB_DAY_CENSUS``
    set: :func:`soak.daymonitor.array_holders`), and the holders that changed most
    between the second census and the last."""
    taken = [c["arrays"] for c in taken if "arrays" in c]
    if len(taken) < 2:
        return
    print("  arrays alive at each pass's stream phase (MiB): "
          + ", ".join(f"{a['mb']:.0f}" for a in taken))
    first, last = ({h["where"]: h["mb"] for h in a["holders"]} for a in (taken[1], taken[-1]))
    moved = sorted(set(first) | set(last), key=lambda w: -abs(last.get(w, 0) - first.get(w, 0)))
    for where in moved[:8]:
        print(f"    {where}: {first.get(where, 0):.1f} -> {last.get(where, 0):.1f} MiB")


def summarise(report: dict) -> dict:
    """The day's figures against :data:`GOALS` (see the module docstring).

    Returns
    -------
    dict
        ``crashes``, ``lost_frames``, ``phases`` (lateness per phase), ``worst_p99_ms``,
        ``worst_max_ms``, ``none_drift_per_min`` and ``true_drift_per_min`` (slope of a
        straight line through the samples after the warm-up: the first pass),
        ``rss_growth_pct`` (last sample over the first after the warm-up); with three
        passes or more these are taken at the passes' starts instead (``drift_basis``;
        the figures over every sample move to ``within_passes``): each pass starts in
        the same state, so what grows from one start to the next is a leak, while the
        data a pass puts on display (the alignment's plot holds about 2.5 references
        to None per point, 1400 points in a whole alignment) goes with it; ``per_loop``
        (memory and None's count at each pass's start), ``stalls`` (what the GUI thread
        ran when the watchdog saw it 100 ms late, counted), ``goals_met`` (per goal).
    """
    lost = sum(int(r.get("lost_by_recorder") or 0) + int(r.get("dropped_by_camera") or 0)
               + int(r.get("skipped_by_ring") or 0) for r in report.get("records", []))
    every = report.get("samples", [])
    samples = [s for s in every if s.get("loop", 0) >= 1]  # after the first pass
    warmup = "the first pass"
    if len(samples) < 2:
        samples = [s for s in every if s["t_s"] >= WARMUP_S] or every[-3:]
        warmup = f"{WARMUP_S:.0f} s"
    out: dict = {"crashes": int(bool(report.get("crashed"))), "lost_frames": lost,
                 "warmup": warmup,
                 "phases": report.get("phases", {}),
                 "worst_p99_ms": report.get("worst_p99_ms"),
                 "worst_max_ms": report.get("worst_max_ms"),
                 "completed": report.get("completed", []), "failure": report.get("failure")}
    if len(samples) >= 2:
        t = np.array([s["t_s"] for s in samples]) / 60.0
        for key in ("none", "true"):
            y = np.array([s[f"{key}_refs"] for s in samples], float)
            out[f"{key}_drift_per_min"] = _slope(t, y)
            out[f"{key}_refs_range"] = [int(y.min()), int(y.max())]
        starts: dict[int, dict] = {}
        for s in every:
            starts.setdefault(s.get("loop", 0), s)
        out["per_loop"] = [{"loop": k, "t_s": round(v["t_s"]), "rss_mb": round(v["rss_mb"]),
                            "none_refs": v["none_refs"],
                            **{h: round(v[h]) for h in _HEAP_KEYS if h in v}}
                           for k, v in sorted(starts.items())]
        rss = [s["rss_mb"] for s in samples]
        out["rss_mb"] = [round(rss[0], 1), round(rss[-1], 1), round(max(rss), 1)]
        out["rss_growth_pct"] = 100.0 * (rss[-1] - rss[0]) / rss[0]
        later = [v for k, v in sorted(starts.items()) if k >= 1]
        if len(later) >= 2:  # leaks, not data on display: the same state each pass
            out["drift_basis"] = f"the starts of passes 2-{len(later) + 1}"
            out["within_passes"] = {k: out[k] for k in (
                "none_drift_per_min", "true_drift_per_min", "rss_growth_pct")}
            t = np.array([v["t_s"] for v in later]) / 60.0
            for key in ("none", "true"):
                out[f"{key}_drift_per_min"] = _slope(
                    t, np.array([v[f"{key}_refs"] for v in later], float))
            out["rss_growth_pct"] = 100.0 * (later[-1]["rss_mb"] - later[0]["rss_mb"]) \
                / later[0]["rss_mb"]
    phases = out["phases"].values()
    out["goals_met"] = {
        "crashes": out["crashes"] == GOALS["crashes"],
        "lost_frames": lost == GOALS["lost_frames"],
        "p99_ms": all(p["p99_ms"] < GOALS["p99_ms"] for p in phases),
        "max_ms": all(p["max_ms"] < GOALS["max_ms"] for p in phases),
        "rss_growth_pct": out.get("rss_growth_pct", 0.0) < GOALS["rss_growth_pct"],
        "none_drift_per_min": abs(out.get("none_drift_per_min", 0.0))
        < GOALS["none_drift_per_min"]}
    out["stalls"] = _stall_causes(report.get("stalls", []))
    return out


#: The allocator's figures in each sample (:func:`gui.memory.heap_mb`), MB.
_HEAP_KEYS = ("heap_in_use_mb", "heap_free_mb", "heap_mapped_mb")


def _slope(t: np.ndarray, y: np.ndarray) -> float:
    """Slope of a straight line through ``(t, y)`` (0 for a single time)."""
    return float(np.polyfit(t, y, 1)[0]) if np.ptp(t) > 0 else 0.0


#: The GUI thread's innermost frame when it waited in Qt's event loop (no Python of
#: ours running: the process waited for a core, or for the GIL held by a worker).
_EVENT_LOOP = ("app.py", "main")


def _stall_causes(stalls: list[dict]) -> list[tuple[str, int]]:
    """What the GUI thread ran during the watchdog's stalls, most frequent first:
    ``"event loop (waiting for a core or the GIL)"`` or its innermost frames."""
    from collections import Counter

    causes: Counter = Counter()
    for st in stalls:
        stack = st.get("gui_stack") or []
        inner = stack[-1] if stack else ""
        parts = inner.split(":")
        if not stack:
            what = "not seen live (the watchdog waited for the GIL or a core too)"
        elif len(parts) >= 3 and parts[0].endswith(_EVENT_LOOP[0]) and parts[2] == _EVENT_LOOP[1]:
            what = "event loop (waiting for a core or the GIL)"
            busy = ", ".join(sorted({t.split("@")[0] for t in st.get("threads", [])}))
            if busy:
                what += f"; running: {busy}"
        else:
            what = " <- ".join(reversed(stack[-3:]))
        if stack and st.get("seen_by") == "faulthandler":
            what += " (the GIL held: seen by faulthandler, not live)"
        causes[f"{st.get('phase')}: {what}"] += 1
    return causes.most_common()


def print_summary(s: dict, report: dict) -> None:
    """The soak benchmark's printout."""
    print(f"operator day: {'emulated' if not report.get('simulate', True) else 'simulated'} "
          f"bench, {report.get('day_s', 0) / 60:.1f} min, {report.get('loops', 0)} extra "
          f"loops, platform {report.get('platform')}, window manager "
          f"{report.get('window_manager')}")
    la = report.get("load_avg", {})
    print(f"  machine load average (1/5/15 min) at start {la.get('start')}, end "
          f"{la.get('end')}")
    print(f"  steps completed: {len(s['completed'])}"
          + (f"; FAILED: {s['failure']}" if s.get("failure") else ""))
    print(f"  crashes {s['crashes']} (exit status {report.get('returncode')}), tracebacks "
          f"{report.get('tracebacks')}, lost frames {s['lost_frames']}")
    if report.get("retyped"):  # keys the X server repeated under load, typed again
        print(f"  fields typed again: {len(report['retyped'])} ({'; '.join(report['retyped'])})")
    print("  GUI-thread lateness of a 10 ms timer, per phase:")
    for name, p in s["phases"].items():
        flag = "" if p["p99_ms"] < GOALS["p99_ms"] and p["max_ms"] < GOALS["max_ms"] else \
            "  <- over the goal"
        print(f"    {name:<14} p50 {p['p50_ms']:6.2f}  p99 {p['p99_ms']:7.2f}  max "
              f"{p['max_ms']:8.2f} ms  ({p['firings']} firings, {p['seconds']:.0f} s){flag}")
    if "none_drift_per_min" in s:
        basis = s.get("drift_basis", f"every sample after {s['warmup']}")
        print(f"  refcount drift ({basis}): None {s['none_drift_per_min']:+.1f}/min, True "
              f"{s['true_drift_per_min']:+.1f}/min; RSS growth {s['rss_growth_pct']:+.1f} %")
        within = s.get("within_passes")
        if within:
            print(f"  over every sample after {s['warmup']}: None "
                  f"{within['none_drift_per_min']:+.1f}/min, RSS "
                  f"{within['rss_growth_pct']:+.1f} %")
        print(f"  RSS {s['rss_mb'][0]:.0f} -> {s['rss_mb'][1]:.0f} MB (max "
              f"{s['rss_mb'][2]:.0f}); None refs range {s['none_refs_range']}")
    if s.get("per_loop"):
        print("  at each pass's start (s: RSS MB, None refs): " + ", ".join(
            f"{p['t_s']}: {p['rss_mb']}, {p['none_refs']}" for p in s["per_loop"]))
        if all(h in s["per_loop"][0] for h in _HEAP_KEYS):
            print("  the allocator's heaps at each pass's start (MB in use / free / mapped): "
                  + ", ".join(f"{p['heap_in_use_mb']}/{p['heap_free_mb']}/{p['heap_mapped_mb']}"
                              for p in s["per_loop"]))
    for g in report.get("heap_growth", [])[:8]:  # DIFFUSERLAB_TRACEMALLOC set
        print(f"  heap grew {g['mb']:+.1f} MB ({g['count']:+d} blocks) at "
              + " <- ".join(reversed(g["where"][-3:])))
    _print_array_census(report.get("notes", {}).get("census", []))
    fg = report.get("frozen_garbage")  # DIFFUSERLAB_DAY_FROZEN_GARBAGE set
    if fg:
        print(f"  at the day's end: {fg['frozen']} objects frozen; a full collection found "
              f"{fg['garbage']} unreachable (holding {fg.get('garbage_arrays_mb', 0):.0f} MiB "
              f"of arrays), {fg['frozen_garbage']} more once unfrozen "
              f"({1e3 * fg['collect_s']:.0f} ms, holding {fg.get('arrays_mb', 0):.0f} MiB of "
              f"arrays); RSS {fg['rss_mb']:.0f} -> {fg.get('rss_mb_collected', 0):.0f} (the "
              f"ordinary garbage freed) -> {fg['rss_mb_after']:.0f} MB (the frozen too)")
        for label, key, holders in (("ordinary", "garbage_types", "garbage_array_holders"),
                                    ("frozen", "types", "array_holders")):
            if fg.get(key):
                print(f"  the {label} garbage by type: " + ", ".join(
                    f"{k} {v}" for k, v in fg[key].items()))
            if fg.get(holders):
                print(f"  the arrays of the {label} garbage by holder (MiB): " + ", ".join(
                    f"{h['where']} {h['mb']:.1f}" for h in fg[holders][:8]))
    gc = report.get("gc", {})
    if gc:
        print("  garbage collector pauses: " + ", ".join(
            f"{g} {v['count']} x, max {v['max_ms']:.0f} ms" for g, v in sorted(gc.items())))
    lost_clicks = report.get("notes", {}).get("jog_clicks_not_received")
    if lost_clicks:
        print(f"  jog clicks sent by xdotool that the button never got (clicked again): "
              f"{lost_clicks}")
    q = report.get("quit_run")
    if q:
        print(f"  Ctrl+Q while recording: run {q.get('status')}, lock {q.get('lock')}, "
              f"{q.get('frames_done')} frames, problems {q.get('problems')}")
    if s.get("stalls"):
        print(f"  stalls over 100 ms, what the GUI thread ran ({sum(n for _, n in s['stalls'])}"
              " seen by the watchdog; most frequent first):")
        for what, n in s["stalls"][:12]:
            print(f"    {n:4d} x {what}")
    met = s["goals_met"]
    print("  goals: " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in met.items()))
