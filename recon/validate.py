"""Argument checks shared across :mod:`recon`.

Every check raises :class:`recon.errors.ReconInputError` naming the argument and
the value received, and returns the value converted (``float``, ``int`` or a
float64 array), so callers write ``x = positive(x, "x")``.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from .errors import ReconInputError

__all__ = ["as_array", "as_int", "as_shape2", "as_vec2", "finite_float", "float_array",
           "nonneg_weight", "positive"]


def _number(value: Any, name: str, what: str, shown: Any = None) -> float:
    """``float(value)`` of a real number, or ReconInputError "<name> must be <what>, got
    <shown>".

    Strings and bytes are refused although ``float()`` parses them: an API caller
    passing ``"3"`` has a bug (the command line converts its text itself).
    """
    try:
        if isinstance(value, str | bytes):
            raise TypeError(value)
        return float(value)
    except (TypeError, ValueError):
        shown = value if shown is None else shown
        raise ReconInputError(f"{name} must be {what}, got {shown!r}") from None


def as_array(value: Any, name: str) -> np.ndarray:
    """``np.asarray(value)``, or ReconInputError naming ``name`` (ragged sequences and the
    like); no dtype or shape check."""
    try:
        return np.asarray(value)
    except Exception as exc:  # ragged sequences and the like
        raise ReconInputError(
            f"{name} cannot be converted to an array ({exc}); pass a numpy array"
        ) from None


def positive(value: Any, name: str, *, unit: str = "") -> float:
    """A finite real number > 0, as float.

    Parameters
    ----------
    value : real number
        Anything ``float()`` accepts except ``bool`` (e.g. int, float, numpy scalar).
    name : str
        Argument name for the message.
    unit : str
        Appended to the value in the message (e.g. ``" mm"``).

    Returns
    -------
    float

    Raises
    ------
    ReconInputError
        Not a number, a bool, NaN/inf or <= 0.
    """
    v = _number(None if isinstance(value, bool) else value, name, "a positive number",
                shown=value)
    if not math.isfinite(v) or v <= 0:
        raise ReconInputError(
            f"{name} must be a positive finite number, got {value!r}{unit}; pass a value > 0")
    return v


def finite_float(value: Any, name: str, *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False) -> float:
    """A finite number within optional bounds, as float.

    Parameters
    ----------
    value : real number
        Anything ``float()`` accepts.
    name : str
        Argument name for the message.
    lo, hi : float, optional
        Lower and upper bounds (inclusive, unless ``lo_open``: then ``value > lo``).
    lo_open : bool
        Exclude ``lo`` itself.

    Returns
    -------
    float
        ``float(value)``.

    Raises
    ------
    ReconInputError
        Not a number (str and bool refused), NaN/inf, or out of bounds.
    """
    v = _number(None if isinstance(value, bool) else value, name, "a finite number",
                shown=value)
    if not math.isfinite(v):
        raise ReconInputError(f"{name} must be a finite number, got {value!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        rel = ">" if lo_open else ">="
        raise ReconInputError(f"{name} must be {rel} {lo}, got {v}")
    if hi is not None and v > hi:
        raise ReconInputError(f"{name} must be <= {hi}, got {v}")
    return v


def as_int(value: Any, name: str, minimum: int = 1) -> int:
    """An integer >= ``minimum`` (Python or numpy integer, not bool), as int.

    Raises
    ------
    ReconInputError
        Not an integer, a bool, or below ``minimum``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ReconInputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def nonneg_weight(value: Any, name: str) -> float:
    """A regularisation weight: a finite number >= 0, ``None`` meaning 0.

    Raises
    ------
    ReconInputError
        Not a number (str and bool refused), NaN/inf or negative (the message reads
        "<name> weight must be ...").
    """
    what = "a finite number >= 0"
    w = 0.0 if value is None else _number(None if isinstance(value, bool) else value,
                                          f"{name} weight", what, shown=value)
    if not (w >= 0 and math.isfinite(w)):
        raise ReconInputError(f"{name} weight must be a finite number >= 0, got {value}")
    return w


def float_array(value: Any, name: str, ndims: tuple[int, ...] | None = (2,),
                finite: bool = True) -> np.ndarray:
    """Convert to a float64 array, refusing non-numeric, empty, wrong-rank or NaN/inf.

    Parameters
    ----------
    value : array_like
        Real (bool, int or float) data.
    name : str
        Argument name for the message.
    ndims : tuple of int, optional
        Accepted numbers of dimensions (``None``: any).
    finite : bool
        Refuse NaN and inf.

    Returns
    -------
    ndarray, float64
        A view when ``value`` is already a float64 array.

    Raises
    ------
    ReconInputError
        Not convertible, non-numeric dtype, empty, wrong rank or (``finite``) NaN/inf.
    """
    arr = as_array(value, name)
    if arr.dtype.kind not in "buif":
        raise ReconInputError(
            f"{name} has non-numeric dtype {arr.dtype}; pass real intensities (int or float)"
        )
    if arr.size == 0:
        raise ReconInputError(f"{name} is empty (shape {arr.shape}); pass a non-empty array")
    if ndims is not None and arr.ndim not in ndims:
        want = " or ".join(f"{n}D" for n in ndims)
        if 2 in ndims:
            hint = "pass an image (rows, cols)" + (
                " or a stack (n, rows, cols)" if 3 in ndims else ""
            )
        else:
            hint = "pass a scalar or a 1D sequence" if 0 in ndims else "pass a 1D sequence"
        raise ReconInputError(f"{name} must be {want}, got shape {arr.shape}; {hint}")
    arr = arr.astype(np.float64, copy=False)
    if finite and not np.all(np.isfinite(arr)):
        raise ReconInputError(
            f"{name} contains NaN or inf values; replace them (e.g. np.nan_to_num) or "
            "re-acquire the image"
        )
    return arr


def as_vec2(value: Any, name: str) -> tuple[float, float]:
    """A pair of finite numbers ``(x, y)``, as floats.

    Raises
    ------
    ReconInputError
        Not convertible to two finite numbers.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ReconInputError(f"{name} must be a pair of finite numbers (x, y), "
                              f"got {value!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ReconInputError(f"{name} must be a pair of finite numbers (x, y), got {value!r}")
    return float(arr[0]), float(arr[1])


def as_shape2(value: Any, name: str) -> tuple[int, int]:
    """A 2D shape ``(rows, cols)`` of integers >= 1.

    Raises
    ------
    ReconInputError
        Not a pair, or an entry not an integer >= 1 (see :func:`as_int`).
    """
    try:
        t = tuple(value)
    except TypeError:
        raise ReconInputError(f"{name} must be (rows, cols), got {value!r}") from None
    if len(t) != 2:
        raise ReconInputError(f"{name} must be (rows, cols), got {value!r}")
    return (as_int(t[0], f"{name}[0]", 1), as_int(t[1], f"{name}[1]", 1))
