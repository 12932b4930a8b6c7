"""What every fault-table test of the ``diffuserlab`` commands shares.

:func:`tree` fingerprints a directory (sha256 of every file), :func:`run_cli` runs a
command in-process and captures its status and output, :func:`assert_refused`
checks the contract of a refused command line: exit status 2, exactly one line on
stderr starting ``diffuserlab: error:`` that names the problem, no traceback, and
the directory unchanged (no file changed, nothing added or removed). Used by ``tests/faults`` and
``tests/instrument/cli/test_output_safety.py``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from pathlib import Path

from instrument.cli import main

__all__ = ["assert_one_error_line", "assert_refused", "run_cli", "tree"]


def tree(root: Path) -> dict[str, str]:
    """{relative path: sha256 hex of a file, ``"dir"`` for a directory} under ``root``.

    Two trees compare equal when no file changed and no file or directory appeared
    or vanished (an empty folder left by a refused command counts).
    """
    return {str(p.relative_to(root)):
            "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if not p.is_symlink()}


def run_cli(argv: Sequence[object], capsys) -> tuple[int, str, str]:
    """Run ``diffuserlab ARGV`` in-process; (exit status, stdout, stderr).

    Items of ``argv`` are turned into strings (paths may be given as Path). An
    argparse refusal (SystemExit) gives its exit code, as the console script would.
    """
    capsys.readouterr()
    try:
        status = main([str(a) for a in argv])
    except SystemExit as exc:
        status = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_error_line(err: str, words: Iterable[str]) -> None:
    """``err`` is one non-empty line ``diffuserlab: error: ...`` holding each of ``words``
    (case-insensitive), and no traceback."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{err}"
    assert lines[0].startswith("diffuserlab: error: "), err
    for word in words:
        assert word.lower() in lines[0].lower(), f"{word!r} not in: {lines[0]}"


def assert_refused(argv: Sequence[object], words: Iterable[str], root: Path, capsys,
                   status: int = 2) -> str:
    """Run ``argv`` and check the refusal contract; returns the error line.

    Parameters
    ----------
    argv : sequence
        The command line without the program name.
    words : iterable of str
        What the error line must mention (case-insensitive substrings).
    root : Path
        The directory that must be unchanged (sha256 of every file before and after,
        no file or directory added or removed).
    capsys : pytest.CaptureFixture
    status : int
        The expected exit status (2: bad input).
    """
    before = tree(root)
    code, _, err = run_cli(argv, capsys)
    assert code == status, f"exit {code}, expected {status}; stderr:\n{err}"
    assert_one_error_line(err, words)
    assert tree(root) == before, "the command changed files under the test directory"
    return err.strip()
