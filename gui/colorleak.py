"""Keep pyqtgraph's colour parsing off NumPy's reference leak of ``None``.

NumPy 2.2-2.4 keeps one reference to ``None`` every time ``np.dtype`` is given the
Python class ``tuple`` or ``list`` (``np.dtype(tuple)`` returns ``dtype('O')`` and
``sys.getrefcount(None)`` grows by one; other classes do not leak). pyqtgraph's
:func:`pyqtgraph.mkColor` asks ``np.issubdtype(type(arg), np.floating)`` of every
colour before it looks at tuples, so each ``(r, g, b[, a])`` colour leaks one
reference: the histogram beside the image repaints with such pens on every frame, a
curve re-applies its pen on every ``setData``. The operator's day drifted by thousands
of references a minute. The count only grows, so it cannot abort the interpreter as a
binding that releases references does (:mod:`gui.binding`), but a drift that hides
any other leak is not acceptable in a tool that runs all day.

:func:`install` wraps ``pyqtgraph.functions.mkColor`` (through which ``mkPen``,
``mkBrush`` and pyqtgraph's own items make every colour; ``pyqtgraph.colormap``
imports it by name and is wrapped too) so that a 3- or 4-tuple or
list of numbers becomes a ``QColor`` exactly as pyqtgraph makes it (non-finite
components become 0), before NumPy is asked; everything else goes to pyqtgraph
unchanged. It does nothing where :func:`numpy_leaks` finds the leak gone.
"""

from __future__ import annotations

import math
import numbers
import sys

__all__ = ["install", "installed", "numpy_leaks"]

_PATCH_ATTR = "_diffuserlab_tuple_colors"


def numpy_leaks(calls: int = 200) -> int:
    """References to ``None`` kept by ``calls`` calls of ``np.dtype(tuple)``.

    Parameters
    ----------
    calls : int
        Number of calls (a few microseconds each).

    Returns
    -------
    int
        About ``calls`` on a NumPy with the leak, about 0 on one without.
    """
    import numpy as np

    np.dtype(tuple)
    before = sys.getrefcount(None)
    for _ in range(calls):
        np.dtype(tuple)
    return sys.getrefcount(None) - before


def installed() -> bool:
    """Whether :func:`install` has wrapped ``pyqtgraph.functions.mkColor``.

    Returns
    -------
    bool
        True once the wrapper is in place in this process.
    """
    import pyqtgraph.functions as fn

    return hasattr(fn.mkColor, _PATCH_ATTR)


def install(*, force: bool = False) -> bool:
    """Wrap ``pyqtgraph.functions.mkColor`` (and ``pyqtgraph.mkColor``) where NumPy leaks.

    Parameters
    ----------
    force : bool
        Install even where :func:`numpy_leaks` finds no leak (for tests).

    Returns
    -------
    bool
        True when the wrapper is in place (now or from an earlier call), False where
        NumPy does not leak and ``force`` is False.

    Examples
    --------
    >>> from gui import colorleak
    >>> colorleak.install(force=True) and colorleak.installed()
    True
    """
    import pyqtgraph as pg
    import pyqtgraph.colormap as colormap
    import pyqtgraph.functions as fn
    from pyqtgraph.Qt import QtGui

    if installed():
        return True
    if not force and numpy_leaks() < 100:
        return False
    original = fn.mkColor

    def mkColor(*args):  # noqa: N802 - pyqtgraph's name
        arg = args[0] if len(args) == 1 else None
        if (type(arg) in (tuple, list) and len(arg) in (3, 4)
                and all(isinstance(v, numbers.Real) for v in arg)):
            rgba = [int(v) if math.isfinite(v) else 0 for v in arg]
            return QtGui.QColor(*rgba) if len(rgba) == 4 else QtGui.QColor(*rgba, 255)
        return original(*args)

    mkColor.__doc__ = original.__doc__
    setattr(mkColor, _PATCH_ATTR, original)
    fn.mkColor = mkColor  # mkPen, mkBrush and the items look it up here
    pg.mkColor = mkColor
    colormap.mkColor = mkColor  # imported by name there
    return True
