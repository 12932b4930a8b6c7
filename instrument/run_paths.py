"""What a path is to the run storage: a run store, a product's folder in one; and
removing a run this process could not finish."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["discard_partial_run", "is_run_store", "product_location"]


def discard_partial_run(path: str | Path, made=(), settle_s: float = 0.1,
                        timeout_s: float = 5.0) -> None:
    """Remove a run store this process began and could not finish (whole or not at all),
    and the folders ``made`` for it (:func:`recon.io.missing_dirs`) once empty
    (:func:`recon.io.remove_tree`: until zarr's writer threads stop adding to it)."""
    from recon.io import remove_empty_dirs, remove_tree

    remove_tree(path, settle_s, timeout_s)
    remove_empty_dirs(made)


def is_run_store(path: str | Path) -> bool:
    """True if ``path`` is a directory whose ``zarr.json`` attributes mark a diffuserlab
    run (``schema = "diffuserlab-run"``, any schema version); False for anything else,
    missing or unreadable (never raises)."""
    try:
        meta = json.loads((Path(path) / "zarr.json").read_text())
    except (OSError, ValueError):
        return False
    attrs = meta.get("attributes") if isinstance(meta, dict) else None
    return Path(path).is_dir() and isinstance(attrs, dict) and \
        attrs.get("schema") == "diffuserlab-run"


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
