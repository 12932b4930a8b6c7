"""The command line of a generated documentation page (``--check`` or write)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

__all__ = ["page_main"]


def page_main(prog: str, description: str, default_page: Path, page: Callable[[], str],
              argv: list[str] | None = None) -> int:
    """Write the page ``page()`` generates to ``--page`` (default ``default_page``), or
    with ``--check`` compare it.

    Returns
    -------
    int
        0 written or up to date; 1 with ``--check`` when the file differs (the message
        says to run ``python -m PROG``).
    """
    parser = argparse.ArgumentParser(prog=f"python -m {prog}", description=description)
    parser.add_argument("--page", type=Path, default=default_page, help="the Markdown file")
    parser.add_argument("--check", action="store_true",
                        help="compare instead of writing; exit 1 when it differs")
    args = parser.parse_args(argv)
    text = page()
    if args.check:
        current = args.page.read_text(encoding="utf-8") if args.page.exists() else ""
        if current != text:
            print(f"{args.page} is out of date: run python -m {prog}", file=sys.stderr)
            return 1
        return 0
    args.page.write_text(text, encoding="utf-8")
    print(f"wrote {args.page}")
    return 0
