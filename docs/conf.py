"""Sphinx configuration of the DiffuserLab documentation (``sphinx-build -W docs site``).

Sphinx with numpydoc because the code's docstrings are numpydoc with Sphinx roles
(``:func:``, ``:mod:``); MyST so the guides stay Markdown.
"""

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # the docs' own extension

project = "DiffuserLab"
author = "DiffuserLab developers"
copyright = "2026, DiffuserLab developers"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
    "benchmark_pages",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "benchmarks/results/**/*.md"]
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
nitpicky = False

html_theme = "pydata_sphinx_theme"
html_title = "DiffuserLab"
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}
os.environ.setdefault("NUMBA_DISABLE_JIT", "0")


def _escape_bars(app, what, name, obj, options, lines):
    """The docstrings write norms and magnitudes as plain text (``||A x - b||``,
    ``|H|^2``); reStructuredText would read ``|b|`` as a substitution. Escape the bars
    outside inline literals and tables."""
    for i, line in enumerate(lines):
        stripped = line.strip()
        table_row = (stripped.startswith("|") and stripped.endswith("|")
                     and stripped.count("|") > 2) or stripped.startswith("+-")
        if "|" not in line or table_row:
            continue
        parts = line.split("``")
        lines[i] = "``".join(p.replace("|", r"\|") if k % 2 == 0 else p
                             for k, p in enumerate(parts))


def setup(app):
    app.connect("autodoc-process-docstring", _escape_bars, priority=400)
