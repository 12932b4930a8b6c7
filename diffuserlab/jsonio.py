"""The one conversion to JSON types and the one JSON text of the project.

Standard JSON has no NaN or infinity: :func:`json_text` turns them into null, so every
metrics, report or benchmark file DiffuserLab writes (through
:func:`instrument.atomic.write_json`, which writes the text atomically and joins an
:func:`instrument.atomic.output_group`) can be read by any JSON parser.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from typing import Any

__all__ = ["json_line", "json_text", "jsonable"]


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
        (:func:`instrument.atomic.write_json` does); False (default) keeps them, for in-memory
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


def json_text(data: Any, *, default=None) -> str:
    """``data`` as indented, standard JSON text (NaN and infinity become null).

    Parameters
    ----------
    data : object
        Anything :func:`jsonable` converts.
    default : callable, optional
        What to write for an object JSON has no type for (``str`` for a report that
        holds, say, an exception); None (default) raises TypeError instead.

    Returns
    -------
    str
        The JSON document, ending with a newline (:func:`instrument.atomic.write_json` writes
        it atomically).

    Raises
    ------
    TypeError
        ``data`` holds an object JSON cannot represent (names it).

    Examples
    --------
    >>> print(json_text({"x": float("inf"), "shape": (2,)}), end="")
    {
     "x": null,
     "shape": [
      2
     ]
    }
    """
    return json.dumps(jsonable(data, nonfinite_to_none=True), indent=1, allow_nan=False,
                      default=default) + "\n"


def json_line(data: Any) -> str:
    """``data`` as one line of standard JSON, ending with a newline (a JSON Lines log
    entry); NaN and infinity become null.

    Raises
    ------
    TypeError
        ``data`` holds an object JSON cannot represent.

    Examples
    --------
    >>> json_line({"x": float("nan"), "n": 2})
    '{"x": null, "n": 2}\\n'
    """
    return json.dumps(jsonable(data, nonfinite_to_none=True), allow_nan=False) + "\n"
