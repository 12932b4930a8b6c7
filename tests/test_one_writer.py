"""One writer of files: outside :mod:`instrument.writer`, :mod:`instrument.atomic` and
the run store, no module of the installed packages calls a file-writing API itself
(``open(..., "w")``, ``write_text``, ``write_bytes``, ``np.save``, ``tifffile.imwrite``,
``savefig``, ``json.dump``, a zarr store opened for writing, ...): a module that
writes a file itself fails (issue 66: the allow-list of modules that still did is
empty; none may be added).
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("diffuserlab", "recon", "drivers", "instrument", "calibration_routines", "gui")
#: Where files are written: the writer, the atomic outputs under it, the run store.
WRITERS = ("instrument/writer/", "instrument/atomic.py", "instrument/runs/runstore.py",
           "instrument/runs/run_writing.py", "instrument/runs/run_creation.py")
#: Methods that write a file on any object (``path.write_text``, ``fig.savefig``).
_METHODS = {"write_text", "write_bytes", "savefig", "tofile", "to_zarr", "imwrite"}
#: Functions of a module that write a file: (module's name or "" for a bare name).
_FUNCTIONS = {("np", "save"), ("np", "savez"), ("np", "savez_compressed"),
              ("numpy", "save"), ("tifffile", "imsave"), ("", "imwrite"), ("", "imsave"),
              ("json", "dump"), ("pickle", "dump")}
_ZARR_OPENERS = {"open", "open_group", "open_array", "create", "create_array",
                 "create_group", "group"}


def _mode(call: ast.Call, position: int) -> str | None:
    for k in call.keywords:
        if k.arg == "mode" and isinstance(k.value, ast.Constant):
            return k.value.value
    if len(call.args) > position and isinstance(call.args[position], ast.Constant):
        return call.args[position].value
    return None


def writes_in(source: str) -> list[str]:
    """``"line: call"`` for each file-writing call in ``source``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        if isinstance(func, ast.Name):
            base, attr = "", func.id
            writing = (base, attr) in _FUNCTIONS
        elif isinstance(func, ast.Attribute):
            base = func.value.id if isinstance(func.value, ast.Name) else ""
            attr = func.attr
            writing = attr in _METHODS or (base, attr) in _FUNCTIONS
        else:
            continue
        if attr == "open" and base not in ("zarr", "RunStore"):
            # open(path, "w") or path.open("w")
            mode = _mode(node, 1 if isinstance(func, ast.Name) else 0)
            writing = isinstance(mode, str) and any(c in mode for c in "wax+")
        if base == "zarr" and attr in _ZARR_OPENERS:
            mode = _mode(node, 99)
            writing = attr.startswith("create") or attr == "group" or (
                isinstance(mode, str) and mode != "r")
        if writing:
            found.append(f"{node.lineno}: {base + '.' if base else ''}{attr}")
    return found


def _writing_modules() -> dict[str, list[str]]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith(WRITERS):
                continue
            calls = writes_in(path.read_text(encoding="utf-8"))
            if calls:
                out[rel] = calls
    return out


def test_only_the_writer_writes_files():
    writing = _writing_modules()
    assert not writing, ("these modules write files themselves; write through "
                         "instrument.writer or instrument.atomic instead: " + repr(writing))


def test_the_scan_sees_each_way_of_writing():
    """Each API the scan looks for is found (a scan that finds nothing passes whatever
    the code does), and reading is not taken for writing."""
    writing = """
open(p, "w"); open(p, mode="ab"); p.open("w"); p.write_text(t); p.write_bytes(b)
np.save(p, a); np.savez(p, a=a); tifffile.imwrite(p, a); cv2.imwrite(p, a)
fig.savefig(p); json.dump(d, fh); a.tofile(p); zarr.open_group(p, mode="w")
zarr.create_array(p, shape=(1,)); imwrite(p, a)
"""
    assert len(writes_in(writing)) == 15, writes_in(writing)
    reading = """
open(p); open(p, "rb"); p.open(); p.read_text(); np.load(p); tifffile.imread(p)
json.load(fh); zarr.open_group(p, mode="r"); RunStore.open(p, "r+"); np.where(a)
write_text(p, t); save_figure(fig, p)  # instrument.atomic's and the writer's
"""
    assert writes_in(reading) == []
