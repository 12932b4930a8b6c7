"""Ctrl-C at named moments of a command's start, made deterministic: one line, 130.

A ``diffuserlab`` console script (as pip writes it, named ``diffuserlab``, so that it
is the command process) is started with a pause at one named moment: an import
(``instrument.cli.startup_signals``: before the signal handlers exist, where Python's
own KeyboardInterrupt lands; ``instrument.cli.recon_run``: a command module loading)
or a call made by the package's module body after its guarded imports
(``logging.getLogger``) or by the command (``startup_signals.is_command_process``:
``main``'s first lines, before its boundary; ``logging.basicConfig``: between
argument parsing and the command;
``instrument.cli.interrupts.terminate_like_ctrl_c``: as the command's error boundary
is entered). The paused process prints ``at NAME`` and waits; the test sends the
signal once that line is read, so the signal lands exactly there, whatever the
machine's load. Every moment must end in one line ``diffuserlab: interrupted (...)``
on stderr, no traceback, exit 128 + the signal, and nothing written (the directory's
files as they were).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from .conftest import REPO
from .helpers import tree

#: The console script with a pause at one moment (``argv[1]``: ``import`` or ``call``,
#: ``argv[2]``: the module or the ``module.function``); everything under the main guard,
#: as pip writes it (worker processes import the main module again)
LAUNCHER = """import sys
import time

if __name__ == "__main__":
    where, name = sys.argv.pop(1), sys.argv.pop(1)

    def pause():
        sys.stdout.write(f"at {name}\\n")
        sys.stdout.flush()
        deadline = time.monotonic() + 600  # a hang guard: the test's signal ends it
        # (raised here, or recorded and held for main: then the command goes on to it)
        handlers = sys.modules.get("instrument.cli.startup_signals")
        while time.monotonic() < deadline and not (handlers and handlers.count()):
            time.sleep(0.01)

    if where == "import":
        class Pause:
            def find_spec(self, fullname, path=None, target=None):
                if fullname == name:
                    sys.meta_path.remove(self)
                    pause()
                return None

        sys.meta_path.insert(0, Pause())
    if where == "module":  # a call of the package's own module body (after its imports)
        import importlib

        module, _, attr = name.rpartition(".")
        owner = importlib.import_module(module)
        original = getattr(owner, attr)

        def paused_in_module(*args, **kwargs):
            caller = sys._getframe(1)
            if (caller.f_code.co_name == "<module>"
                    and caller.f_globals.get("__name__") == "instrument.cli"):
                setattr(owner, attr, original)
                pause()
            return original(*args, **kwargs)

        setattr(owner, attr, paused_in_module)
    from instrument.cli import main

    if where == "call":
        import importlib

        module, _, attr = name.rpartition(".")
        owner = importlib.import_module(module)
        original = getattr(owner, attr)

        def paused(*args, **kwargs):
            pause()
            return original(*args, **kwargs)

        setattr(owner, attr, paused)
    sys.exit(main())
"""

#: (how, name, the line's end: before the command's boundary nothing was done)
MOMENTS = {
    "handlers importing": ("import", "instrument.cli.startup_signals",
                           "while starting; nothing was done"),
    "command modules loading": ("import", "instrument.cli.recon_run",
                                "while starting; nothing was done"),
    # the package's module body after its guarded imports (its 'log = logging.getLogger')
    "package body after its imports": ("module", "logging.getLogger",
                                       "while starting; nothing was done"),
    # main's first lines, before its boundary (its 'mark = ...is_command_process()')
    "main before its boundary": ("call", "instrument.cli.startup_signals.is_command_process",
                                 "while starting; nothing was done"),
    "between parsing and the command": ("call", "logging.basicConfig",
                                        "while starting; nothing was done"),
    "entering the error boundary": ("call", "instrument.cli.interrupts.terminate_like_ctrl_c",
                                    ")"),
}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A directory with a recorded run ``r.zarr`` (4 frames) and a PSF ``psf.npy`` at its
    frame shape: what ``recon-run`` would reconstruct if the signal were lost."""
    from instrument.cli import main
    from instrument.runs.runstore import RunStore

    d = tmp_path_factory.mktemp("early_interrupts")
    assert main(["capture", "video", "--simulate", "--frames", "4", "--out",
                 str(d / "r.zarr")]) == 0
    shape = RunStore.open(d / "r.zarr").frame_shape
    psf = np.full(shape, 64.0, np.float32)
    psf[shape[0] // 2 - 4:shape[0] // 2 + 4, shape[1] // 2 - 4:shape[1] // 2 + 4] = 4000.0
    np.save(d / "psf.npy", psf)
    return d


def _paused(d: Path, how: str, name: str, argv: list[str]) -> subprocess.Popen:
    script = d / "bin" / "diffuserlab"  # the command process (its console script's name)
    script.parent.mkdir(exist_ok=True)
    script.write_text(LAUNCHER)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # SIGINT at its default in the child, as from a terminal (a test run in the
    # background may pass it ignored)
    proc = subprocess.Popen([sys.executable, str(script), how, name, *argv], cwd=d, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    line = proc.stdout.readline()  # the pause, or the end of a process that never got there
    if line != f"at {name}\n":
        proc.kill()
        _, err = proc.communicate(timeout=600)
        pytest.fail(f"the command never reached {name} ({line!r}): {err[-2000:]}")
    return proc


def _assert_one_line(proc: subprocess.Popen, sig: int, end: str) -> None:
    out, err = proc.communicate(timeout=600)
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert proc.returncode == 128 + sig, (proc.returncode, out, err)
    lines = [line for line in err.splitlines() if line.strip()]
    text = "Ctrl-C" if sig == signal.SIGINT else f"stopped by {signal.Signals(sig).name}"
    assert len(lines) == 1 and lines[0].startswith(f"diffuserlab: interrupted ({text})"), err
    assert lines[0].endswith(end), err


#: (moment, signal): SIGINT at each; SIGTERM, handled like Ctrl-C, in the gaps around
#: the command (before its handlers exist a SIGTERM is the system's: the process ends)
CASES = [*[(m, signal.SIGINT) for m in MOMENTS],
         *[(m, signal.SIGTERM) for m in ("package body after its imports",
                                         "main before its boundary",
                                         "between parsing and the command",
                                         "entering the error boundary")]]


@pytest.mark.parametrize("moment, sig", CASES,
                         ids=[f"{m}-{signal.Signals(s).name}" for m, s in CASES])
def test_a_signal_at_each_early_moment_of_recon_run_is_one_line(recorded, moment, sig):
    """Before: a KeyboardInterrupt traceback at the handlers' import, between parsing and
    the command (1 of 20 delays of the sweep) and as the error boundary was entered;
    later, in the package's module body after its guarded imports (a SIGINT 0.05 s
    into capture video under load: 'instrument/cli/__init__.py, in <module>') and in
    main's first lines, where no except was waiting for the interrupt."""
    how, name, end = MOMENTS[moment]
    before = tree(recorded / "r.zarr")
    proc = _paused(recorded, how, name, ["recon-run", "r.zarr", "--psf", "psf.npy",
                                         "--method", "wiener", "--workers", "1"])
    proc.send_signal(sig)
    _assert_one_line(proc, sig, end)
    assert tree(recorded / "r.zarr") == before  # nothing written, no lock left


def test_ctrl_c_while_capture_video_imports_its_handlers_is_one_line(tmp_path):
    """Before: 'a SIGINT 0.05 s into capture video lands in from . import startup_signals'
    and printed a KeyboardInterrupt traceback."""
    proc = _paused(tmp_path, "import", "instrument.cli.startup_signals",
                   ["capture", "video", "--simulate", "--frames", "300", "--out", "v.zarr"])
    proc.send_signal(signal.SIGINT)
    _assert_one_line(proc, signal.SIGINT, "while starting; nothing was done")
    assert not (tmp_path / "v.zarr").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("moment", ["package body after its imports", "main before its boundary"])
def test_a_signal_after_capture_video_imports_its_modules_is_one_line(tmp_path, moment, sig):
    """Before: 'a SIGINT 0.05 s into capture video' (under load) landed in the package's
    module body after its guarded imports, and its KeyboardInterrupt escaped from the
    console script's 'from instrument.cli import main' with a traceback."""
    how, name, end = MOMENTS[moment]
    proc = _paused(tmp_path, how, name,
                   ["capture", "video", "--simulate", "--frames", "300", "--out", "v.zarr"])
    proc.send_signal(sig)
    _assert_one_line(proc, sig, end)
    assert not (tmp_path / "v.zarr").exists()
