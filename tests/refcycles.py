"""Test helper: an object is freed by reference counting alone, without the garbage
collector (the GUI freezes its heap, and a frozen reference cycle is never freed)."""

from __future__ import annotations

import gc
import weakref


def assert_freed_without_the_collector(namespace: dict, name: str, what: str) -> None:
    """Delete ``namespace[name]`` (a test's ``locals()`` cannot be changed, so pass a dict
    holding the only reference) with the collector off, and assert it was freed: no
    reference cycle kept it."""
    probe = weakref.ref(namespace[name])
    gc.disable()
    try:
        del namespace[name]
        assert probe() is None, f"a reference cycle keeps the {what}"
    finally:
        gc.enable()
