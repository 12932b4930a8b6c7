"""SIGTERM and SIGHUP are handled like Ctrl-C, and a killed recording keeps its frames.

Real signals sent to a real ``diffuserlab`` process (``python -m instrument.cli``) in
the middle of its work, on the simulated bench (the camera streams at its real
frame rate, so a recording takes wall-clock time):

* a recording, a calibration sweep and a batch reconstruction stopped by SIGTERM or
  SIGHUP end like Ctrl-C: exit 128 + the signal, status stopped (recording) or aborted
  (sweep), the writer lock released, what was stored intact (``runs verify`` exit 0);
* a recording killed outright (SIGKILL) keeps its completed shards: ``runs show``
  offers no resume, ``runs verify`` calls them intact, ``runs export --frames`` and
  ``recon-run`` use them;
* Ctrl-C (SIGINT) at moments while a recording starts (its modules loading, its run
  being created) never prints a traceback and leaves either no run or a stopped one,
  unlocked, with every frame the command says it recorded;
* SIGINT or SIGTERM at fixed delays from 0.05 s after the process has taken its
  signals (through a console script, as installed), and at the progress point where
  ``recon-run`` starts its dask workers: one line, 128 + the signal, no traceback, the
  run unlocked (the full sweep of delays is marked slow).

Every wait is on the command's own progress (a store's frames, a line printed, its
signal handlers in place), never on a clock: a delay counted from the process's start
lands at different moments under load, Python's own start-up among them (the window
docs/data-safety.md leaves to Python). A wait fails at once when the command ends
first, and otherwise only after :data:`HANG_S`.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from instrument.runs.runstore import RunStore

from .conftest import REPO


def _start(argv: list[str], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # SIGINT at its default in the child, as from a terminal: a test run started in the
    # background (nohup, "&" without job control) passes SIGINT ignored, and Python
    # then never raises KeyboardInterrupt
    return subprocess.Popen([sys.executable, "-m", "instrument.cli", *argv], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


#: How long a command may make no progress before a wait calls it a hang (s): not a
#: speed check (beside busy processes a command's start-up alone took minutes); a wait
#: ends as soon as its condition holds.
HANG_S = 600.0


def _wait_for(predicate, what: str, proc: subprocess.Popen) -> None:
    """Wait until ``predicate()``; fail with the command's stderr if it ended first, or
    after :data:`HANG_S`."""
    deadline = time.monotonic() + HANG_S
    while not predicate():
        if proc.poll() is not None:
            _, err = proc.communicate(timeout=HANG_S)
            pytest.fail(f"the command ended (status {proc.returncode}) before {what}: "
                        f"{err[-2000:]}")
        if time.monotonic() > deadline:
            pytest.fail(f"no {what} in {HANG_S:g} s: a hang")
        time.sleep(0.05)


def _takes_its_signals(proc: subprocess.Popen) -> bool:
    """Whether the command process catches SIGINT, SIGTERM and SIGHUP (``SigCgt`` in
    /proc): instrument.cli.startup_signals, its first line of project code, has run;
    before it Python itself is starting, and a signal there is Python's."""
    try:
        status = Path(f"/proc/{proc.pid}/status").read_text()
    except OSError:  # ended
        return False
    caught = int(next(line.split()[1] for line in status.splitlines()
                      if line.startswith("SigCgt:")), 16)
    return all(caught >> (s - 1) & 1 for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP))


needs_proc = pytest.mark.skipif(not Path("/proc/self/status").exists(),
                                reason="a process's signal handlers are read from /proc")


def _done(run: Path) -> int:
    try:
        return int(RunStore.open(run).done().sum())
    except Exception:  # not written yet
        return 0


def _finish(proc: subprocess.Popen) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=HANG_S)
    return proc.returncode, out, err


def _cli(argv, cwd) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "instrument.cli", *map(str, argv)], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=HANG_S)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_recording_stopped_by_a_signal_is_stopped_cut_and_unlocked(tmp_path, sig):
    run = tmp_path / "v.zarr"
    proc = _start(["capture", "video", "--simulate", "--frames", "900", "--shard-frames", "8",
                   "--out", str(run)], tmp_path)
    _wait_for(lambda: _done(run) >= 16, "16 frames stored", proc)
    proc.send_signal(sig)
    code, out, err = _finish(proc)
    assert code == 128 + sig, err
    assert "Traceback" not in err
    store = RunStore.open(run)
    assert store.status == "stopped" and store.lock_owner() is None
    assert 16 <= store.n_frames < 900 and store.done().all()  # cut to what it recorded
    verify = _cli(["runs", "verify", run], tmp_path)
    assert verify.returncode == 0, verify.stdout
    show = _cli(["runs", "show", run], tmp_path).stdout
    assert "resume" not in show


def test_a_sweep_stopped_by_sigterm_is_aborted_safe_and_unlocked(tmp_path):
    run = tmp_path / "s.zarr"
    proc = _start(["calibrate", "psf-sweep", "--simulate", "--frames", "2", "--n-depths", "60",
                   "--out", str(run)], tmp_path)
    _wait_for(lambda: _done(run) >= 6, "6 frames stored", proc)
    proc.send_signal(signal.SIGTERM)
    code, _, err = _finish(proc)
    assert code == 143, err
    assert "Traceback" not in err and "calibrate resume" in err
    store = RunStore.open(run)
    assert store.status == "aborted" and store.lock_owner() is None
    assert not [w for w in store.attrs["warnings"] if "could not make safe" in w]
    assert "SIGTERM" in (store.attrs.get("error") or "")


def test_a_killed_recording_is_exported_and_reconstructed_from_its_frames(tmp_path):
    run = tmp_path / "k.zarr"
    proc = _start(["capture", "video", "--simulate", "--frames", "900", "--shard-frames", "8",
                   "--out", str(run)], tmp_path)
    _wait_for(lambda: _done(run) >= 16, "16 frames stored", proc)
    proc.kill()
    proc.communicate(timeout=HANG_S)
    store = RunStore.open(run)
    kept = int(store.done().sum())
    assert store.status == "recording" and kept >= 16
    show = _cli(["runs", "show", run], tmp_path).stdout
    assert "killed while recording" in show and "resume" not in show
    assert _cli(["runs", "verify", run], tmp_path).returncode == 0
    export = _cli(["runs", "export", run, "--frames", "--out", tmp_path / "k.tif"], tmp_path)
    assert export.returncode == 0, export.stderr
    assert "resume" not in export.stdout + export.stderr
    import tifffile

    assert tifffile.imread(tmp_path / "k.tif").shape[0] == kept
    # the lock a killed process leaves is named; once removed, recon-run takes the frames
    psf = tmp_path / "psf.npy"
    _psf_of(store, psf)
    refused = _cli(["recon-run", run, "--psf", psf], tmp_path)
    assert refused.returncode == 2 and "stale lock" in refused.stderr
    (run / ".lock").unlink()
    batch = _cli(["recon-run", run, "--psf", psf, "--method", "wiener", "--frames", "0:4",
                  "--workers", "1"], tmp_path)
    assert batch.returncode == 0, batch.stderr
    assert RunStore.open(run).product_frames_done("recon_wiener")[:4].all()


def _psf_of(store: RunStore, path: Path) -> None:
    """A PSF of the run's frame shape: the simulated camera's view of a point source."""
    import numpy as np

    from instrument.devices.virtual_bench import VirtualBench

    with VirtualBench(seed=0) as vb:
        h = vb.psf((0.0, 0.0, 30.0))
        offset = vb.camera.dark_offset_dn
    assert h.shape == store.frame_shape
    np.save(path, (h / h.max() * 4000.0 + offset).astype(np.float32))


@needs_proc
@pytest.mark.parametrize("moment", ["modules loading", "run created"])
def test_ctrl_c_while_a_recording_starts_never_prints_a_traceback(tmp_path, moment):
    """Ctrl-C once the command has taken its signals (its modules then load for
    seconds), or once its run's store exists (the run being created, the recorder and
    the camera starting): the signal lands there or at any later moment, and each ends
    the same way."""
    run = tmp_path / "c.zarr"
    proc = _start(["capture", "video", "--simulate", "--frames", "300", "--out", str(run)],
                  tmp_path)
    if moment == "run created":
        _wait_for(lambda: (run / "zarr.json").exists(), "the run's store", proc)
    else:
        _wait_for(lambda: _takes_its_signals(proc), "the command's signal handlers", proc)
    proc.send_signal(signal.SIGINT)
    out = _assert_stopped_in_one_line(proc, signal.SIGINT, run)
    _assert_kept_what_it_recorded(run, out)


def test_a_batch_stopped_by_sigterm_keeps_its_frames_and_its_run_unlocked(tmp_path):
    from instrument.cli import main

    run = tmp_path / "b.zarr"
    assert main(["capture", "video", "--simulate", "--frames", "24", "--out", str(run)]) == 0
    psf = tmp_path / "psf.npy"
    _psf_of(RunStore.open(run), psf)
    proc = _start(["recon-run", str(run), "--psf", str(psf), "--method", "admm", "--tv",
                   "1e-4", "--iterations", "300", "--workers", "1"], tmp_path)

    def some_done() -> bool:
        try:
            return RunStore.open(run).product_frames_done("recon_admm").sum() >= 1
        except Exception:  # the product is not created yet
            return False

    _wait_for(some_done, "a frame reconstructed", proc)
    proc.send_signal(signal.SIGTERM)
    code, out, err = _finish(proc)
    assert code == 143, err
    assert "Traceback" not in err and "run the same command again" in out
    store = RunStore.open(run)
    done = store.product_frames_done("recon_admm")
    assert store.lock_owner() is None and 1 <= done.sum() < 24
    assert _cli(["runs", "verify", run], tmp_path).returncode == 0


#: The console script as pip writes it (the main guard: dask's worker processes import
#: the main module again): signals are sent at fixed delays after the process has taken
#: its signals (:func:`_takes_its_signals`; before, Python itself starts, outside any
#: project code)
LAUNCHER = """import sys
from instrument.cli import main
if __name__ == "__main__":
    sys.exit(main())
"""


#: The console script with a camera ring that swallows every interrupt raised while it
#: waits for a frame, as a library's ``except BaseException`` (or a finalizer) may
SWALLOWING_LAUNCHER = """import sys
from drivers.camera import FrameRing
_take = FrameRing._take
def _take_swallowing(self, timeout_s, latest):
    while True:
        try:
            return _take(self, timeout_s, latest)
        except KeyboardInterrupt:
            pass
FrameRing._take = _take_swallowing
from instrument.cli import main
if __name__ == "__main__":
    sys.exit(main())
"""


def _launch(argv: list[str], cwd: Path, launcher: str = LAUNCHER) -> subprocess.Popen:
    """``diffuserlab ARGV`` through a console script (the process handles its signals
    from its first line of project code), returned once it has taken them."""
    script = cwd / "bin" / "diffuserlab"
    script.parent.mkdir(exist_ok=True)
    script.write_text(launcher)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, str(script), *map(str, argv)], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _wait_for(lambda: _takes_its_signals(proc), "the command's signal handlers", proc)
    return proc


def _assert_stopped_in_one_line(proc: subprocess.Popen, sig: int, run: Path) -> str:
    """Exit 128 + the signal, no traceback, at most one line on stderr (none when the
    command's own stop message is on stdout), the run (if begun) unlocked; returns
    the command's stdout."""
    code, out, err = _finish(proc)
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert code == 128 + sig, (code, out, err)
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()
             and "%|" not in line and not line.startswith(("INFO ", "WARNING "))]
    # the command's own stop line on stdout when the signal stopped a recording or a
    # batch it had begun ("stopped: N frames in RUN (M requested)", "stopped (SIGTERM)")
    own = [line for line in out.splitlines() if line.startswith(("stopped (", "stopped:"))]
    assert len(lines) == 1 or (not lines and own), (out, err)
    assert all(line.startswith("diffuserlab: interrupted (") for line in lines), err
    if run.exists():
        assert not (run / ".lock").exists(), "the run was left locked"
    return out


def _assert_kept_what_it_recorded(run: Path, out: str) -> None:
    """A recording stopped: its run (if begun) is stopped with all its frames stored, as
    many as the command's line "stopped: N frames in RUN" says; without a run, no
    frame was said to be recorded (a signal before the first frame leaves none)."""
    said = re.search(r"^stopped: (\d+) frames in ", out, re.MULTILINE)
    if run.exists():
        store = RunStore.open(run)
        assert store.status == "stopped", (store.status, sorted(p.name for p in run.iterdir()))
        assert store.done().all(), "a frame of the stopped run is missing"
        assert said is not None and store.n_frames == int(said.group(1)), out
    else:
        assert said is None or said.group(1) == "0", out


def _signal_at(argv, tmp_path, sig, delay_s, run):
    proc = _launch(argv, tmp_path)
    time.sleep(delay_s)
    proc.send_signal(sig)
    _assert_stopped_in_one_line(proc, sig, run)


FINALIZER = """import gc, os, signal, sys, time
from instrument.cli import startup_signals
startup_signals.install()
from instrument.cli.interrupts import quiet_shutdown, terminate_like_ctrl_c

class Late:
    def __del__(self):  # the signal's handler runs here, in a finalizer
        os.kill(os.getpid(), int(sys.argv[1]))
        for _ in range(1000):
            pass

quiet_shutdown(debug=sys.argv[2] == "debug")
try:
    with terminate_like_ctrl_c():
        Late()
        gc.collect()
        deadline = time.monotonic() + 60  # the interrupt comes long before: a hang guard
        while time.monotonic() < deadline:
            time.sleep(0.01)
        print("ran on")
except KeyboardInterrupt as exc:
    print("stopped", getattr(exc, "signum", 2))
"""


@pytest.mark.parametrize("debug", ["quiet", "debug"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM],
                         ids=["SIGINT", "SIGTERM"])
def test_an_interrupt_raised_in_a_finalizer_still_stops_the_command(tmp_path, sig, debug):
    """A signal whose handler ran inside a finalizer raised its KeyboardInterrupt there,
    where Python reports it as unraisable and runs on (the likely way a Ctrl-C as a
    recording started was once lost under load: exit 0). The command process raises
    it again in its main thread."""
    script = tmp_path / "bin" / "diffuserlab"  # a command process (is_command_process)
    script.parent.mkdir()
    script.write_text(FINALIZER)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, str(script), str(int(sig)), debug], env=env,
                          capture_output=True, text=True, timeout=HANG_S)
    assert done.stdout.split() == ["stopped", str(int(sig))], (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr


#: The console script with a finalizer (a weakref callback, as importlib's module locks
#: have) that runs as the package imports argparse, its first import after it takes its
#: signals, and sends the signal while it runs: the handler's interrupt is raised where
#: Python can only report it ("Exception ignored in ...") and run on
FINALIZER_AT_START = """import builtins, os, sys, weakref
class Lock:
    pass
def callback(ref):
    os.kill(os.getpid(), int(os.environ["SIGNAL"]))
    for _ in range(10000):  # the handler runs here, in the callback
        pass
held = [Lock()]
ref = weakref.ref(held[0], callback)
_import = builtins.__import__
def importing(name, *args, **kwargs):
    if name == "argparse" and held:
        held.clear()  # the callback runs now
    return _import(name, *args, **kwargs)
builtins.__import__ = importing
from instrument.cli import main
builtins.__import__ = _import
if __name__ == "__main__":
    sys.exit(main())
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupt_lost_in_a_finalizer_while_starting_is_one_line(tmp_path, sig):
    """Before, in CI: SIGTERM while the command imported, its handler run in importlib's
    module-lock callback, printed "Exception ignored ... Traceback" above the one line.
    The interrupt is recorded, and the command stops for it before doing anything."""
    script = tmp_path / "bin" / "diffuserlab"
    script.parent.mkdir()
    script.write_text(FINALIZER_AT_START)
    env = {**os.environ, "PYTHONPATH": str(REPO), "SIGNAL": str(int(sig))}
    done = subprocess.run([sys.executable, str(script), *_VIDEO, tmp_path / "v.zarr"],
                          cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=HANG_S)
    assert done.returncode == 128 + sig, (done.returncode, done.stderr)
    assert done.stderr.splitlines() == [
        f"diffuserlab: interrupted ({'Ctrl-C' if sig == signal.SIGINT else 'stopped by SIGTERM'})"
        " while starting; nothing was done"], done.stderr
    assert not (tmp_path / "v.zarr").exists()


_VIDEO = ["capture", "video", "--simulate", "--frames", "300", "--out"]
_SIGNALS = [signal.SIGINT, signal.SIGTERM]


@needs_proc
@pytest.mark.parametrize("sig", _SIGNALS, ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("delay_s", [0.05, 0.4])
def test_a_signal_while_capture_video_starts_is_one_line(tmp_path, sig, delay_s):
    """Before: SIGTERM in the import window killed the process silently (-15), Ctrl-C
    there printed a traceback."""
    _signal_at([*_VIDEO, tmp_path / "v.zarr"], tmp_path, sig, delay_s, tmp_path / "v.zarr")


@pytest.fixture(scope="module")
def batch_run(tmp_path_factory) -> tuple[Path, Path]:
    from instrument.cli import main

    d = tmp_path_factory.mktemp("batch_signals")
    run = d / "b.zarr"
    assert main(["capture", "video", "--simulate", "--frames", "8", "--out", str(run)]) == 0
    _psf_of(RunStore.open(run), d / "psf.npy")
    return run, d / "psf.npy"


def _recon_run(batch_run, tmp_path) -> tuple[list, Path]:
    import shutil

    run = Path(shutil.copytree(batch_run[0], tmp_path / "b.zarr"))
    return ["recon-run", run, "--psf", batch_run[1], "--method", "admm", "--tv", "1e-4",
            "--iterations", "300", "--workers", "1"], run


@needs_proc
@pytest.mark.parametrize("sig", _SIGNALS, ids=["SIGINT", "SIGTERM"])
def test_a_signal_while_the_batch_starts_its_workers_is_one_line(batch_run, tmp_path, sig):
    """At the progress point where recon-run starts its dask cluster (its first line is
    printed). Before: dask's exit hook closed the half-started cluster with a traceback
    ("AssertionError: Status.init"), or 'internal error (a bug): Nanny failed to start'."""
    argv, run = _recon_run(batch_run, tmp_path)
    proc = _launch(argv, tmp_path)
    assert "local workers" in proc.stdout.readline()
    time.sleep(0.3)
    proc.send_signal(sig)
    _assert_stopped_in_one_line(proc, sig, run)


@needs_proc
@pytest.mark.parametrize("sig", _SIGNALS, ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("after_s", [0.0, 0.3])
def test_a_signal_while_recording_is_one_line(tmp_path, sig, after_s):
    """At the progress point where the recording has begun (its first line printed):
    128 + the signal, the command's own stop line, no traceback, the run stopped and
    unlocked. Before, a test's check read only 'stopped (' and took the recording's
    'stopped: N frames in RUN' for a missing line."""
    run = tmp_path / "v.zarr"
    proc = _launch([*_VIDEO, run], tmp_path)
    _wait_for(lambda: proc.stdout.readline().startswith("recording "),
              "the line 'recording ...'", proc)
    time.sleep(after_s)
    proc.send_signal(sig)
    _assert_kept_what_it_recorded(run, _assert_stopped_in_one_line(proc, sig, run))


@needs_proc
@pytest.mark.parametrize("sig", _SIGNALS, ids=["SIGINT", "SIGTERM"])
def test_a_recording_stops_when_a_library_swallows_the_interrupt(tmp_path, sig):
    """The interrupt raised inside the camera ring's wait and caught there (as a
    library may): the recording still stops at its next frame, 128 + the signal, its
    frames kept. Before, a Ctrl-C lost this way recorded all 300 frames and exited 0
    (once in CI)."""
    run = tmp_path / "v.zarr"
    proc = _launch([*_VIDEO, run], tmp_path, SWALLOWING_LAUNCHER)
    # the first progress line: frames flow, the main thread waits in the ring
    _wait_for(lambda: " fps, " in proc.stdout.readline(), "a progress line", proc)
    proc.send_signal(sig)
    out = _assert_stopped_in_one_line(proc, sig, run)
    _assert_kept_what_it_recorded(run, out)
    assert not re.search(r"^stopped: 300 frames", out, re.MULTILINE), out


#: The sweep's delays after the process has taken its signals (s); each is taken REPEATS times with
#: a seeded jitter of up to 0.25 of the step to the next delay, so the repeats land at
#: different points of the start-up
DELAYS_S = (0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.2, 1.6, 2.0, 2.5, 3.0, 4.0, 6.0)
REPEATS = 3


@needs_proc
@pytest.mark.slow
@pytest.mark.parametrize("sig", _SIGNALS, ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", ["capture video", "recon-run"])
def test_signals_at_fixed_delays_are_always_one_line(batch_run, tmp_path, sig, command):
    """The sweep: a signal at fixed delays from 0.05 s to 6 s after the process has
    taken its signals, each delay several times with a seeded jitter, each in a fresh process; every
    one ends in one line, 128 + the signal, no traceback, the run unlocked (a recording
    stopped, a batch resumable)."""
    import random

    rng = random.Random(int(sig) * 100 + len(command))
    steps = [b - a for a, b in zip(DELAYS_S, DELAYS_S[1:], strict=False)] + [1.0]
    for k, (base, step) in enumerate(zip(DELAYS_S, steps, strict=True)):
        for r in range(REPEATS):
            where = tmp_path / f"{k}-{r}"
            where.mkdir()
            if command == "capture video":
                argv, run = [*_VIDEO, where / "v.zarr"], where / "v.zarr"
            else:
                argv, run = _recon_run(batch_run, where)
            _signal_at(argv, where, sig, base + (rng.random() * 0.25 * step if r else 0.0),
                       run)


def test_an_earlier_signal_does_not_stop_the_next_command_in_process(tmp_path, capsys):
    """In a program that calls ``main`` (the GUI, the tests), a signal handled during one
    command is not taken for an interrupt of the next one's start."""
    from instrument.cli import main, startup_signals

    startup_signals.record(signal.SIGTERM)  # as terminate_like_ctrl_c does
    capsys.readouterr()
    assert main(["runs", "show", str(tmp_path / "missing.zarr")]) == 2
    assert "interrupted" not in capsys.readouterr().err


#: A ``python -m`` module whose command catches a KeyboardInterrupt that ended code run
#: from a string (as one landing in a dataclass's generated ``__init__`` while a
#: command imports its modules) and chooses its status, 130.
CAUGHT_IN_EXEC = """import runpy, sys
import instrument.cli


def interrupted_command():
    try:
        exec("raise KeyboardInterrupt")
    except KeyboardInterrupt:
        return 130


{run}
"""


@pytest.mark.parametrize("run, status", [
    # instrument.cli's __main__ with this command as its main
    ("instrument.cli.main = interrupted_command\n"
     "runpy.run_module('instrument.cli', run_name='__main__')", 130),
    ("sys.exit(interrupted_command())", -signal.SIGINT),  # CPython's behaviour, undone above
], ids=["the command", "plain python -m"])
def test_an_interrupt_caught_in_a_string_exec_does_not_end_python_m_by_sigint(
        tmp_path, run, status):
    """Run B2 beside busy loops: a Ctrl-C while the command started printed its one line
    and exited -2, not 130: CPython's flag of an interrupt that ended a string ``exec``
    outlives the except that caught it, and ``python -m`` then exits by SIGINT.
    ``instrument.cli``'s ``__main__`` clears it (``startup_signals``)."""
    (tmp_path / "caught_in_exec.py").write_text(CAUGHT_IN_EXEC.format(run=run))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    done = subprocess.run([sys.executable, "-m", "caught_in_exec"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=HANG_S)
    assert done.returncode == status, done.stderr
