"""The bench (layer 3), in rooms by concern (docs/architecture.md, "Rooms of
instrument"): ``devices`` (from a bench file to open devices; the virtual and emulated
benches), ``bench`` (the bench process and its service), ``acquisition`` (plans, the
runner, recording, live), ``runs`` (run storage and its verification), ``processing``
(reconstruction of files and runs), ``writer`` (the one writer of products),
``config`` (bench files), ``cli`` (the ``diffuserlab`` command) and ``benchmarks``.

May import ``drivers`` and ``recon`` (see docs/architecture.md).

The import paths that users' scripts and the docs used before the rooms keep working:
``from instrument.runstore import RunStore`` imports :mod:`instrument.runs.runstore`
(the same module object, under both names), and likewise for the modules in
:data:`OLD_PATHS`. Nothing is imported until such a path is.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys

#: Old module (``instrument.X``) -> its module now, for the paths users' scripts import.
OLD_PATHS = {
    "bench_process": "bench.bench_process",
    "runstore": "runs.runstore",
    "runner": "acquisition.runner",
    "virtual_bench": "devices.virtual_bench",
    "stacks": "runs.stacks",
}


class _OldPathLoader(importlib.abc.Loader):
    """Gives the module at its new path for an old one (no second copy)."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec):
        return importlib.import_module(self.new)

    def exec_module(self, module) -> None:
        pass


class _OldPathFinder(importlib.abc.MetaPathFinder):
    """Finds ``instrument.X`` for each X of :data:`OLD_PATHS` (after every other finder,
    so a real module of that name would win)."""

    def find_spec(self, fullname, path=None, target=None):
        head, _, tail = fullname.partition(".")
        if head != __name__ or tail not in OLD_PATHS:
            return None
        return importlib.util.spec_from_loader(fullname, _OldPathLoader(f"{__name__}."
                                                                         f"{OLD_PATHS[tail]}"))


def _install() -> None:
    """Put the finder right after the path finder: a real module of the name (found on
    ``instrument.__path__``) still wins, and no later finder (an editable install's
    of another checkout) answers for the old path first."""
    if any(isinstance(f, _OldPathFinder) for f in sys.meta_path):
        return
    after = [i for i, f in enumerate(sys.meta_path) if f is importlib.machinery.PathFinder]
    sys.meta_path.insert(after[0] + 1 if after else len(sys.meta_path), _OldPathFinder())


_install()
