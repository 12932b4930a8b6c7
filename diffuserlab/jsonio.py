"""The one conversion to JSON types and the one JSON writer of the project.

Standard JSON has no NaN or infinity: :func:`jsonable` turns them into ``None`` by
default, and :func:`write_json` refuses to write them, so every metrics, report or
benchmark file DiffuserLab writes can be read by any JSON parser.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["jsonable", "write_json", "atomic_write_text"]


def jsonable(obj: Any, *, nonfinite_to_none: bool = False) -> Any:
    """A copy of ``obj`` made of JSON types (dict, list, str, float, int, bool, None).

    Parameters
    ----------
    obj : object
        Nested mappings, lists, tuples, sets, numpy arrays and scalars, paths, plain
        Python values. Mapping keys become strings; arrays, tuples and sets lists;
        numpy scalars Python scalars; paths strings.
    nonfinite_to_none : bool
        Replace NaN and infinite floats by None, so the result is standard JSON
        (:func:`write_json` does); False (default) keeps them, for in-memory
        dictionaries (device status, store attributes) where they mean something.

    Returns
    -------
    object

    Examples
    --------
    >>> import numpy as np
    >>> jsonable({"psnr_db": np.float32(21.5), "shape": (2, 3)})
    {'psnr_db': 21.5, 'shape': [2, 3]}
    >>> jsonable([np.inf, 1.0], nonfinite_to_none=True)
    [None, 1.0]
    """
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v, nonfinite_to_none=nonfinite_to_none)
                for k, v in obj.items()}
    if isinstance(obj, list | tuple | set | frozenset):
        return [jsonable(v, nonfinite_to_none=nonfinite_to_none) for v in obj]
    if hasattr(obj, "tolist") and hasattr(obj, "dtype"):  # numpy arrays and scalars
        return jsonable(obj.tolist(), nonfinite_to_none=nonfinite_to_none)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, float) and nonfinite_to_none and not math.isfinite(obj):
        return None
    return obj


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file renamed into place.

    A crash or an error never leaves half a file under the final name; missing
    parent directories are created.

    Parameters
    ----------
    path : str or os.PathLike
        The final file name.
    text : str
        The whole content (UTF-8).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    OSError
        The directory cannot be written (permissions, full disk); ``path`` is
        left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                suffix=f".tmp{path.suffix}")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(name, 0o666 & ~umask)  # mkstemp makes 0600; the usual mode
        os.replace(name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(name)
        raise
    return path


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write ``data`` as indented, standard JSON, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file (replaced if it exists: callers check for overwriting first).
    data : object
        Anything :func:`jsonable` converts; NaN and infinity become null.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    TypeError
        ``data`` holds an object JSON cannot represent (names it).
    OSError
        The file cannot be written; an existing file is left as it was.

    Examples
    --------
    >>> import json, tempfile, pathlib
    >>> p = write_json(pathlib.Path(tempfile.mkdtemp()) / "m.json", {"x": float("inf")})
    >>> json.loads(p.read_text())
    {'x': None}
    """
    text = json.dumps(jsonable(data, nonfinite_to_none=True), indent=1, allow_nan=False) + "\n"
    return atomic_write_text(path, text)
