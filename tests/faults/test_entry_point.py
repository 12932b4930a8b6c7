"""The real entry point (``python -m instrument.cli``, a fresh process) refuses bad
input exactly as the in-process table does: same exit status 2, the same one line
on stderr (no log records of other libraries, no traceback), nothing changed."""

from __future__ import annotations

import shlex
import subprocess
import sys

import pytest

from .helpers import assert_one_error_line, run_cli, tree

CASES = {
    # tifffile logs "invalid page offset" on a truncated stack: without -v that record
    # must not reach the console
    "truncated TIFF stack": ("recon3d --psf-stack trunc_stack.tif --raw raw.tif --out o/v.tif",
                             "trunc_stack.tif"),
    "argparse value": ("recon --psf psf.npy --raw raw.tif --iterations abc", "--iterations"),
    "deleted chunk": ("runs export deleted_chunk.zarr --out o/e.tif", "deleted_chunk.zarr"),
    "locked run": ("calibrate resume locked.zarr --simulate", "locked.zarr"),
}


@pytest.mark.parametrize("name", CASES)
def test_entry_point_matches_in_process(d, capsys, name):
    command, word = CASES[name]
    before = tree(d)
    proc = subprocess.run([sys.executable, "-m", "instrument.cli", *shlex.split(command)],
                          cwd=d, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert_one_error_line(proc.stderr, [word])
    assert tree(d) == before
    status, _, err = run_cli(shlex.split(command), capsys)
    assert status == 2
    assert err.strip() == proc.stderr.strip()


def test_a_saturation_warning_is_one_log_line_once(d):
    """A 12.5 %-saturated raw: reconstructed, and warned once, in one line (no Python
    ``warnings`` source line, no second copy)."""
    proc = subprocess.run([sys.executable, "-m", "instrument.cli", *shlex.split(
        "recon --psf psf.npy --raw sat12.tif --method admm --tv 1e-3 --iterations 2 "
        "--out o/s")], cwd=d, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "at full scale" in lines[0], proc.stderr
    assert lines[0].startswith("WARNING ") and "warn(" not in proc.stderr
