"""The bench process's connection file: where a notebook finds the bench and its key.

As a Jupyter kernel does, the bench process writes a small JSON file in a per-user
runtime directory when it starts serving: its ``address`` (the local socket), its
``authkey`` (hex) and its ``pid``, with what it serves (``bench``: the bench file, or
``simulated``) and when it started (``started_utc``). The file is made with mode 0600
in a directory of mode 0700: the key lets anyone who reads it drive the devices. The
bench process removes it when it ends; a file left by a process that was killed is
passed over (its pid no longer runs) and removed when the next bench process writes
its own.

:meth:`instrument.bench.bench_process.BenchClient.connect` reads the newest live one (or the
file named), so a notebook attaches with no address to copy::

    from instrument.bench.bench_process import BenchClient
    bench = BenchClient.connect()

The directory is ``$DIFFUSERLAB_RUNTIME_DIR`` if set, else
``$XDG_RUNTIME_DIR/diffuserlab``, else ``~/.local/share/diffuserlab/runtime``.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Any

from .bench_service import BenchGoneError

__all__ = ["connection_files", "find_connection_file", "read_connection_file",
           "runtime_dir", "write_connection_file"]


def runtime_dir() -> Path:
    """The per-user directory of the connection files (module docstring); not made."""
    if os.environ.get("DIFFUSERLAB_RUNTIME_DIR"):
        return Path(os.environ["DIFFUSERLAB_RUNTIME_DIR"])
    if os.environ.get("XDG_RUNTIME_DIR"):
        return Path(os.environ["XDG_RUNTIME_DIR"]) / "diffuserlab"
    return Path.home() / ".local" / "share" / "diffuserlab" / "runtime"


def write_connection_file(address: Any, authkey: bytes, *, pid: int | None = None,
                          bench: str | None = None) -> Path:
    """Write the connection file of the bench process ``pid`` (default: this one).

    Parameters
    ----------
    address : str or tuple
        The bench process's listening address.
    authkey : bytes
        Its key (written as hex).
    pid : int, optional
    bench : str, optional
        What it serves: the bench file, or ``simulated``.

    Returns
    -------
    pathlib.Path
        ``<runtime dir>/bench-<pid>.json``, mode 0600.
    """
    pid = os.getpid() if pid is None else int(pid)
    folder = runtime_dir()
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    _remove_stale(folder)
    path = folder / f"bench-{pid}.json"
    text = json.dumps({"address": address, "authkey": authkey.hex(), "pid": pid,
                       "bench": bench,
                       "started_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")},
                      indent=1)
    tmp = folder / f".bench-{pid}.json.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, text.encode())
    finally:
        os.close(fd)
    os.replace(tmp, path)
    return path


def read_connection_file(path: str | Path) -> dict:
    """``{"address", "authkey" (bytes), "pid", "bench", "started_utc"}`` of a
    connection file.

    Raises
    ------
    instrument.bench.bench_service.BenchGoneError
        The file cannot be read or is not a connection file.
    """
    try:
        data = json.loads(Path(path).read_text())
        address = data["address"]
        info = {**data, "authkey": bytes.fromhex(data["authkey"]),
                "address": tuple(address) if isinstance(address, list) else address}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BenchGoneError(f"{path} is not a bench connection file ({exc}); name the one "
                             "the window shows in its Devices panel") from None
    return info


def _alive(pid: int) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, ValueError, TypeError):
        return isinstance(pid, int)
    return True


def _remove_stale(folder: Path) -> None:
    """Remove the connection files of bench processes that no longer run (killed)."""
    for path in folder.glob("bench-*.json"):
        try:
            if not _alive(int(path.stem.removeprefix("bench-"))):
                path.unlink()
        except (ValueError, OSError):
            continue


def connection_files() -> list[Path]:
    """The connection files of bench processes that still run, newest first."""
    folder = runtime_dir()
    found = []
    for path in folder.glob("bench-*.json") if folder.is_dir() else ():
        try:
            pid = int(path.stem.removeprefix("bench-"))
        except ValueError:
            continue
        if _alive(pid):
            found.append((path.stat().st_mtime, path))
    return [p for _, p in sorted(found, reverse=True)]


def find_connection_file() -> Path:
    """The newest connection file of a running bench process.

    Raises
    ------
    instrument.bench.bench_service.BenchGoneError
        None runs for this user.
    """
    files = connection_files()
    if not files:
        raise BenchGoneError(f"no bench process runs for this user (no live connection "
                             f"file in {runtime_dir()}); open the bench in the window "
                             "(Connect) or start one with `diffuserlab bench serve "
                             "BENCH.toml`")
    return files[0]
