"""One writer: the reconstruction layer (``recon/``) returns arrays and records and
writes no files; every product is written by :mod:`instrument.writer` (the PNG view,
the float TIFF, JSON, the volume Zarr, the all-or-nothing group, the output guards).

The scan reads every module of ``recon/`` (AST, so text in messages and docstrings
does not count) for the calls that write files."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Methods that write whatever object they are called on (a path, a figure, an array,
#: a zarr group): ``tifffile.imwrite``, ``cv2.imwrite``, ``imageio.imwrite``,
#: ``fig.savefig``, ``Path.write_text``, ``group.create_array``, ...
WRITING_METHODS = {"imwrite", "imsave", "mimwrite", "volwrite", "savefig", "write_text",
                   "write_bytes", "to_zarr", "to_tiff", "create_array", "create_group",
                   "create_dataset", "mkdir", "makedirs", "mkstemp", "mkdtemp", "symlink_to",
                   "touch"}
#: Functions of a module that write: ``json.dump``, ``np.save``, ``zarr.create``, ...
WRITING_FUNCTIONS = {("json", "dump"), ("np", "save"), ("np", "savez"),
                     ("np", "savez_compressed"), ("np", "savetxt"), ("numpy", "save"),
                     ("zarr", "create"), ("zarr", "create_array"), ("zarr", "create_group"),
                     ("zarr", "save"), ("zarr", "save_array"), ("os", "replace"),
                     ("os", "rename"), ("os", "remove"), ("os", "unlink"), ("os", "link"),
                     ("os", "mkdir"), ("shutil", "rmtree"), ("shutil", "copy"),
                     ("shutil", "copyfile"), ("shutil", "move")}
#: The project's writers, by name (they live in instrument.writer).
WRITERS = {"atomic_path", "atomic_dir", "output_group", "save_image", "write_json",
           "write_volume"}
#: ``zarr.open*`` modes that create or change a store.
WRITE_MODES = ("w", "a", "x", "+")


def _mode(call: ast.Call, position: int) -> str:
    """The literal ``mode`` of ``call`` (keyword, or the argument at ``position``);
    ``"r"`` when none is given (open's default), ``"?"`` when it is not a literal."""
    node = next((k.value for k in call.keywords if k.arg == "mode"), None)
    if node is None and len(call.args) > position:
        node = call.args[position]
    if node is None:
        return "r"
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else "?"


def file_writes(source: str) -> list[str]:
    """``"LINE: what"`` for every call in ``source`` that writes a file or folder."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        func, what = node.func, None
        if isinstance(func, ast.Name):
            if func.id in WRITERS:
                what = func.id
            elif func.id == "open" and any(m in _mode(node, 1) for m in (*WRITE_MODES, "?")):
                what = f"open(..., {_mode(node, 1)!r})"
        elif isinstance(func, ast.Attribute):
            owner = func.value.id if isinstance(func.value, ast.Name) else None
            if func.attr in WRITING_METHODS or (owner, func.attr) in WRITING_FUNCTIONS:
                what = f"{owner or '...'}.{func.attr}"
            elif func.attr in WRITERS:
                what = func.attr
            elif owner == "zarr" and func.attr.startswith("open"):
                mode = _mode(node, 99)
                if mode == "?" or any(m in mode for m in WRITE_MODES):
                    what = f"zarr.{func.attr}(mode={mode!r})"
        if what is not None:
            found.append(f"{node.lineno}: {what}")
    return found


def test_recon_writes_no_files():
    found = [f"{path.relative_to(ROOT)}:{line}"
             for path in sorted((ROOT / "recon").rglob("*.py"))
             for line in file_writes(path.read_text())]
    assert found == [], ("recon/ writes files; return the arrays and records and write "
                         "them with instrument.writer:\n" + "\n".join(found))


@pytest.mark.parametrize("line", [
    "tifffile.imwrite(p, a)", "cv2.imwrite(str(p), v)", "imageio.v3.imwrite(p, a)",
    "fig.savefig(p, dpi=110)", "Path(p).write_text('{}')", "json.dump(d, fh)",
    "np.save(fh, a)", "zarr.open_group(str(p), mode='w')", "zarr.open(p, mode=m)",
    "zarr.create_array(store=p, shape=(2,), dtype='f4')", "g.create_array('0', shape=s)",
    "open(p, 'w')", "open(p, mode='ab')", "open(p, m)", "os.replace(a, b)",
    "Path(p).mkdir(parents=True)", "tempfile.mkstemp(dir=d)",
    "save_image(p, a)", "io.write_json(p, d)", "atomic_path(p)", "output_group()"])
def test_the_scan_sees_each_kind_of_write(line):
    assert len(file_writes(line)) == 1, line


@pytest.mark.parametrize("line", [
    "open('/proc/meminfo')", "open(p, 'rb')", "zarr.open_group(str(p), mode='r')",
    "tifffile.imread(p)", "np.load(fh)", "json.dumps(d)", "self.path.save('x')",
    "log.info('tifffile.imwrite(...)')", "text.replace('a', 'b')",
    "dataclasses.replace(options, seed=1)"])
def test_the_scan_lets_reading_pass(line):
    assert file_writes(line) == []
