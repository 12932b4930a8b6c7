"""Responsiveness benchmark of the GUI: the Qt event loop's latency under load.

``python -m soak.benchmark [--seconds 20] [--method admm:5] [--json OUT.json]``
(``python -m soak.benchmark soak [--minutes 60] [--emulated]``: the operator's day in a
real window, :mod:`soak.soak`)

Measures how late a 10 ms timer fires on the GUI thread (its lateness: the interval
between two firings minus 10 ms), first with the window idle (the reference), then
while, in the same process,

* the main window's live view streams the real-time virtual bench (beads flowing in a
  channel) and shows every 20 Hz refresh the newest raw frame, its histogram and
  saturation overlay, beside the live reconstruction (Wiener, or warm-started ADMM
  with a few iterations per frame, on a worker thread) of the newest frame, and
* a calibration panel runs a PSF sweep (:class:`calibration_routines.psf_sweep.PsfSweepPlan`
  through :class:`instrument.acquisition.runner.Runner` on a worker, every frame shown as it is
  taken) on a second virtual bench: one camera cannot stream and snap at once, so
  the sweep has its own simulated camera, as a second camera of the same bench would.

Prints the lateness percentiles (50, 99, max) of the idle window, the live view
alone and the live view with the sweep, the GUI thread's CPU time in each (% of a
core), the loaded-to-idle ratio, the camera's and the reconstruction's rates and the
sweep's progress. Goal: 99th percentile under 50 ms while loaded. Runs on the
offscreen platform unless ``QT_QPA_PLATFORM`` says otherwise (an X display under Xvfb
renders the same way).

``--large-frame 2048x2448`` adds a phase for a camera larger than the simulated one
(:func:`large_frame_lateness`): an image view as the live view's raw frame, in a
700 x 560 px window, showing a new frame of that size 20 times a second; it prints
the lateness and the GUI thread's CPU time per frame shown.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gui.workers import wait_until

from .device_jobs import twin_psf

__all__ = ["large_frame_lateness", "measure_lateness", "run_benchmark"]

TIMER_MS = 10


#: The longest a phase waits past its ``seconds`` for what it waits on (``until``).
HANG_S = 120.0


def measure_lateness(app, seconds: float,
                     until: Callable[[int], bool] | None = None) -> np.ndarray:
    """Lateness (s) of every firing of a 10 ms precise timer over ``seconds``, while the
    event loop runs everything else that is going on.

    Parameters
    ----------
    app : QApplication
    seconds : float
        The phase's length, at least.
    until : callable, optional
        ``until(firings)``: the phase goes on past ``seconds`` until it is true (at most
        :data:`HANG_S` more): on a loaded machine the GUI thread may not run the timer
        at all in a short phase.

    Returns
    -------
    ndarray, float64, (firings - 1,)
        Each interval's lateness, s (empty with fewer than two firings).
    """
    from PySide6.QtCore import QElapsedTimer, QEventLoop, Qt, QTimer

    clock = QElapsedTimer()
    stamps: list[int] = []
    timer = QTimer()
    timer.setTimerType(Qt.TimerType.PreciseTimer)
    timer.setInterval(TIMER_MS)
    loop = QEventLoop()
    end_ns = int(seconds * 1e9)

    def fired() -> None:
        stamps.append(clock.nsecsElapsed())
        if stamps[-1] >= end_ns and (until is None or until(len(stamps))):
            loop.quit()

    timer.timeout.connect(fired)
    QTimer.singleShot(int((seconds + (HANG_S if until is not None else 0.0)) * 1000) + 50,
                      loop.quit)
    clock.start()
    timer.start()
    loop.exec()
    timer.stop()
    intervals = np.diff(np.asarray(stamps, np.float64)) / 1e9
    return np.maximum(intervals - TIMER_MS / 1000.0, 0.0)


def _summary(lateness: np.ndarray, cpu_s: float | None = None,
             seconds: float | None = None) -> dict:
    ms = 1e3 * lateness
    if not ms.size:  # the timer did not fire twice: nothing to measure, said so
        out = {"firings": 0, "p50_ms": None, "p99_ms": None, "max_ms": None,
               "sample": "no sample: the timer fired fewer than twice (the GUI thread "
                         "did not run it; a machine too busy, or a phase too short)"}
    else:
        out = {"firings": int(ms.size), "p50_ms": float(np.percentile(ms, 50)),
               "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max())}
    if cpu_s is not None:
        out["gui_thread_cpu_pct"] = 100.0 * cpu_s / seconds
    return out


def _phase(app, seconds: float, until: Callable[[int], bool] | None = None) -> dict:
    """:func:`measure_lateness`'s summary and the GUI thread's CPU time meanwhile."""
    t0, cpu0 = time.monotonic(), time.thread_time()
    lateness = measure_lateness(app, seconds, until)
    return _summary(lateness, time.thread_time() - cpu0, time.monotonic() - t0)


def large_frame_lateness(shape: tuple[int, int], seconds: float = 20.0,
                         hz: float = 20.0) -> dict:
    """Lateness of the GUI thread while an image view shows ``shape`` frames.

    A :class:`gui.imageview.FrameView` as the live view's raw frame (levels and
    histogram twice a second) in a 700 x 560 px window is handed a new uint16 frame
    (12-bit noise over a gradient, none saturated; four precomputed frames in turn)
    ``hz`` times a second for ``seconds`` while :func:`measure_lateness` runs.

    Returns
    -------
    dict
        The lateness summary (``firings``, ``p50_ms``, ``p99_ms``, ``max_ms``,
        ``gui_thread_cpu_pct``), ``frames_shown``, ``cpu_ms_per_frame`` (the GUI
        thread's CPU time, painting included, per frame shown) and ``shape``.
    """
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QApplication

    from gui.app import configure
    from gui.imageview import FrameView

    app = QApplication.instance() or QApplication(sys.argv[:1])
    configure()
    rows, cols = shape
    rng = np.random.default_rng(0)
    ramp = np.add.outer(np.linspace(0, 2000, rows), np.linspace(0, 1000, cols))
    frames = [(ramp + rng.integers(0, 1000, shape)).astype(np.uint16) for _ in range(4)]
    view = FrameView("raw frame (DN)", histogram_hz=2.0, name="raw")
    view.resize(700, 560)
    view.show()
    shown = [0]

    def show() -> None:
        view.setImage(frames[shown[0] % len(frames)], autoLevels=True)
        shown[0] += 1

    timer = QTimer()
    timer.timeout.connect(show)
    timer.start(int(1000 / hz))
    try:
        wait_until(app, lambda: shown[0] >= 5, 60, "the first frames")
        first = shown[0]
        # at least two firings and one frame shown within the phase, however loaded
        out = _phase(app, seconds, lambda firings: firings >= 3 and shown[0] > first)
    finally:
        timer.stop()
        view.deleteLater()
    out["frames_shown"] = shown[0] - first
    out["cpu_ms_per_frame"] = (10.0 * out["gui_thread_cpu_pct"] * seconds
                               / max(out["frames_shown"], 1))
    out["shape"] = [rows, cols]
    return out


def run_benchmark(seconds: float = 20.0, method: str = "wiener", iterations: int = 5,
                  workdir: str | None = None) -> dict:
    """Run the three phases (see the module docstring); returns the figures.

    Parameters
    ----------
    seconds : float
        Length of each measurement, s.
    method, iterations
        The live reconstruction's method (``"wiener"`` or ``"admm"``) and ADMM
        iterations per frame.
    workdir : str, optional
        Where the PSF and the sweep's run store go (default a temporary folder).
    """
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    from gui.app import MainWindow, configure
    from gui.panels.calibration import CalibrationPanel
    from gui.session import Session

    app = QApplication.instance() or QApplication(sys.argv[:1])
    configure()
    work = Path(workdir or tempfile.mkdtemp(prefix="gui-benchmark-"))
    window = MainWindow(Session(None, simulate=True, scene="beads-flow"))
    window.show()
    sweep_session = Session(None, simulate=True, seed=1, scene="none")
    sweep_panel = CalibrationPanel(sweep_session)
    sweep_panel.resize(900, 600)
    sweep_panel.show()
    try:
        window.session.connect_bench()
        sweep_session.connect_bench()
        wait_until(app, lambda: window.session.connected and sweep_session.connected, 300,
              "the benches to open (the moving scene is rendered ahead)")
        idle = _phase(app, seconds)
        psf, dark = twin_psf(window.session, (0.0, 0.0, 60.0))
        psf = (1000.0 * psf / psf.max() + dark).astype(np.float32)  # 1000 DN at its peak
        np.save(work / "psf.npy", psf)
        live = window.live
        live.psf.setText(str(work / "psf.npy"))
        live.dark.setText(f"{dark:g}")
        live.method.setCurrentText(method)
        live.iterations.setValue(iterations)
        job = live.start_reconstruction()
        wait_until(app, lambda: job.done, 120, "the live reconstruction to build")
        if live.live is None:
            raise RuntimeError(f"live reconstruction: {live.error.text()}")
        wait_until(app, lambda: live._shown_recon >= 0, 180, "the first reconstruction")
        live_only = _phase(app, seconds)
        axes = sweep_session.devices["source_stage"].axes
        sweep_session.service.apply_settings("source_stage",
                                             {"velocity": dict.fromkeys(axes, 50.0)})
        sweep_panel.routine.setCurrentText("psf-sweep")
        fields = sweep_panel.fields["psf-sweep"]
        for flag, value in (("--z-min", "30"), ("--z-max", "200"), ("--n-depths", "64"),
                            ("--frames", "2")):
            fields[flag].setText(value)
        sweep_panel.out.setText(str(work / "sweep.zarr"))
        if sweep_panel.start() is None:
            raise RuntimeError(f"PSF sweep: {sweep_panel.status.text()}")
        wait_until(app, lambda: "frame" in sweep_panel.events, 120, "the sweep's first frame")
        before = (window.session.frames_seen, live.live.stats()["reconstructed"],
                  sweep_panel.progress.value())
        t0 = time.monotonic()
        loaded = _phase(app, seconds)
        span = time.monotonic() - t0
        stats = live.live.stats()
        after = (window.session.frames_seen, stats["reconstructed"], sweep_panel.progress.value())
        sweep_running = bool(sweep_panel.job is not None and sweep_panel.job.running)
        sweep_panel.abort()
        out = {
            "timer_ms": TIMER_MS, "seconds": seconds, "idle": idle,
            "live_only": live_only, "loaded": loaded,
            "camera_fps": (after[0] - before[0]) / span,
            "reconstruction_fps": (after[1] - before[1]) / span,
            "reconstruction": f"{method}" + ("" if method == "wiener" else f" x{iterations}"),
            "reconstruction_latency_median_ms": (None if stats["latency_median_s"] is None
                                                 else 1e3 * stats["latency_median_s"]),
            "reconstruction_skipped": stats["skipped"],
            "sweep_frames_during": after[2] - before[2],
            "sweep_still_running_at_end": sweep_running,
            "frame_shape": list(psf.shape),
        }
        loaded_p99, idle_p99 = out["loaded"]["p99_ms"], out["idle"]["p99_ms"]
        out["p99_ratio_loaded_to_idle"] = (None if loaded_p99 is None or idle_p99 is None
                                           else loaded_p99 / max(idle_p99, 1e-3))
        wait_until(app, lambda: sweep_panel.job is None or sweep_panel.job.done, 60,
              "the sweep to stop")
        return out
    finally:
        sweep_panel.control.abort("benchmark over")
        window.shutdown()
        job = sweep_session.disconnect_bench()
        if job is not None:
            job.wait(10.0)


def _line(label: str, s: dict) -> str:
    if not s["firings"]:
        return f"  {label}: {s['sample']}"
    return (f"  {label}: p50 {s['p50_ms']:6.2f} ms  p99 {s['p99_ms']:6.2f} ms  max "
            f"{s['max_ms']:7.2f} ms  ({s['firings']} firings; GUI thread "
            f"{s['gui_thread_cpu_pct']:.0f} % of a core)")


def soak(argv: list[str]) -> int:
    """``python -m soak.benchmark soak [--minutes 60] [--emulated] [--json OUT]``: the
    operator's day in a real window for ``--minutes`` (:func:`soak.soak.run_day`), its
    figures against the goals (:func:`soak.soak.summarise`)."""
    from .soak import print_summary, run_day, summarise

    p = argparse.ArgumentParser(prog="python -m soak.benchmark soak",
                                description=soak.__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=60.0, help="length of the day")
    p.add_argument("--emulated", action="store_true",
                   help="the emulated bench (real drivers on protocol emulators)")
    p.add_argument("--alignment-s", type=float, default=0.0,
                   help="abort the alignment after this many seconds (default 0: the "
                   "whole alignment)")
    p.add_argument("--display", default=None, help="an X display (default a new Xvfb)")
    p.add_argument("--work", default=None, help="folder for the runs and the report")
    p.add_argument("--json", default=None, help="also write the report and figures here")
    args = p.parse_args(argv)
    report = run_day(emulated=args.emulated, minutes=args.minutes,
                     alignment_s=args.alignment_s, display=args.display, work=args.work)
    figures = summarise(report)
    print_summary(figures, report)
    if args.json:
        from instrument.atomic import write_json

        write_json(args.json, {"figures": figures, "report": report}, default=str)
    return 0 if all(figures["goals_met"].values()) and not figures["failure"] else 1


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["soak"]:
        return soak(argv[1:])
    p = argparse.ArgumentParser(
        prog="python -m soak.benchmark", description=__doc__.split("\n\n")[0],
        epilog="python -m soak.benchmark soak --help: the operator's day in a "
        "real window (60 minutes by default)")
    p.add_argument("--seconds", type=float, default=20.0, help="length of each phase, s")
    p.add_argument("--method", default="wiener", help="wiener or admm:K")
    p.add_argument("--large-frame", default=None, metavar="ROWSxCOLS",
                   help="also a phase of an image view showing frames of this size")
    p.add_argument("--json", default=None, help="also write the figures here")
    args = p.parse_args(argv)
    large = None
    if args.large_frame:
        try:
            large = tuple(int(n) for n in args.large_frame.lower().split("x"))
            if len(large) != 2 or min(large) < 1:
                raise ValueError
        except ValueError:
            p.error(f"--large-frame {args.large_frame!r}: give ROWSxCOLS, e.g. 2048x2448")
    name, _, k = args.method.partition(":")
    res = run_benchmark(args.seconds, name, int(k) if k else 5)
    if large is not None:
        res["large_frame"] = large_frame_lateness(large, args.seconds)
    ld = res["loaded"]
    print(f"Qt event loop lateness of a {TIMER_MS} ms timer ({res['seconds']:g} s each; "
          f"frames {res['frame_shape'][0]}x{res['frame_shape'][1]}; load average "
          f"{os.getloadavg()[0]:.2f}):")
    for label, key in (("idle window     ", "idle"), ("live view only  ", "live_only"),
                       ("live + PSF sweep", "loaded")):
        print(_line(label, res[key]))
    if "large_frame" in res:
        lf = res["large_frame"]
        print(_line(f"{lf['shape'][0]}x{lf['shape'][1]} frames", lf)
              + f"; {lf['cpu_ms_per_frame']:.1f} ms CPU a frame ({lf['frames_shown']} shown)")
    ratio = res["p99_ratio_loaded_to_idle"]
    print(f"  p99 loaded / idle: {'-' if ratio is None else f'{ratio:.1f}x'}; goal p99 < 50 "
          "ms: " + ("no sample" if ld["p99_ms"] is None else
                    "met" if ld["p99_ms"] < 50 else "NOT met"))
    lat = res["reconstruction_latency_median_ms"]
    print(f"  meanwhile: camera {res['camera_fps']:.1f} fps shown, live {res['reconstruction']} "
          f"{res['reconstruction_fps']:.1f} fps (latency {'-' if lat is None else f'{lat:.0f}'} "
          f"ms, {res['reconstruction_skipped']} frames skipped), PSF sweep "
          f"{res['sweep_frames_during']} frames taken "
          f"({'still running' if res['sweep_still_running_at_end'] else 'ended'} at the end)")
    if args.json:
        from instrument.atomic import write_json

        write_json(args.json, res)
    return 0


if __name__ == "__main__":
    from gui.cli import exit_now

    exit_now(main())
