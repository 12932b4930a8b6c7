"""OS and resource errors: exit 2, one error line naming the path or the resource, no
traceback, and outputs whole or not at all (no half file, no ``*.tmp``, no half run).

* Real failing writes, without root: each command runs in a fresh process whose file
  size limit (RLIMIT_FSIZE, SIGXFSZ ignored) is below its output's size, so the
  kernel refuses the write mid-file (EFBIG) wherever it happens - numpy, tifffile,
  OpenCV or zarr's writer threads.
* A full disk's own message (ENOSPC with the free space; numpy's short write, which
  carries no errno), with the writer patched to fail mid-file.
* MemoryError, OverflowError, Ctrl-C while a command starts, a device that cannot be
  opened: each raised for real inside a command.
"""

from __future__ import annotations

import errno
import os
import shlex
import subprocess
import sys

import numpy as np
import pytest

import instrument.cli.recon

from .conftest import REPO
from .helpers import assert_one_error_line, assert_refused, run_cli, tree

#: a child that cannot write a file larger than LIMIT bytes
FSIZE_CHILD = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from numba.core import caching  # JIT code is compiled, never cached: the limit would cut it
caching.Cache.save_overload = lambda self, sig, data: None
from instrument.cli import main
sys.exit(main(sys.argv[2:]))
"""

R = "recon --psf psf.npy --raw raw.tif --method admm --tv 1e-3 --iterations 2 --out o/r"
#: (command, file-size limit in bytes, what the error line must name)
WRITE_FAILS = {
    "recon: the TIFF after the PNG": (R + " --metrics-json o/m.json", 3000, "o/r"),
    "runs export": ("runs export run.zarr --out o/e.tif", 8000, "o/e.tif"),
    "runs import-psf": ("runs import-psf stack.tif --out o/i.zarr", 3000, "o/i.zarr"),
    "calibrate dark: no frame stored": (
        "calibrate dark --simulate --frames 2 --out o/c.zarr", 20000, "o/c.zarr"),
    "capture video: no frame stored": (
        "capture video --simulate --frames 4 --out o/v.zarr", 3000, "o/v.zarr"),
}


def _error_lines(err: str) -> list[str]:
    """stderr without progress bars and log records (a capture logs its devices)."""
    lines = []
    for line in err.replace("\r", "\n").splitlines():
        if not line.strip() or "%|" in line or line.startswith(("INFO ", "WARNING ")):
            continue
        lines.append(line)
    return lines


@pytest.mark.parametrize("name", WRITE_FAILS)
def test_a_write_refused_by_the_system_leaves_nothing_half_written(d, tmp_path, name):
    command, limit, where = WRITE_FAILS[name]
    before = tree(d)
    # no byte code or JIT cache is written by the child: the limit would cut them short
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1",
           "NUMBA_CACHE_DIR": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-c", FSIZE_CHILD, str(limit),
                           *shlex.split(command)], cwd=d, capture_output=True, text=True,
                          timeout=180, env=env)
    assert proc.returncode == 2, proc.stderr
    lines = _error_lines(proc.stderr)
    assert len(lines) == 1, proc.stderr
    assert_one_error_line(lines[0], [where])
    assert "File too large" in lines[0] or "stopped short" in lines[0], lines[0]
    assert tree(d) == before, "a half output or a temporary file was left"


def test_an_alignment_cut_by_the_system_keeps_whole_records(d, tmp_path):
    """``align mask`` whose capture log meets the file-size limit mid-line: exit 2 naming
    the log, the record kept (status failed, every line whole, no ``*.tmp``), inputs
    unchanged. Before: a half JSON line that ``load_alignment`` could not read."""
    from calibration_routines.mask_alignment.record import load_alignment

    before = tree(d)
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1",
           "NUMBA_CACHE_DIR": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-c", FSIZE_CHILD, "5000", "align", "mask",
                           "--simulate", "--out", "o/al.align"], cwd=d, capture_output=True,
                          text=True, timeout=180, env=env)
    assert proc.returncode == 2, proc.stderr
    lines = [x for x in _error_lines(proc.stderr) if not x.startswith("[")]
    assert len(lines) == 1, proc.stderr
    assert_one_error_line(lines[0], ["File too large", "o/al.align/captures.jsonl"])
    after = tree(d)
    assert set(after) - set(before) - {"o"} == {
        "o/al.align", "o/al.align/alignment.json", "o/al.align/captures.jsonl"}
    assert {k: v for k, v in after.items() if k in before} == before
    log = (d / "o" / "al.align" / "captures.jsonl").read_bytes()
    assert 0 < len(log) <= 5000 and log.endswith(b"\n")
    record = load_alignment(d / "o" / "al.align")
    assert record["status"] == "failed" and len(record["captures"]) == log.count(b"\n")


def _failing_imwrite(exc: OSError):
    def imwrite(path, data, **kwargs):
        with open(path, "wb") as fh:
            fh.write(b"II*\x00" + bytes(100))  # half a file, then the disk is full
        raise exc
    return imwrite


FULL = {
    "ENOSPC": (OSError(errno.ENOSPC, "No space left on device"), None,
               ["No space left on device", "free of", "o/e.tif", "write elsewhere"]),
    # numpy's short write carries no errno: the free space tells a full disk ...
    "short write, disk full": (OSError("1966080 requested and 101288 written"), 1000,
                               ["No space left on device", "1.0 kB free", "o/e.tif"]),
    # ... from a file-size limit or a failing disk
    "short write, space free": (OSError("1966080 requested and 101288 written"), 10 ** 12,
                                ["stopped short", "1966080 requested", "o/e.tif"]),
}


@pytest.mark.parametrize("name", FULL)
def test_a_full_disk_names_the_file_and_the_free_space(d, capsys, monkeypatch, name):
    import collections
    import shutil

    import tifffile

    exc, free, words = FULL[name]
    monkeypatch.setattr(tifffile, "imwrite", _failing_imwrite(exc))
    if free is not None:
        usage = collections.namedtuple("usage", "total used free")
        monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 ** 12, 0, free))
    assert_refused(["runs", "export", "run.zarr", "--out", "o/e.tif"], words, d, capsys)


def _raising(make):
    def handler(args):
        make()
    return handler


def _memory():
    np.empty(2 ** 62, np.uint8)  # numpy: "Unable to allocate 4 EiB ..."


def _overflow():
    int(float("inf"))


def _interrupt():
    raise KeyboardInterrupt


#: (what the handler does, words of the one error line)
RAISED = {
    "MemoryError": (_memory, ["out of memory", "Unable to allocate", "GiB of memory"]),
    "OverflowError": (_overflow, ["a number is too large", "infinity"]),
}


@pytest.mark.parametrize("name", RAISED)
def test_resource_errors_are_one_line(d, capsys, monkeypatch, name):
    make, words = RAISED[name]
    monkeypatch.setattr(instrument.cli.recon, "run", _raising(make))
    assert_refused(["recon", "--psf", "psf.npy", "--raw", "raw.tif"], words, d, capsys)


def _interrupted(argv, d, capsys) -> None:
    """Exit 130, one line ``diffuserlab: interrupted (Ctrl-C)``, nothing changed."""
    before = tree(d)
    code, _, err = run_cli(argv, capsys)
    assert code == 130, err
    assert [line for line in err.splitlines() if line.strip()] == [
        "diffuserlab: interrupted (Ctrl-C)"], err
    assert tree(d) == before


def test_a_device_that_cannot_be_opened_is_named(d, capsys):
    """The emulated bench without its emulators: its serial ports do not exist."""
    bench = REPO / "examples" / "bench-emulated.toml"
    line = assert_refused(["calibrate", "dark", bench, "--frames", "2", "--out", "o/c.zarr"],
                          ["cannot open the bench", "opening device"], d, capsys)
    assert "bug" not in line


def test_ctrl_c_while_capture_starts_leaves_no_run(d, capsys, monkeypatch):
    """Ctrl-C after the run store is created, before the recorder holds it."""
    import instrument.acquisition.video

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(instrument.acquisition.video.Recorder, "start", interrupted)
    _interrupted(["capture", "video", "--simulate", "--frames", "4", "--out", "o/v.zarr"], d,
                 capsys)


def test_ctrl_c_in_any_command_is_one_line(d, capsys, monkeypatch):
    monkeypatch.setattr(instrument.cli.recon, "run", _raising(_interrupt))
    _interrupted(["recon", "--psf", "psf.npy", "--raw", "raw.tif"], d, capsys)


def test_emulators_bench_out_cut_by_the_system_leaves_no_file(d, tmp_path):
    """``emulators start --bench-out``: whole or nothing (before: a cut or 0-byte file)."""
    before = tree(d)
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1",
           "NUMBA_CACHE_DIR": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-c", FSIZE_CHILD, "300", "emulators", "start",
                           "--dir", str(tmp_path / "em"), "--bench-out", "o/b.toml",
                           "--duration-s", "0.1"], cwd=d, capture_output=True, text=True,
                          timeout=180, env=env)
    assert proc.returncode == 2, proc.stderr
    lines = _error_lines(proc.stderr)
    assert len(lines) == 1, proc.stderr
    assert_one_error_line(lines[0], ["File too large", "o/b.toml"])
    assert tree(d) == before, "a half bench file or a temporary file was left"


def test_recon3d_zarr_on_a_full_disk_leaves_no_hidden_folder(d, capsys, monkeypatch):
    """zarr writes chunks on threads: those still running when one fails with ENOSPC
    created their folders again after the temporary volume was removed (a hidden
    ``.v.zarr.XXXX.tmp`` left). Here the failing chunk fails at once and the others
    finish 0.5 s later, long after the error has reached the command and past the
    0.1 s that :func:`instrument.atomic.remove_tree` waits for the folder to stay
    gone: the clean-up waits for zarr's writes in flight
    (:func:`instrument.atomic.wait_for_zarr_writes`), not for a fixed time."""
    import asyncio

    from zarr.storage import LocalStore

    write = LocalStore.set

    async def full_disk(self, key, value):
        if key.endswith("c/0/0/0"):
            raise OSError(errno.ENOSPC, "No space left on device")
        if "/c/" in key or key.startswith("c/"):
            await asyncio.sleep(0.5)
        return await write(self, key, value)

    monkeypatch.setattr(LocalStore, "set", full_disk)
    assert_refused(["recon3d", "--psf-stack", "stack.tif", "--raw", "raw.tif", "--method",
                    "fista", "--iterations", "2", "--out", "o/v.zarr"],
                   ["No space left on device", "free", "o/v.zarr"], d, capsys)
    import time

    time.sleep(1.0)  # the late chunk writes have ended: still nothing left
    assert not any(p.name.startswith(".v.zarr") for p in d.rglob("*"))
    assert not (d / "o").exists()
