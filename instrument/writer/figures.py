"""Figures written whole or not at all: the PNGs of ``analyze``, ``holo`` and the
benchmarks.

:func:`save_figure` saves a ``matplotlib.figure.Figure`` through
:func:`instrument.atomic.atomic_path` (so it joins an
:func:`instrument.atomic.output_group`), with no pyplot state involved.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["save_figure"]


def save_figure(fig, path: str | os.PathLike, **savefig) -> Path:
    """Save ``fig`` to ``path`` whole or not at all.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        A figure made with or without pyplot (an Agg canvas is attached when it has
        none).
    path : str or os.PathLike
        The file (replaced if it exists: callers check for overwriting first; its
        folder is made). The format is the name's, or ``format=`` in ``savefig``.
    **savefig
        Passed to ``matplotlib.figure.Figure.savefig`` (``dpi``,
        ``bbox_inches``, ``format``, ``metadata``).

    Returns
    -------
    pathlib.Path
        ``path``; an ``OSError`` when it cannot be written, as
        :func:`instrument.atomic.write_json`'s (an existing file left as it was).
    """
    from matplotlib.backend_bases import FigureCanvasBase
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from ..atomic import atomic_path

    if type(fig.canvas) is FigureCanvasBase:  # a bare Figure(): draw it with Agg
        FigureCanvasAgg(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **savefig)
    return Path(path)
