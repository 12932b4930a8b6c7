"""Names of a package imported on first use (PEP 562), so that importing a package for a
light submodule (a parser, an error class) does not load its heavy ones."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping

__all__ = ["lazy_attributes"]


def lazy_attributes(package: str, table: Mapping[str, str], namespace: dict,
                    names: Iterable[str]) -> tuple[Callable, Callable]:
    """The module-level ``__getattr__`` and ``__dir__`` of a package with lazy names.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : mapping of str to str
        Name -> the relative module that defines it (``".api"``).
    namespace : dict
        The package's ``globals()``: a name, once imported, is stored there.
    names : iterable of str
        The package's ``__all__`` (listed by ``dir()``).

    Returns
    -------
    (__getattr__, __dir__)
        ``__getattr__(name)`` raises AttributeError for a name not in ``table``.
    """
    names = tuple(names)

    def __getattr__(name: str):
        if name in table:
            value = getattr(importlib.import_module(table[name], package), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(names))

    return __getattr__, __dir__
