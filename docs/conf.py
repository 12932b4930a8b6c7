"""Sphinx configuration of the DiffuserLab documentation (``sphinx-build -W docs site``).

Sphinx with numpydoc because the code's docstrings are numpydoc with Sphinx roles
(``:func:``, ``:mod:``); MyST so the guides stay Markdown.
"""

import importlib
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
nitpicky = True  # every cross-reference must resolve (sphinx-build -n)
# Third-party and standard-library objects: the build is offline, so there is no
# intersphinx inventory to resolve them against. Only outside packages belong here; a
# reference into the project must resolve (see _resolve_public_name below).
nitpick_ignore_regex = [
    (r"py:.*", r"numpy(\..+)?"),  # NumPy: numpy.random.default_rng, numpy.roll, ...
    (r"py:.*", r"scipy\..+"),  # SciPy: scipy.fft, scipy.optimize.curve_fit, ...
    (r"py:.*", r"skimage\..+"),  # scikit-image: metrics, restoration, registration, ...
    (r"py:.*", r"tifffile\..+"),  # tifffile.imread / tifffile.imwrite
    (r"py:.*", r"os\..+"),  # the standard library's os (os.replace)
]

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


#: The project's top-level packages: a reference into them must resolve (no ignores).
PROJECT_PACKAGES = {"calibration_routines", "diffuserlab", "drivers", "gui", "instrument",
                    "recon"}


def _import_dotted(name):
    """The object a dotted name reaches: the longest importable module prefix, then
    attributes (``recon.reconstruct``, ``recon.volume.VolumeAdmmPlan.of``); a
    ``LookupError`` when the name reaches nothing."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            try:
                obj = getattr(obj, attr)
            except AttributeError:
                raise LookupError(name) from None
        return obj
    raise LookupError(name)


def _same(a, b):
    """The same object, a bound method (``VolumeAdmmPlan.of``) by its function. Never
    for None, a bool, a number or a string: Python shares small ints and short strings
    between unrelated names, so there identity proves nothing (such a constant is
    linked by the name of the module that defines it)."""
    if isinstance(a, (type(None), bool, int, float, complex, str, bytes)):
        return False
    return a is b or getattr(a, "__func__", a) is getattr(b, "__func__", b)


def _candidates(node):
    """The dotted names a reference may mean, as Python would look its name up: the
    name itself when it starts with a project package, then the name inside the class
    and the module whose docstring holds the reference (``box_bin`` in
    ``recon.preprocess.pair``, which imports it from ``recon.preprocess.binning``)."""
    target = node.get("reftarget", "").removesuffix("()")
    module, cls = node.get("py:module"), node.get("py:class")
    names = [target] if target.split(".")[0] in PROJECT_PACKAGES else []
    if module and module.split(".")[0] in PROJECT_PACKAGES:
        if cls:
            names.append(f"{module}.{cls}.{target}")
        names.append(f"{module}.{target}")
    return target, names


def _resolve_public_name(app, env, node, contnode):
    """Resolve a project name that Sphinx did not find to the entry documenting it.

    The code's docstrings name objects as a user imports them (``recon.reconstruct``,
    ``recon.volume.fista3d``, ``recon.preprocess.box_bin``) or as their module sees
    them (a name it imports); the API reference documents each object once, in the
    module that defines it (``recon.api.reconstruct``). Such a reference resolves to
    the documented entry with the same last name that is the very same object.
    Anything else (a misspelling, an object the reference does not document) stays
    unresolved, and nitpicky reports it."""
    if node.get("refdomain") != "py" or node.get("reftype") == "mod":
        return None
    target, names = _candidates(node)
    wanted = None
    for name in names:
        try:
            wanted = _import_dotted(name)
            break
        except Exception:  # noqa: BLE001, S112 - a name that imports nothing is no candidate
            continue
    if wanted is None:
        return None
    domain = env.get_domain("py")
    last = "." + target.rsplit(".", 1)[-1]
    for name, entry in domain.objects.items():
        if entry.aliased or not name.endswith(last):
            continue
        try:
            documented = _import_dotted(name)
        except Exception:  # noqa: BLE001, S112
            continue
        if _same(documented, wanted):
            return domain.resolve_xref(env, node["refdoc"], app.builder, node["reftype"],
                                       name, node, contnode)
    return None


def setup(app):
    app.connect("autodoc-process-docstring", _escape_bars, priority=400)
    app.connect("missing-reference", _resolve_public_name)
