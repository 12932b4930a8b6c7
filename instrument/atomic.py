"""Outputs written whole or not at all: files, folders (Zarr) and groups of them.

Every writer of the project goes through these (the product writer,
:mod:`instrument.writer`, and the run stores): a temporary name beside the output,
renamed into place on success (:func:`atomic_path`, :func:`atomic_dir`), several
outputs together (:func:`output_group`), what a failed write left removed
(:func:`remove_tree`, after zarr's writes in flight, :func:`wait_for_zarr_writes`), a
full disk named with its free space (:func:`free_space_text`), and every JSON file
(:func:`write_json`), and an append-only log whose lines are written whole or not at all
(:class:`AppendLog`), and a file other processes update too, edited on a scratch copy
in memory and put in place under a lock file (:func:`update_file`). It imports nothing
else of ``instrument``, so the run stores below the product writer use it too.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["AppendLog", "atomic_dir", "atomic_path", "free_space_text", "missing_dirs",
           "output_group", "remove_empty_dirs", "remove_tree", "update_file",
           "wait_for_zarr_writes", "write_json", "write_text"]


def _size_text(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} TB"  # pragma: no cover


def free_space_text(path: str | os.PathLike) -> str:
    """``"23.0 GB free of 80.0 GB on /data"`` for the file system holding ``path`` (its
    nearest existing ancestor); ``"free space unknown"`` when it cannot be read."""
    import shutil

    p = Path(os.path.abspath(os.fspath(path)))
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        usage = shutil.disk_usage(p)
    except OSError:
        return "free space unknown"
    return f"{_size_text(usage.free)} free of {_size_text(usage.total)} on {p}"


def _disk_full(path: Path, exc: OSError) -> OSError | None:
    """An ENOSPC OSError naming ``path`` and the free space for a write that failed
    because the disk (or quota) is full, including numpy's short write ("N requested
    and M written", no errno); None for any other error."""
    import errno
    import re
    import shutil

    text = str(exc)
    short = exc.errno is None and "requested and" in text and "written" in text
    if exc.errno not in (errno.ENOSPC, errno.EDQUOT) and not short:
        return None
    if short:  # numpy says how much it wanted, not why it got less
        wanted = re.search(r"(\d+) requested", text)
        where = Path(os.path.abspath(path)).parent
        while not where.exists() and where != where.parent:
            where = where.parent
        try:
            free = shutil.disk_usage(where).free
        except OSError:
            free = 0
        if wanted and free > int(wanted.group(1)):
            return OSError(errno.EIO, f"the write stopped short ({text}; "
                           f"{free_space_text(path)}: a file-size limit or a failing "
                           "disk); write elsewhere", str(path))
    detail = f"; {text}" if short else ""
    return OSError(errno.ENOSPC, f"No space left on device ({free_space_text(path)}"
                   f"{detail}); free space or write elsewhere", str(path))


#: The open :func:`output_group`'s pending ``(temporary, final)`` renames and the
#: folders its writers created, per thread.
_GROUP = threading.local()


def missing_dirs(path: str | os.PathLike) -> list[Path]:
    """The ancestors of ``path`` (``path`` itself excluded) that do not exist yet, deepest
    first: what writing ``path`` creates, and a failed write removes again
    (:func:`remove_empty_dirs`)."""
    out = []
    p = Path(os.path.abspath(os.fspath(path))).parent
    while not p.exists() and p != p.parent:
        out.append(p)
        p = p.parent
    return out


def _make_parent(path: str | os.PathLike) -> tuple[Path, list[Path]]:
    """Create ``path``'s folder; returns ``(Path(path), the folders made)``, the latter
    also noted in the current :func:`output_group`."""
    path = Path(path)
    made = missing_dirs(path)
    group = getattr(_GROUP, "made", None)
    if group is not None:
        group.extend(made)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path, made


def remove_empty_dirs(dirs) -> None:
    """Remove the folders of :func:`missing_dirs` that are still empty, deepest first."""
    for d in dirs:
        with contextlib.suppress(OSError):
            d.rmdir()


@contextlib.contextmanager
def output_group(replace: bool = True) -> Iterator[None]:
    """Several outputs written whole or not at all, together.

    Inside the block, every :func:`atomic_path` (so
    :func:`instrument.writer.files.save_image` too) and :func:`atomic_dir` keeps its
    finished temporary output instead of renaming it; when the block ends normally all
    of them are renamed into place, when it raises
    (or a rename fails) those not yet in place are removed. So a command that writes
    ``OUT.png``, ``OUT.tif`` and a JSON never leaves the PNG alone when the TIFF fails
    (a full disk), which would block its retry ("exists"). Groups do not nest (an
    inner one joins the outer, its ``replace`` ignored).

    Parameters
    ----------
    replace : bool
        True: outputs replace existing files or folders of their names (the
        command's ``--overwrite``). False: each output takes a name that is still
        free, atomically (a folder claimed with ``os.mkdir``, a file hard-linked into
        place); when another process wrote one of the names since the command
        checked its outputs, that process's output is kept and none of the group's
        is put in place.

    Raises
    ------
    recon.errors.ReconInputError
        ``replace`` is False and an output's name is taken (one line naming it).
    """
    if getattr(_GROUP, "pending", None) is not None:
        yield
        return
    _GROUP.pending, _GROUP.made = pending, made = [], []
    try:
        yield
        if replace:
            for tmp, final in pending:
                _put_in_place(tmp, final)
        else:
            _put_all_new(pending)
    except BaseException:
        for tmp, _ in pending:  # what is in place is gone from its temporary name
            _discard(tmp)
        remove_empty_dirs(made)
        raise
    finally:
        _GROUP.pending = _GROUP.made = None


def _claim_new(tmp: Path, final: Path) -> tuple[str, int]:
    """Take the free name ``final`` for ``tmp`` atomically (FileExistsError when taken):
    a folder gets an empty folder of that name (replaced by ``tmp`` after), a file a
    hard link to ``tmp`` (in place at once) or, where the file system has none, an
    empty file created exclusively (replaced after). Returns how, and the inode."""
    if tmp.is_dir():
        os.mkdir(final)
        return "dir", os.stat(final).st_ino
    try:
        os.link(tmp, final)
        return "link", os.stat(final).st_ino
    except FileExistsError:
        raise
    except OSError:  # no hard links here (some network or FAT file systems)
        os.close(os.open(final, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        return "file", os.stat(final).st_ino


def _put_all_new(pending: list[tuple[Path, Path]]) -> None:
    """Put the finished outputs of a group in place under names that must be free:
    every name is claimed first (:func:`_claim_new`); when one is taken, the claims
    made are released (each only if still this process's: its inode) and nothing is
    put in place, else the outputs replace their claims."""
    from recon.errors import ReconInputError

    claimed: list[tuple[Path, Path, str, int]] = []
    for tmp, final in pending:
        try:
            claimed.append((tmp, final, *_claim_new(tmp, final)))
        except FileExistsError:
            for _, mine, _, ino in claimed:
                with contextlib.suppress(OSError):
                    if os.stat(mine).st_ino != ino:
                        continue
                    if mine.is_dir():
                        os.rmdir(mine)
                    else:
                        os.unlink(mine)
            raise ReconInputError(
                f"{final} already exists (another process wrote it meanwhile; it is kept); "
                "choose another --out or pass --overwrite to replace it") from None
    for tmp, final, how, _ in claimed:
        if how == "link":
            tmp.unlink()
        else:  # over the empty folder or file this process made
            os.replace(tmp, final)


def _discard(tmp: Path) -> None:
    """Remove a temporary output: a file, or a folder (:func:`remove_tree`)."""
    if tmp.is_dir():
        remove_tree(tmp)
    else:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _put_in_place(tmp: Path, final: Path) -> None:
    """Rename a finished temporary output over ``final``; a folder replacing a folder
    moves the old one aside first (a rename cannot replace a non-empty folder) and
    removes it after."""
    if not (tmp.is_dir() and final.is_dir()):
        os.replace(tmp, final)
        return
    old = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".old"))
    os.replace(final, old)
    os.replace(tmp, final)
    remove_tree(old)


def wait_for_zarr_writes(timeout_s: float = 5.0) -> bool:
    """Wait until zarr's event loop has no task left running (its chunk writes).

    zarr (3.x) runs an array's chunk writes as tasks on one event loop in its own
    thread and gathers them; when one write fails the error reaches the caller while
    the other writes still run and may create folders after the caller cleaned up. This
    waits, on that loop, for every other task to end (each write's thread included).

    Parameters
    ----------
    timeout_s : float
        The longest wait (s).

    Returns
    -------
    bool
        True when no write was left running; False when zarr is not loaded, its loop
        is not running (nothing to wait for) or the wait timed out.
    """
    import asyncio
    import sys

    sync = sys.modules.get("zarr.core.sync")
    loop = getattr(sync, "loop", [None])
    loop = loop[0] if isinstance(loop, list) and loop else None
    if loop is None or not loop.is_running():
        return False

    async def drain() -> None:
        me = asyncio.current_task()
        while others := [t for t in asyncio.all_tasks() if t is not me and not t.done()]:
            await asyncio.wait(others)

    future = asyncio.run_coroutine_threadsafe(drain(), loop)
    try:
        future.result(timeout_s)
    except Exception:  # timed out (or the loop stopped): the settle loop still runs
        future.cancel()
        return False
    return True


def remove_tree(path: str | os.PathLike, settle_s: float = 0.1,
                timeout_s: float = 5.0) -> None:
    """Remove a folder a failed write left, until it stays gone.

    zarr writes chunks on a pool of threads: when one write fails (a full disk), the
    others still finish after the error has reached the caller and may create their
    folders again. So zarr's writes still in flight are waited for first
    (``wait_for_zarr_writes``), then the folder is removed until it stays gone for
    ``settle_s`` (at most ``timeout_s`` in all).
    """
    import shutil
    import time

    path = Path(path)
    deadline = time.monotonic() + timeout_s
    wait_for_zarr_writes(timeout_s)
    while True:
        shutil.rmtree(path, ignore_errors=True)
        time.sleep(settle_s)
        if not path.exists() or time.monotonic() > deadline:
            break


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary folder next to ``path`` to write a directory output to (a Zarr
    array); put in place on success, as :func:`atomic_path` does for a file.

    On success the folder replaces ``path`` (an existing folder is moved aside and
    removed after), or, inside an :func:`output_group`, when the group ends; when the
    block raises, the folder (:func:`remove_tree`: also what zarr's writer threads
    add after the error) and any parent folder it had to create are removed, and a
    full disk is named with its free space.

    Yields
    ------
    pathlib.Path
        The temporary folder (hidden, ``.NAME.XXXX.tmp``, created empty).
    """
    path, made = _make_parent(path)
    tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
    try:
        yield tmp
        pending = getattr(_GROUP, "pending", None)
        if pending is None:
            _put_in_place(tmp, path)
        else:
            pending.append((tmp, path))
    except BaseException as exc:
        remove_tree(tmp)
        remove_empty_dirs(made)
        full = _disk_full(path, exc) if isinstance(exc, OSError) else None
        if full is not None:
            raise full from exc
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary name next to ``path`` to write to; renamed into place on success.

    The writer inside the ``with`` block writes the temporary file (same directory,
    so the rename is atomic: :func:`os.replace`; same suffix, so writers that choose
    the format by extension still do). When the block succeeds the file replaces
    ``path``; when it raises, the temporary file (and any folder it had to create,
    if still empty) is removed and ``path`` is left as it was: a crash never leaves
    half a file under the final name. A write that
    fails because the disk is full (ENOSPC, a quota, numpy's short write) is raised
    as an ENOSPC OSError naming ``path`` and the free space left.

    Parameters
    ----------
    path : str or os.PathLike
        The final file name. Missing parent directories are created.

    Yields
    ------
    pathlib.Path
        The temporary file name (a hidden file ``.NAME.XXXX.tmpSUFFIX``, created empty).

    Examples
    --------
    >>> with atomic_path("out/metrics.json") as tmp:  # doctest: +SKIP
    ...     tmp.write_text("{}")
    """
    path, made = _make_parent(path)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                suffix=f".tmp{path.suffix}")
    os.close(fd)
    tmp = Path(name)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the final file gets the usual mode
    try:
        yield tmp
        group = getattr(_GROUP, "pending", None)
        if group is None:
            os.replace(tmp, path)
        else:  # renamed with the rest of its output_group
            group.append((tmp, path))
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        remove_empty_dirs(made)
        full = _disk_full(path, exc) if isinstance(exc, OSError) else None
        if full is not None:
            raise full from exc
        raise


def write_json(path: str | os.PathLike, data, *, default=None) -> Path:
    """Write ``data`` as indented, standard JSON (:func:`diffuserlab.jsonio.json_text`)
    through :func:`atomic_path`: whole or not at all, and with
    the other outputs of an :func:`output_group`.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file (replaced if it exists: callers check for overwriting first).
    data : object
        Anything :func:`diffuserlab.jsonio.jsonable` converts; NaN and infinity
        become null.
    default : callable, optional
        What to write for an object JSON has no type for (``str``); None (default)
        raises TypeError.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    TypeError
        ``data`` holds an object JSON cannot represent (nothing is written).
    OSError
        The file cannot be written (a full disk is named with its free space); an
        existing file is left as it was.

    Examples
    --------
    >>> import json, tempfile, pathlib
    >>> p = write_json(pathlib.Path(tempfile.mkdtemp()) / "m.json", {"x": float("inf")})
    >>> json.loads(p.read_text())
    {'x': None}
    """
    from diffuserlab.jsonio import json_text

    text = json_text(data, default=default)  # before the file: a TypeError leaves no trace
    return write_text(path, text)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) through :func:`atomic_path`: whole or not at all.

    Parameters
    ----------
    path : str or os.PathLike
        The file (replaced if it exists: callers check for overwriting first; its
        folder is made).
    text : str

    Returns
    -------
    pathlib.Path
        ``path``; an ``OSError`` as :func:`write_json`'s (nothing replaced).
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def _scratch_root() -> str:
    """Memory-backed ``/dev/shm`` where it is writable, else the system's temp folder."""
    shm = "/dev/shm"
    return shm if os.path.isdir(shm) and os.access(shm, os.W_OK) else tempfile.gettempdir()


def update_file(path: str | os.PathLike, edit: Callable[[Path], None]) -> Path:
    """Update ``path`` by ``edit`` on a scratch copy in memory, then put the result in
    place whole, synced to the disk, under an exclusive lock file beside it.

    For a file several processes update (the GUI's settings file: two windows, a
    window and a notebook): ``fcntl.flock`` on ``PATH.writer-lock`` makes the read,
    the edit and the write one step, so no process's values are lost to another's
    write. The edit works on a copy in ``/dev/shm``, so an editor that keeps the
    interpreter's lock while it writes (PySide6's ``QSettings.sync()``) never waits
    for the disk; the disk's waits (``os.fsync``, the rename, the lock) are Python's
    and release the interpreter's lock, so other threads run meanwhile.

    Parameters
    ----------
    path : str or os.PathLike
        The file (may not exist yet: ``edit`` then gets no file; its folder is made).
    edit : callable
        ``edit(scratch)`` with ``scratch`` a ``pathlib.Path`` holding a copy of
        ``path`` (absent if ``path`` is); what it leaves there replaces ``path``.
        Other files it makes beside ``scratch`` (a lock file) are removed.

    Returns
    -------
    pathlib.Path
        ``path``, updated (its lock file ``PATH.writer-lock`` stays beside it).

    Raises
    ------
    OSError
        The file, its lock or the scratch copy cannot be written, or ``edit`` left no
        file (``path`` is then left as it was); what ``edit`` raises propagates, and
        ``path`` is left as it was.
    """
    import fcntl
    import shutil

    target, _ = _make_parent(path)
    scratch_dir = Path(tempfile.mkdtemp(prefix="diffuserlab-update-", dir=_scratch_root()))
    scratch = scratch_dir / target.name
    try:
        with open(f"{target}.writer-lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # another process's update: waits, GIL free
            try:
                if target.exists():
                    shutil.copyfile(target, scratch)
                edit(scratch)
                if not scratch.is_file():
                    raise OSError(f"the update of {target} left no file; {target} is "
                                  "left as it was")
                with atomic_path(target) as tmp, open(tmp, "wb") as out, \
                        open(scratch, "rb") as src:
                    shutil.copyfileobj(src, out)
                    out.flush()
                    os.fsync(out.fileno())  # the interpreter's lock is released here
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)
    finally:
        shutil.rmtree(scratch_dir, ignore_errors=True)
    return target


class AppendLog:
    """An append-only log of lines, each written through to the file whole or not at
    all (the mask alignment's ``captures.jsonl``: a crash loses nothing already
    appended).

    Parameters
    ----------
    path : str or os.PathLike
        The file, opened for appending (made if missing; its folder must exist).

    Raises
    ------
    OSError
        The file cannot be opened.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fh = open(self.path, "ab", buffering=0)  # noqa: SIM115 (closed by close())

    def append(self, line: bytes) -> None:
        """Append ``line`` (bytes, its newline included), unbuffered: a write the system
        refuses midway (a full disk, a file-size limit) is cut back to the previous
        line and the ``OSError`` propagates, naming the file."""
        end = self._fh.seek(0, os.SEEK_END)
        try:
            written = 0
            while written < len(line):  # an unbuffered write may take part of it
                written += self._fh.write(line[written:])
        except OSError as exc:
            self._fh.truncate(end)
            if exc.filename is None:  # a raw write names no file: name it
                exc.filename = str(self.path)
            raise

    def close(self) -> None:
        """Close the file (appending after this raises ``ValueError``)."""
        self._fh.close()
