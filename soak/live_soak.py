"""An hour of live view with live ADMM in a real window, and what an operator sees of it.

``python -m soak.live_soak [--minutes 60] [--soak-minutes M] [--admm-start-s S]
[--probe-s 30] [--busy N] [--json OUT]``
starts Xvfb and a window manager (:func:`soak.soak.x_display`) and runs
the real ``diffuserlab gui`` on the simulated bench (beads flowing, the xcb platform).
Inside the GUI process an :class:`~soak.operator_day.Operator` whose day is
:meth:`LiveSoak.day` presses F5, starts the live ADMM reconstruction (5 iterations per
frame) with the bench's PSF through the Live panel, and then leaves the window alone
while :class:`~soak.daymonitor.DayMonitor` measures the GUI thread's
lateness (a 10 ms timer) and its watchdog records what ran during stalls.

From *outside* the GUI process, every ``--probe-s`` seconds a probing process of its
own (``python -m soak.live_soak probe``) sends a key and a click through
the X server (xdotool) and times when the screen shows them: it
types a character into the Live panel's dark field (then BackSpace) and clicks the
method box open (then Esc), grabbing the field's or box's pixels from the X server
(Qt's ``QScreen.grabWindow`` on a display connection of its own) every 2 ms until
they change. That delay is what an operator waits for a key or a click to show:
input through the X server, the event loop, the repaint and the X server's copy.

Printed and written (``--json``): the lateness over the soak (p50, p99, max, the
stalls), each probe's delay (p50, p99, max, per kind), the live reconstruction's rate
and errors, the camera's frames and the machine's load average (1 min) sampled at
every probe. Goals: max lateness < 250 ms, p99 < 50 ms, every probe visible within
100 ms, at a load average <= 4. With ``--busy N``, N busy loops (``python -c "while
True: pass"``, normal priority) run beside the window from the soak's start (the live
ADMM running: its process, at nice +10, would hardly start beside them) to its end;
the goal is then max lateness < 1 s (:data:`GOALS` ``busy_max_ms``), the other
figures printed beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from .device_jobs import twin_psf
from .operator_day import Operator, StepFailed, start_when_shown

__all__ = ["GOALS", "LiveSoak", "ScreenProbe", "busy_loops", "progressing", "run_live_soak",
           "soak_end"]

#: Goals of the soak (lateness of the GUI thread, delay of what an operator sees).
GOALS = {"max_ms": 250.0, "p99_ms": 50.0, "visible_ms": 100.0, "load": 4.0,
         "busy_max_ms": 1000.0}
#: Seconds of live ADMM before the soak's measurement starts (numba compiled, caches).
SETTLE_S = 30.0
#: Seconds without a new live ADMM reconstruction after which the set-up fails.
STALL_S = 300.0


class LiveSoak(Operator):
    """The soak's day inside the GUI process (module docstring)."""

    def day(self) -> Iterator:
        from PySide6.QtWidgets import QApplication

        w = self.w
        QApplication.setCursorFlashTime(0)  # a steady text cursor: the probes' pixels
        self.phase("connect")
        yield self.until(lambda: w.session.connected, 300, "the bench to open")
        self.x.click(w.live.raw_view.glw)
        self.x.key("F5")
        yield self.typed()
        yield self.until(lambda: w.live._shown_raw > 10, 60, "frames in the live view")
        psf, dark = twin_psf(w.session, (0.0, 0.0, 60.0))  # the scene's depth
        psf = psf / psf.max() * 1000.0 + dark  # as the camera records it
        path = Path(self.o.work) / "psf.npy"
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, psf.astype(np.float32))
        live = w.live
        yield from self.fill(live.psf, str(path), enter=True)
        yield from self.fill(live.depth.lineEdit(), "")
        yield from self.fill(live.dark, f"{dark:g}")
        yield from self.choose(live.method, "admm")
        live.iterations.setValue(5)
        yield from self.click(live.recon_button)
        yield self.until(lambda: live.live is not None or live.error.text(), 300,
                         "the live reconstruction")
        if live.live is None:
            raise StepFailed(f"live reconstruction: {live.error.text()}")
        # on a loaded machine its process (nice +10) may take many minutes for its
        # first ten: it fails only when none comes for STALL_S; with --admm-start-s the
        # soak starts after that long however many there are (counted in the report)
        started = progressing(lambda: live.live.stats()["reconstructed"], 10, STALL_S)
        give_up = time.monotonic() + (getattr(self.o, "admm_start_s", None) or float("inf"))
        yield self.until(lambda: time.monotonic() > give_up or started(), float("inf"),
                         "ADMM reconstructions")
        yield SETTLE_S
        self.done("live ADMM started")
        yield from self.aim(live.dark)
        probe = {"pid": os.getpid(),
                 "key_field": _rect(live.dark), "click_box": _rect(live.method)}
        Path(self.o.probe).write_text(json.dumps(probe))
        self.phase("soak")
        start = {"frames": w.session.frames_seen, **live.live.stats(),
                 "view": _view_counts(live)}
        t_end = soak_end(self.t0, time.monotonic(), self.o.minutes,
                         getattr(self.o, "soak_minutes", None))
        while time.monotonic() < t_end:
            yield 5.0
        end = live.live.stats()
        self.notes["live"] = {
            "start": start, "end": end,
            "frames_shown": w.session.frames_seen - start["frames"],
            "reconstructed": end["reconstructed"] - start["reconstructed"],
            "skipped": end["skipped"] - start["skipped"],
            "errors": end["errors"] - start["errors"], "last_error": end["last_error"],
            "latency": live.live.latency_summary(),
            "view_start": start["view"], "view_end": _view_counts(live),
            "child": getattr(live.live, "child_info", None), "gui_pid": os.getpid(),
            "in_process": type(live.live).__name__}
        self.done("soak")
        self.phase("end")
        Path(self.o.probe).write_text(json.dumps({"done": True}))
        self._finish()


def progressing(count: Callable[[], int], target: int, stall_s: float,
                clock: Callable[[], float] = time.monotonic) -> Callable[[], bool]:
    """A condition to wait on: true once ``count()`` exceeds ``target``; it raises
    :class:`~soak.operator_day.StepFailed` when ``count()`` has not grown for
    ``stall_s`` (a hang guard that a slow, loaded machine still passes).

    Parameters
    ----------
    count : callable
        ``count() -> int``, non-decreasing.
    target : int
    stall_s : float
        Seconds without growth after which the wait fails.
    clock : callable
        Seconds, monotonic.
    """
    seen = {"n": None, "at": clock()}

    def condition() -> bool:
        n = count()
        if n > target:
            return True
        now = clock()
        if n != seen["n"]:
            seen["n"], seen["at"] = n, now
        elif now - seen["at"] > stall_s:
            raise StepFailed(f"no progress for {stall_s:g} s (at {n} of more than "
                             f"{target})")
        return False

    return condition


def soak_end(t0: float, soak_start: float, minutes: float,
             soak_minutes: float | None) -> float:
    """When the soak ends, on ``t0``'s clock: ``minutes`` after the day's start ``t0``
    or, with ``soak_minutes``, that long after the soak's start (whichever is later),
    so a set-up slowed by a loaded machine does not shorten the soak."""
    end = t0 + 60.0 * minutes
    if soak_minutes is not None:
        end = max(end, soak_start + 60.0 * soak_minutes)
    return end


def _view_counts(live) -> dict:
    """The Live panel's raw frames shown and not shown, and its display pacer's
    interval (None where the window has none)."""
    pacer = getattr(live, "pacer", None)
    return {"shown": getattr(live, "frames_shown", None),
            "not_shown": getattr(live, "frames_not_shown", None),
            "period_s": None if pacer is None else pacer.period_s,
            "ticks_skipped": None if pacer is None else pacer.ticks_skipped}


@contextmanager
def busy_loops(n: int, own_session: bool = True) -> Iterator[list[int]]:
    """``n`` processes spinning a core each at normal priority (``python -c "while True:
    pass"``), ended (killed and reaped) when the block ends; yields their pids.

    With ``own_session`` (default) each is started in a session of its own, as another
    program of the desktop is (a terminal's job, another application): with the
    kernel's automatic process groups (``/proc/sys/kernel/sched_autogroup_enabled``) the
    scheduler then shares the cores between sessions first. Without it they share the
    soak's session with the window, as jobs started by the window's own program would.
    """
    procs: list[subprocess.Popen] = []
    try:
        for _ in range(int(n)):
            procs.append(subprocess.Popen([sys.executable, "-c", "while True: pass"],
                                          start_new_session=bool(own_session)))
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait(30)


def _rect(widget) -> list[int]:
    """``widget``'s rectangle on the screen: x, y, width, height (px)."""
    top_left = widget.mapToGlobal(widget.rect().topLeft())
    return [top_left.x(), top_left.y(), widget.width(), widget.height()]


def inside(argv: list[str]) -> int:
    """The GUI process: ``diffuserlab gui`` with :class:`LiveSoak` on its event loop."""
    p = argparse.ArgumentParser(prog="python -m soak.live_soak inside")
    p.add_argument("--minutes", type=float, required=True)
    p.add_argument("--soak-minutes", type=float, default=None)
    p.add_argument("--admm-start-s", type=float, default=None)
    p.add_argument("--work", required=True)
    p.add_argument("--report", required=True)
    p.add_argument("--probe", required=True)
    args = p.parse_args(argv)
    args.simulate, args.alignment_s = True, 0.0
    start_when_shown(lambda window: LiveSoak(window, args))
    from instrument.cli import main as diffuserlab

    return diffuserlab(["gui", "--scene", "beads-flow", "--simulate"])


class ScreenProbe:
    """Times, from outside the GUI process, how long a key or a click takes to show.

    Parameters
    ----------
    display : str
        The X display (``:N``). Run it in a process of its own (Qt ends a process
        whose X connection breaks, as when the display is stopped).

    Raises
    ------
    FileNotFoundError
        xdotool is not installed.
    """

    def __init__(self, display: str) -> None:
        import shutil

        os.environ["DISPLAY"] = display
        os.environ["QT_QPA_PLATFORM"] = "xcb"
        from PySide6.QtGui import QGuiApplication

        self.app = QGuiApplication.instance() or QGuiApplication(["probe"])
        self.screen = QGuiApplication.primaryScreen()
        self.xdotool = shutil.which("xdotool")
        if self.xdotool is None:
            raise FileNotFoundError(2, "xdotool is not installed (scripts/system-deps.sh)",
                                    "xdotool")

    def grab(self, rect) -> bytes:
        """The pixels of ``rect`` (x, y, width, height) as the X server holds them."""
        x, y, w, h = rect
        image = self.screen.grabWindow(0, x, y, w, h).toImage()
        return bytes(image.constBits())

    def xdo(self, *args: str) -> None:
        subprocess.run([self.xdotool, *args], check=True, timeout=10)

    def timed(self, rect, *args: str, timeout_s: float = 5.0) -> float:
        """Send ``xdotool args`` and return the seconds until ``rect``'s pixels change
        (``inf`` if they did not within ``timeout_s``)."""
        before = self.grab(rect)
        t0 = time.perf_counter()
        subprocess.Popen([self.xdotool, *args])  # the send time counts, as an operator's
        while time.perf_counter() - t0 < timeout_s:
            if self.grab(rect) != before:
                return time.perf_counter() - t0
            time.sleep(0.002)
        return float("inf")

    def probe(self, target: dict) -> dict:
        """One key probe (a character typed, then BackSpace) and one click probe (the
        method box opened, then Esc); delays in ms."""
        fx, fy, fw, fh = target["key_field"]
        self.xdo("mousemove", str(fx + fw - 6), str(fy + fh // 2), "click", "1")
        time.sleep(0.5)  # the focus moved in; its frame repainted
        out = {"key_ms": 1e3 * self.timed(target["key_field"], "key", "x")}
        time.sleep(0.3)
        out["backspace_ms"] = 1e3 * self.timed(target["key_field"], "key", "BackSpace")
        time.sleep(0.3)
        bx, by, bw, bh = target["click_box"]
        self.xdo("mousemove", str(bx + bw // 2), str(by + bh // 2))
        time.sleep(0.3)  # the hover highlight
        out["click_ms"] = 1e3 * self.timed(target["click_box"], "click", "1")
        time.sleep(0.3)
        out["escape_ms"] = 1e3 * self.timed(target["click_box"], "key", "Escape")
        out["load_1min"] = os.getloadavg()[0]
        return out


def probe_main(argv: list[str]) -> int:
    """The probing process: waits for the window's targets, then every ``--every`` s a
    round of :meth:`ScreenProbe.probe`, each a JSON line of ``--out`` (with its start
    and end times), until the window says it is done."""
    p = argparse.ArgumentParser(prog="python -m soak.live_soak probe")
    p.add_argument("--target", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--every", type=float, required=True)
    args = p.parse_args(argv)
    target_path = Path(args.target)
    screen = ScreenProbe(os.environ["DISPLAY"])
    with open(args.out, "a") as out:
        while True:
            if not target_path.exists():
                time.sleep(1.0)
                continue
            target = json.loads(target_path.read_text())
            if target.get("done"):
                return 0
            start = time.time()
            probe = screen.probe(target)
            if json.loads(target_path.read_text()).get("done"):
                return 0  # the window was closing: not a measurement of it
            out.write(json.dumps({"start_time": start, "end_time": time.time(), **{
                k: (None if v == float("inf") else v) for k, v in probe.items()}}) + "\n")
            out.flush()
            time.sleep(args.every)


def run_live_soak(minutes: float = 60.0, probe_s: float = 30.0,
                  work: str | None = None, busy: int = 0,
                  busy_own_session: bool = True,
                  soak_minutes: float | None = None,
                  admm_start_s: float | None = None) -> dict:
    """Run the soak (module docstring); returns the report and its figures.

    Parameters
    ----------
    minutes : float
        Length of the GUI's day (the soak is what follows the set-up, about a minute).
    probe_s : float
        Seconds between two rounds of probes.
    work : str, optional
        Folder for the report, the PSF and the GUI's log (default a temporary one).
    busy : int
        Busy loops beside the window from the soak's start, once the live ADMM runs
        (:func:`busy_loops`).
    busy_own_session : bool
        Each busy loop in a session of its own (default), or in the window's.
    soak_minutes : float, optional
        The soak lasts at least this long from its start, however long the set-up
        took (:func:`soak_end`).
    admm_start_s : float, optional
        Start the soak after this long of live ADMM even if it has not made its first
        ten reconstructions (on a loaded machine its process at nice +10 may make none
        for minutes); default: wait for them (failing after :data:`STALL_S` without one).
    """
    from .soak import peer_env, x_display

    work_dir = Path(work or tempfile.mkdtemp(prefix="live-soak-"))
    work_dir.mkdir(parents=True, exist_ok=True)
    report_path, probe_path = work_dir / "report.json", work_dir / "probe.json"
    root = Path(__file__).resolve().parents[1]  # the checkout (soak is not installed)
    env = {**os.environ, "QT_QPA_PLATFORM": "xcb",
           "DIFFUSERLAB_GUI_SETTINGS": str(work_dir / "gui.ini"),
           "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "soak.live_soak", "inside", "--minutes",
           str(minutes), "--work", str(work_dir / "runs"), "--report", str(report_path),
           "--probe", str(probe_path)]
    if soak_minutes is not None:
        cmd += ["--soak-minutes", str(soak_minutes)]
    if admm_start_s is not None:
        cmd += ["--admm-start-s", str(admm_start_s)]
    probes_path = work_dir / "probes.jsonl"
    t0 = time.time()
    with x_display() as (display, wm), ExitStack() as beside:
        env["DISPLAY"] = display
        env.update(peer_env(display))
        with open(work_dir / "gui-stderr.log", "w") as err, \
                open(work_dir / "probe-stderr.log", "w") as probe_err:
            proc = subprocess.Popen(cmd, env=env, cwd=work_dir, stdout=subprocess.DEVNULL,
                                    stderr=err)
            # the probe is a process of its own: a display connection of ours would
            # outlive the X server (Qt ends a process whose X connection breaks)
            prober = subprocess.Popen(
                [sys.executable, "-m", "soak.live_soak", "probe", "--target",
                 str(probe_path), "--out", str(probes_path), "--every", str(probe_s)],
                env=env, cwd=work_dir, stdout=subprocess.DEVNULL, stderr=probe_err)
            try:
                if busy:  # from the soak's start (the window wrote the probes' targets)
                    while proc.poll() is None and not probe_path.exists():
                        time.sleep(0.5)
                    beside.enter_context(busy_loops(busy, busy_own_session))
                # the set-up's own guard (STALL_S without progress) ends a stuck one
                rc = proc.wait(60.0 * (minutes + (soak_minutes or 0.0)) + 7200)
            except BaseException:
                proc.kill()
                proc.wait()
                raise
            finally:
                ended = time.time()
                prober.terminate()
                prober.wait(30)
    probes = []
    if probes_path.exists():  # rounds that met the window closing are not the window's
        probes = [p for p in map(json.loads, probes_path.read_text().splitlines())
                  if p.pop("end_time") < ended]
    for p in probes:
        p["t_s"] = p.pop("start_time") - t0
    loads = [p["load_1min"] for p in probes]
    report = json.loads(report_path.read_text()) if report_path.exists() else {
        "failure": "no report written (the GUI process ended first)"}
    stderr = (work_dir / "gui-stderr.log").read_text(errors="replace")
    report.update(returncode=rc, window_manager=wm, probes=probes, work=str(work_dir),
                  busy_processes=int(busy), busy_own_session=bool(busy_own_session),
                  crashed=rc != 0 or "Fatal Python error" in stderr,
                  stderr_tail=stderr[-3000:], load_1min=loads,
                  probe_stderr_tail=(work_dir / "probe-stderr.log").read_text(
                      errors="replace")[-2000:])
    report["figures"] = figures(report)
    return report


def figures(report: dict) -> dict:
    """The soak's figures against :data:`GOALS`."""
    soak = report.get("phases", {}).get("soak", {})
    probes = report.get("probes", [])
    out: dict = {"soak_s": soak.get("seconds"), "firings": soak.get("firings"),
                 "p50_ms": soak.get("p50_ms"), "p99_ms": soak.get("p99_ms"),
                 "max_ms": soak.get("max_ms"), "probe_rounds": len(probes)}
    for kind in ("key_ms", "backspace_ms", "click_ms", "escape_ms"):
        # None: not seen within the probe's timeout (JSON has no infinity)
        ms = np.array([np.inf if p[kind] is None else p[kind] for p in probes], float)
        out[kind] = None if not ms.size else {
            "p50": float(np.percentile(ms, 50, method="nearest")),
            "p99": float(np.percentile(ms, 99, method="nearest")),
            "max": float(ms.max()), "over_100": int((ms > GOALS["visible_ms"]).sum())}
    load = [p["load_1min"] for p in probes]
    out["load_1min"] = None if not load else {"min": min(load), "median": float(
        np.median(load)), "max": max(load)}
    out["live"] = report.get("notes", {}).get("live")
    out["stalls"] = len([s for s in report.get("stalls", []) if s.get("phase") == "soak"])
    visible = [out[k]["max"] for k in ("key_ms", "backspace_ms", "click_ms", "escape_ms")
               if out[k]]
    out["busy_processes"] = int(report.get("busy_processes", 0) or 0)
    no_crash = not report.get("crashed") and not report.get("failure")
    if out["busy_processes"]:  # beside busy loops: the stall goal only
        out["goals_met"] = {"max_ms_beside_busy": soak.get("max_ms") is not None
                            and soak["max_ms"] < GOALS["busy_max_ms"], "no_crash": no_crash}
        return out
    out["goals_met"] = {
        "max_ms": soak.get("max_ms") is not None and soak["max_ms"] < GOALS["max_ms"],
        "p99_ms": soak.get("p99_ms") is not None and soak["p99_ms"] < GOALS["p99_ms"],
        "visible_ms": bool(visible) and max(visible) < GOALS["visible_ms"],
        "load": bool(load) and max(load) <= GOALS["load"], "no_crash": no_crash}
    return out


def print_figures(f: dict) -> None:
    """The figures as text."""
    if f["p99_ms"] is None:  # the soak never started (the failure says why)
        print("soak: not measured")
        print("  goals: " + ", ".join(f"{k} {'met' if v else 'NOT met'}"
                                      for k, v in f["goals_met"].items()))
        return
    print(f"soak: {f['soak_s']} s of live ADMM, {f['firings']} timer firings; GUI thread "
          f"lateness p50 {f['p50_ms']:.1f} ms, p99 {f['p99_ms']:.1f} ms (goal < 50), max "
          f"{f['max_ms']:.1f} ms (goal < 250); {f['stalls']} stalls over 100 ms")
    for kind in ("key_ms", "backspace_ms", "click_ms", "escape_ms"):
        d = f[kind]
        if d:
            print(f"  {kind[:-3]:<9} visible after p50 {d['p50']:.1f} ms, p99 {d['p99']:.1f} "
                  f"ms, max {d['max']:.1f} ms; {d['over_100']} of {f['probe_rounds']} over "
                  "100 ms")
    if f["load_1min"]:
        ld = f["load_1min"]
        print(f"  load average (1 min) at the probes: {ld['min']:.2f}-{ld['max']:.2f} "
              f"(median {ld['median']:.2f})")
    if f.get("busy_processes"):
        print(f"  beside {f['busy_processes']} busy loops (goal: max lateness < "
              f"{GOALS['busy_max_ms']:.0f} ms)")
    live = f["live"] or {}
    if live:
        lat = live["latency"]["median_s"]
        print(f"  live ADMM ({live['in_process']}): {live['reconstructed']} reconstructed, "
              f"{live['skipped']} skipped, {live['errors']} errors; latency median "
              f"{'-' if lat is None else f'{1e3 * lat:.0f}'} ms; {live['frames_shown']} "
              "camera frames")
        v0, v1 = live.get("view_start") or {}, live.get("view_end") or {}
        if v1.get("shown") is not None:
            print(f"  live view: {v1['shown'] - v0['shown']} raw frames shown, "
                  f"{v1['not_shown'] - v0['not_shown']} not shown; display interval at the "
                  f"end {1e3 * v1['period_s']:.0f} ms")
    print("  goals: " + ", ".join(f"{k} {'met' if v else 'NOT met'}"
                                  for k, v in f["goals_met"].items()))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["inside"]:
        return inside(argv[1:])
    if argv[:1] == ["probe"]:
        return probe_main(argv[1:])
    p = argparse.ArgumentParser(prog="python -m soak.live_soak",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=60.0, help="length of the day")
    p.add_argument("--probe-s", type=float, default=30.0, help="seconds between probes")
    p.add_argument("--soak-minutes", type=float, default=None,
                   help="the soak lasts at least this long from its start, however long "
                   "the set-up took on a loaded machine")
    p.add_argument("--admm-start-s", type=float, default=None,
                   help="start the soak after this long of live ADMM even without its "
                   "first ten reconstructions (a loaded machine; counted in the report)")
    p.add_argument("--work", default=None, help="folder for the report and the GUI's log")
    p.add_argument("--busy", type=int, default=0,
                   help="busy loops beside the window (normal priority; ended after)")
    p.add_argument("--busy-in-session", action="store_true",
                   help="start the busy loops in the window's session (default: each in a "
                   "session of its own, as other programs are)")
    p.add_argument("--json", default=None, help="also write the report and figures here")
    args = p.parse_args(argv)
    report = run_live_soak(args.minutes, args.probe_s, args.work, args.busy,
                           not args.busy_in_session, args.soak_minutes, args.admm_start_s)
    print_figures(report["figures"])
    if report.get("failure"):
        print(f"  failure: {report['failure']}")
    if args.json:
        from instrument.atomic import write_json

        write_json(args.json, report, default=str)
    return 0 if all(report["figures"]["goals_met"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
