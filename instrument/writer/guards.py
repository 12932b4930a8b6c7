"""Output safety of the ``diffuserlab`` commands: outputs never clobber inputs.

Every command that writes files calls :func:`check_outputs` before any work starts.
It refuses, with one line naming both paths, an output that is one of the command's
inputs (resolved paths: ``recon --raw raw.tif --out raw`` would write ``raw.tif``)
or lies inside an input directory (a run store), an output that already exists
(unless ``--overwrite``), an output directory that is a file, and an output whose
directory cannot be created or written (reported before the solve, not after). It
creates nothing: a command refused afterwards leaves no trace.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

from diffuserlab.errors import InputError

__all__ = ["OutputError", "checked_outputs", "check_outputs"]

log = logging.getLogger(__name__)

#: The outputs :func:`check_outputs` passed in this process, most recent last: an OS
#: error without a file name (zarr's writes on a full disk) is reported against them.
_CHECKED: list[str] = []


def checked_outputs(reset: bool = False) -> list[str]:
    """The outputs checked so far (see ``_CHECKED``); ``reset`` forgets them (the
    command line does at the start of each command)."""
    if reset:
        _CHECKED.clear()
    return list(_CHECKED)


class OutputError(InputError):
    """An output path the command refuses (exit status 2 through the CLI boundary)."""


def is_run_store(path: str | Path) -> bool:
    """True if ``path`` is a directory whose ``zarr.json`` attributes mark a diffuserlab
    run (``schema = "diffuserlab-run"``, any schema version); False for anything else,
    missing or unreadable (never raises).

    Defined here, with the rule that needs it (no output inside a run store), so that
    the writer depends on nothing of the run stores; :mod:`instrument.runs.runstore`
    offers it to its users."""
    try:
        meta = json.loads((Path(path) / "zarr.json").read_text())
    except (OSError, ValueError):
        return False
    attrs = meta.get("attributes") if isinstance(meta, dict) else None
    return Path(path).is_dir() and isinstance(attrs, dict) and \
        attrs.get("schema") == "diffuserlab-run"


def _resolved(path: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.expanduser(os.fspath(path)))).resolve()


def _inside(path: Path, folder: Path) -> bool:
    return folder in path.parents


def _check_writable(folder: Path, label: str) -> None:
    """Refuse ``folder`` unless it is, or can be created as, a writable directory.

    Nothing is created: the writers make their directories
    (:func:`instrument.atomic.atomic_path`, Zarr), so a command refused later,
    on its inputs, leaves no empty folder behind.
    The nearest existing ancestor must be a directory in which a probe file (removed
    at once) can be written.
    """
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        what = "a file of that name exists" if existing == folder else f"{existing} is a file"
        raise OutputError(f"{label}: cannot create directory {folder}: {what}; choose another "
                          "path")
    try:
        with tempfile.TemporaryFile(dir=existing, prefix=".diffuserlab-probe-"):
            pass
    except OSError as exc:
        where = folder if existing == folder else f"{existing} (to create {folder})"
        raise OutputError(f"{label}: cannot write in {where} ({exc.strerror or exc}); "
                          "choose a writable path") from None


def check_outputs(outputs: Iterable[str | os.PathLike],
                  inputs: Mapping[str, str | os.PathLike | None] | None = None,
                  overwrite: bool = False, *, directory: str | os.PathLike | None = None,
                  option: str = "--out", store: bool = False) -> None:
    """Refuse outputs that would clobber an input or an existing file, before any work.

    Parameters
    ----------
    outputs : iterable of path
        Every file (or Zarr directory) the command will write.
    inputs : mapping of str to path, optional
        The command's inputs by option name (``{"--raw": "raw.tif"}``); None values
        are skipped.
    overwrite : bool
        ``--overwrite``: existing outputs may be replaced (never an input).
    directory : path, optional
        The command's output directory (``--out`` of demo, analyze, holo evaluate,
        benchmark recon); refused when it exists and is not a directory.
    option : str
        How messages name the output option.
    store : bool
        The outputs are directories (run stores); otherwise only Zarr outputs (a
        ``.zarr`` name or a ``zarr.json`` inside) may be existing directories.

    Raises
    ------
    OutputError
        An output is an input or lies inside an input directory or inside any run
        store, or is written twice (e.g. ``--metrics-json`` naming the image
        ``--out`` writes); an output exists (without ``overwrite``) or is a
        directory where a file is written; the output
        directory is a file, cannot be created or is not writable. The message is
        one line naming the paths.

    Notes
    -----
    Nothing is created: for each output directory, a probe file is written and
    removed in it or, if it does not exist yet, in its nearest existing ancestor.
    """
    ins = {name: _resolved(p) for name, p in (inputs or {}).items() if p is not None}
    folders: dict[Path, str] = {}
    if directory is not None:
        d = _resolved(directory)
        if d.exists() and not d.is_dir():
            raise OutputError(f"{option} {directory} is a file, not a directory; choose a "
                              "directory name")
        folders[d] = f"{option} {directory}"
    seen: dict[Path, str] = {}
    for out in outputs:
        target = _resolved(out)
        if target in seen:
            raise OutputError(f"output {out} is also the output {seen[target]}; choose "
                              "different names")
        seen[target] = str(out)
        for name, src in ins.items():
            if target == src or _inside(target, src):
                what = "is" if target == src else "is inside"
                raise OutputError(f"output {out} {what} the input {name} {src}; choose "
                                  f"another {option}")
        run = next((p for p in target.parents if is_run_store(p)), None)
        if run is not None:
            raise OutputError(f"output {out} is inside the run store {run}; a run holds only "
                              f"what its runs wrote - choose another {option} outside it")
        if target.is_dir() and not (store or target.suffix.lower() == ".zarr"
                                    or (target / "zarr.json").is_file()):
            raise OutputError(f"output {out} is a directory; give a file name")
        if target.exists() and not overwrite:
            raise OutputError(f"output {out} exists; pass --overwrite to replace it, or "
                              f"choose another {option}")
        folders.setdefault(target.parent, f"output {out}")
    for folder, label in folders.items():
        _check_writable(folder, label)
    _CHECKED.extend(str(out) for out in seen.values())
    log.debug("outputs checked: %s", ", ".join(map(str, folders)))
