"""instrument.atomic.update_file: a file several processes update, edited on a scratch
copy and put in place whole under its lock file."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

import instrument.atomic as atomic


@pytest.fixture
def scratch_root(tmp_path, monkeypatch):
    root = tmp_path / "shm"
    root.mkdir()
    monkeypatch.setattr(atomic, "_scratch_root", lambda: str(root))
    return root


def test_the_edit_works_on_a_copy_and_its_result_replaces_the_file(tmp_path, scratch_root):
    path = tmp_path / "a.ini"
    path.write_text("kept\n")
    seen = []

    def edit(scratch):
        seen.append(scratch)
        assert scratch != path and scratch.read_text() == "kept\n"
        scratch.write_text(scratch.read_text() + "added\n")
        (scratch.parent / f"{scratch.name}.lock").write_text("")  # an editor's own lock

    assert atomic.update_file(path, edit) == path
    assert path.read_text() == "kept\nadded\n"
    assert seen[0].is_relative_to(scratch_root)
    assert list(scratch_root.iterdir()) == []  # scratch copy and its neighbours removed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ini", "a.ini.writer-lock", "shm"]


def test_a_missing_file_is_made_in_a_new_folder(tmp_path, scratch_root):
    path = tmp_path / "new" / "b.ini"

    def edit(scratch):
        assert not scratch.exists()
        scratch.write_text("x=1\n")

    atomic.update_file(path, edit)
    assert path.read_text() == "x=1\n"


@pytest.mark.parametrize("failure", ["raises", "no file"])
def test_a_failed_edit_leaves_the_file_as_it_was(tmp_path, scratch_root, failure):
    path = tmp_path / "c.ini"
    path.write_text("before\n")

    def edit(scratch):
        scratch.write_text("half\n")
        if failure == "raises":
            raise ValueError("editor failed")
        scratch.unlink()

    with pytest.raises(ValueError if failure == "raises" else OSError,
                       match="editor failed" if failure == "raises" else "left no file"):
        atomic.update_file(path, edit)
    assert path.read_text() == "before\n"
    assert list(scratch_root.iterdir()) == []
    assert not list(tmp_path.glob(".c.ini.*"))  # no temporary file left beside it


def test_two_processes_updating_one_file_at_once_lose_nothing(tmp_path):
    """Each of two real processes appends 40 lines, one update each, the two started
    together: every line is there (without the lock, a read-modify-write of one
    process overwrites the other's)."""
    path = tmp_path / "shared.txt"
    script = textwrap.dedent("""
        import sys, time
        from pathlib import Path
        from instrument.atomic import update_file
        who, path, go = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
        while not go.exists():
            time.sleep(0.001)
        for i in range(40):
            def edit(scratch, i=i):
                text = scratch.read_text() if scratch.exists() else ""
                time.sleep(0.002)  # widen the window between the read and the write
                scratch.write_text(text + f"{who}{i}\\n")
            update_file(path, edit)
    """)
    go = tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", script, who, str(path), str(go)])
             for who in "ab"]
    go.write_text("")
    assert [p.wait(timeout=120) for p in procs] == [0, 0]
    lines = path.read_text().split()
    assert sorted(lines) == sorted(f"{w}{i}" for w in "ab" for i in range(40))
