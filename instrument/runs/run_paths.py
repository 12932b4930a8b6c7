"""What a path is to the run storage: a run store, a product's folder in one; claiming
a new run's directory for this process, and removing a run this process created and
could not finish (never another's)."""

from __future__ import annotations

import json
import logging
import os
import socket
import uuid
from pathlib import Path

from ..writer.guards import is_run_store

__all__ = ["CREATOR_ATTR", "claim_run_dir", "creator_of", "discard_partial_run",
           "is_run_store", "product_location", "remove_replaced_run"]

log = logging.getLogger(__name__)

#: The run attribute that names the process which created the run: ``{"pid", "host",
#: "token"}``; the token, random, proves to that process (it keeps it in memory,
#: ``RunStore.creation_token``) that the run is its own.
CREATOR_ATTR = "created_by"


def claim_run_dir(path: str | Path) -> dict:
    """Create the directory of a new run, atomically (``os.mkdir``): of several
    processes creating the same path at once exactly one succeeds.

    Parameters
    ----------
    path : str or Path
        The run's directory; its missing parent folders are created.

    Returns
    -------
    dict
        ``{"pid", "host", "token"}`` (the ``created_by`` attribute), the token random.

    Raises
    ------
    FileExistsError
        ``path`` exists (made by another process meanwhile, or before).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkdir(path)
    return {"pid": os.getpid(), "host": socket.gethostname(), "token": uuid.uuid4().hex}


def remove_replaced_run(path: str | Path) -> None:
    """Remove the run at ``path`` that a new one replaces (``overwrite``): renamed to a
    hidden name beside it first, so ``path`` is free at once and the removal never
    reaches a run another process claims there meanwhile; nothing when ``path`` is
    gone already. The caller has checked that it is a run no process writes.

    Raises
    ------
    OSError
        It cannot be renamed or removed (permissions).
    """
    import shutil

    path = Path(path)
    aside = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.replaced")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return
    shutil.rmtree(aside)


def creator_of(path: str | Path) -> dict | None:
    """The :data:`CREATOR_ATTR` record of the run at ``path``; None when ``path`` holds
    no readable zarr.json or its run records no creator (a run written before)."""
    try:
        meta = json.loads((Path(path) / "zarr.json").read_text())
    except (OSError, ValueError):
        return None
    attrs = meta.get("attributes") if isinstance(meta, dict) else None
    record = attrs.get(CREATOR_ATTR) if isinstance(attrs, dict) else None
    return record if isinstance(record, dict) else None


def discard_partial_run(path: str | Path, made=(), *, token: str | None,
                        claimed: bool = False, settle_s: float = 0.1,
                        timeout_s: float = 5.0) -> bool:
    """Remove a run store this process created and could not finish (whole or not at
    all), and the folders ``made`` for it
    (:func:`instrument.atomic.missing_dirs`) once empty.

    Only a run this process created is removed: its ``zarr.json`` must record
    ``token`` (the ``created_by`` attribute), which only the creating process holds. So a
    process refused because another one created the same path meanwhile never
    removes the other's run. The run is first renamed to a hidden name beside it
    (atomic: ``path`` is free again at once, and the removal can never reach a run
    created there afterwards), after zarr's writes in flight have ended, then removed
    (:func:`instrument.atomic.remove_tree`: until zarr's writer threads stop
    adding to it).

    Parameters
    ----------
    path : str or Path
        The run store.
    made : iterable of Path
        Folders created for the run, deepest first; each is removed if empty.
    token : str or None
        The creation token this process got (``RunStore.creation_token``); None:
        nothing is removed (the run was not created here).
    claimed : bool
        The caller made ``path`` itself (:func:`~instrument.runs.run_paths.claim_run_dir`)
        and may have failed before the run recorded its creator: a directory recording
        no creator is then removed too (``RunStore.create`` cleaning up after itself).
    settle_s, timeout_s : float
        As :func:`instrument.atomic.remove_tree`, s.

    Returns
    -------
    bool
        True when the run was removed; False when ``path`` holds no run of this
        process (nothing removed but empty folders of ``made``; a warning logged
        when ``token`` is given and another run is there).
    """
    from ..atomic import remove_empty_dirs, remove_tree, wait_for_zarr_writes

    path = Path(path)
    record = creator_of(path)
    ours = token is not None and (record.get("token") == token if record is not None
                                  else claimed)
    if not ours:
        if token is not None and path.exists():
            log.warning("not removing %s: this process did not create it (another "
                        "process replaced it?)", path)
        remove_empty_dirs(made)
        return False
    wait_for_zarr_writes(timeout_s)
    aside = path.with_name(f".{path.name}.{token[:12]}.discard")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        remove_empty_dirs(made)
        return False
    remove_tree(aside, settle_s, timeout_s)
    remove_empty_dirs(made)
    return True


def product_location(path: str | Path) -> tuple[Path, str] | None:
    """The run and the product name of a product's own folder, None for any other path.

    Parameters
    ----------
    path : str or Path
        ``RUN.zarr/products/NAME`` (an image product's group, or the array of a table
        or of a run written before the image groups) or ``RUN.zarr/products/NAME/0``
        (an image product's array).

    Returns
    -------
    (Path, str) or None
        ``(RUN.zarr, NAME)`` when ``path`` is such a folder of a run store (read it
        through ``RunStore.product``, verified); None
        otherwise (never raises).
    """
    from .product_nodes import HIDDEN_SUFFIXES, IMAGE_ARRAY

    p = Path(path)
    if p.name == IMAGE_ARRAY and p.parent.parent.name == "products":
        p = p.parent
    if p.parent.name != "products" or p.name.endswith(HIDDEN_SUFFIXES) \
            or not (p / "zarr.json").is_file() or not is_run_store(p.parent.parent):
        return None
    return p.parent.parent, p.name
