"""Draw the measured map of the code: the layers, the parts of each package sized by
their lines, the imports between packages, and the walk of one ``diffuserlab recon``.

Everything drawn is measured from the checkout when the script runs (``ast`` for the
imports and lines, ``sys.setprofile`` for the walk), so the picture cannot drift from
the code. Used for docs/images/architecture.png (docs/architecture.md)::

    python scripts/architecture_map.py docs/images/architecture.png --docs docs/architecture.md

Beside the PNG it writes the numbers drawn, ``architecture.json`` (lines per part and
package, import statements between packages, the walk), and the PNG carries that
summary's SHA-256 (its ``Description`` text); ``--docs`` rewrites the table of
docs/architecture.md between its ``architecture-map`` markers from the same numbers.
tests/docs/test_architecture_map.py re-measures the checkout and fails when the
committed figures have drifted from it. The output is deterministic: the same checkout
gives the same JSON and the same PNG bytes.

The walk needs the tutorial sample (``../shared/data/diffusercam-tutorial`` beside the
repository, or ``--sample DIR`` with ``psf_sample.tif`` and ``rawdata_hand_sample.tif``);
without it the walk panel says so and the map is drawn alone. ``--keep-walk`` takes the
walk from the JSON already beside the PNG instead of profiling a reconstruction again
(minutes on a loaded machine), for a redraw after lines and imports alone have moved.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: Layers from the top (may import everything below) to the bottom, as the
#: import-linter contract in pyproject.toml draws them.
LAYERS = (("benchmarks", "soak"), ("gui",), ("calibration_routines",), ("instrument",),
          ("drivers", "recon"), ("diffuserlab",))
PACKAGES = tuple(p for layer in LAYERS for p in layer)
LAYER_OF = {p: i for i, layer in enumerate(LAYERS) for p in layer}


def part_of(module: str) -> str:
    """``recon.solvers.admm`` -> ``recon.solvers``; ``recon.planar`` -> ``recon.planar``."""
    bits = module.split(".")
    return ".".join(bits[:2])


def module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    bits = list(rel.parts)
    if bits[-1] == "__init__":
        bits = bits[:-1]
    return ".".join(bits)


def measure() -> tuple[Counter, Counter]:
    """Lines per part and import statements between top-level packages."""
    lines: Counter = Counter()
    edges: Counter = Counter()
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            name = module_name(path)
            text = path.read_text(encoding="utf-8")
            lines[part_of(name)] += text.count("\n")
            tree = ast.parse(text)
            is_pkg = path.name == "__init__.py"
            for node in ast.walk(tree):
                targets = []
                if isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    if node.level:
                        base = name.split(".")
                        base = base[:len(base) - node.level + (1 if is_pkg else 0)]
                        targets = [".".join([*base, node.module] if node.module else base)]
                    elif node.module:
                        targets = [node.module]
                for t in targets:
                    top = t.split(".")[0]
                    if top in PACKAGES and top != pkg:
                        edges[(pkg, top)] += 1
    return lines, edges


#: Code that runs for an import, not for the work: a module's body and the import
#: protocol's methods (instrument/__init__.py's finder of the old import paths is asked
#: about every module the path finder does not find, the optional imports included).
IMPORT_CALLS = frozenset({"<module>", "find_spec", "create_module", "exec_module"})


def walk(sample: Path) -> list[str]:
    """The packages one ``diffuserlab recon`` moves between, in order, each step named by
    the part it enters (a profile of every Python call made in our packages, imports
    left out)."""
    sys.path.insert(0, str(REPO))
    from instrument.cli import main

    seen: list[str] = []
    handler = str(REPO / "instrument" / "cli" / "recon.py")
    part_of_file: dict[str, str | None] = {}  # a file's part, or None: not ours

    def file_part(path: str) -> str | None:
        try:
            rel = Path(path).resolve().relative_to(REPO)
        except ValueError:
            return None
        if rel.parts[0] not in PACKAGES or rel.parts[0] == "diffuserlab":
            return None
        return part_of(module_name(REPO / rel))

    def profile(frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        path = code.co_filename
        if not seen:  # from the command's handler on (the parser's building left out)
            if path != handler or code.co_name != "run":
                return
        if code.co_name in IMPORT_CALLS:  # an import, not the work
            return
        if path not in part_of_file:
            part_of_file[path] = file_part(path)
        part = part_of_file[path]
        if part is None:
            return
        # a step is a change of package, named by the part it enters
        if not seen or seen[-1].split(".")[0] != part.split(".")[0]:
            seen.append(part)

    with tempfile.TemporaryDirectory() as tmp:
        argv = ["recon", "--psf", str(sample / "psf_sample.tif"),
                "--raw", str(sample / "rawdata_hand_sample.tif"), "--method", "admm",
                "--iterations", "5", "--bin", "4", "--out", str(Path(tmp) / "hand.tif")]
        sys.setprofile(profile)
        try:
            status = main(argv)
        finally:
            sys.setprofile(None)
    if status != 0:
        raise SystemExit(f"diffuserlab recon exited {status}")
    return seen


def summary(lines: Counter, edges: Counter, steps: list[str] | None) -> dict:
    """The numbers the map draws, as plain JSON types in a fixed order.

    Returns
    -------
    dict
        ``packages`` (lines per top-level package), ``parts`` (lines per part),
        ``imports`` (``"a -> b"``: import statements of package a naming package b),
        ``imports_total``, ``upward`` (of those, the statements to the same or a
        higher layer) and ``walk`` (the parts one ``diffuserlab recon`` enters, in
        order; None without the sample).
    """
    packages = {pkg: sum(n for p, n in lines.items() if p.split(".")[0] == pkg)
                for pkg in PACKAGES}
    upward = sum(n for (a, b), n in edges.items() if LAYER_OF[b] <= LAYER_OF[a])
    return {"packages": packages,
            "parts": {p: lines[p] for p in sorted(lines)},
            "imports": {f"{a} -> {b}": edges[(a, b)] for a, b in sorted(edges)},
            "imports_total": sum(edges.values()),
            "upward": upward,
            "walk": steps}


def summary_json(data: dict) -> str:
    """The summary's text as committed (sorted keys, one line per number)."""
    return json.dumps(data, indent=1, sort_keys=True) + "\n"


def digest(data: dict) -> str:
    """SHA-256 of the summary's text: the PNG's ``Description``, so a PNG and a JSON
    drawn apart are told apart."""
    return hashlib.sha256(summary_json(data).encode()).hexdigest()


#: How far a committed number may lag the checkout before the map counts as stale:
#: a fraction of the measured number, with a floor for small ones.
LINES_SLACK = (0.05, 30)
IMPORTS_SLACK = (0.05, 3)
TOTAL_IMPORTS_SLACK = 0.03


def drift(committed: dict, measured: dict) -> list[str]:
    """What of the committed summary no longer holds for the measured one.

    Parameters
    ----------
    committed, measured : dict
        :func:`summary` of the committed map and of the checkout (walks not compared:
        profiling one takes minutes).

    Returns
    -------
    list of str
        One line per difference: a part or an import direction that appeared or went,
        a line count off by more than :data:`LINES_SLACK`, an import count by more
        than :data:`IMPORTS_SLACK`, the total of imports by more than
        :data:`TOTAL_IMPORTS_SLACK`, or a different number of upward imports.
        Empty when the map is still true.
    """
    found = []

    def near(what, old, new, slack):
        frac, floor = slack
        if abs(old - new) > max(frac * new, floor):
            found.append(f"{what}: drawn {old}, now {new}")

    for key, slack in (("packages", LINES_SLACK), ("parts", LINES_SLACK),
                       ("imports", IMPORTS_SLACK)):
        old, new = committed[key], measured[key]
        for name in sorted(set(old) ^ set(new)):
            found.append(f"{key[:-1]} {name}: " + ("gone" if name in old else "new"))
        for name in sorted(set(old) & set(new)):
            near(f"{key[:-1]} {name}", old[name], new[name], slack)
    near("imports in all", committed["imports_total"], measured["imports_total"],
         (TOTAL_IMPORTS_SLACK, 0))
    if committed["upward"] != measured["upward"]:
        found.append(f"upward imports: drawn {committed['upward']}, now {measured['upward']}")
    return found


#: The markers around the generated table in docs/architecture.md.
DOCS_START = "<!-- architecture-map:start (scripts/architecture_map.py --docs) -->"
DOCS_END = "<!-- architecture-map:end -->"


def docs_table(data: dict) -> str:
    """The Markdown table of each package's lines and its import statements naming
    other packages (out) and naming it (in)."""
    pairs = [(k.split(" -> "), n) for k, n in data["imports"].items()]
    rows = ["| package | lines | import statements naming another package | "
            "import statements naming it |", "|---|---:|---:|---:|"]
    for pkg in PACKAGES:
        out = sum(n for (a, _), n in pairs if a == pkg)
        into = sum(n for (_, b), n in pairs if b == pkg)
        rows.append(f"| `{pkg}` | {data['packages'][pkg]:,} | {out:,} | {into:,} |")
    rows.append(f"| all | {sum(data['packages'].values()):,} | {data['imports_total']:,} "
                f"(upward or sideways: {data['upward']}) | |")
    return "\n".join(rows)


def rewrite_docs(page: Path, data: dict) -> None:
    """Replace the table between the markers of ``page`` (the markers must be there)."""
    text = page.read_text(encoding="utf-8")
    if DOCS_START not in text or DOCS_END not in text:
        raise SystemExit(f"{page}: no {DOCS_START!r} ... {DOCS_END!r} markers; add them "
                         "where the table goes")
    head, rest = text.split(DOCS_START, 1)
    _, tail = rest.split(DOCS_END, 1)
    page.write_text(f"{head}{DOCS_START}\n{docs_table(data)}\n{DOCS_END}{tail}",
                    encoding="utf-8")


def draw(out: Path, lines: Counter, edges: Counter, steps: list[str] | None,
         description: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, Rectangle

    fig = plt.figure(figsize=(16, 11.5))
    ax = fig.add_axes((0.01, 0.22, 0.98, 0.74))
    ax.set_xlim(0, 100)
    ax.set_ylim(0, len(LAYERS) * 10)
    ax.axis("off")
    colours = {"benchmarks": "#d9d9d9", "soak": "#d9d9d9", "gui": "#f4c7a1",
               "calibration_routines": "#f7e19c", "instrument": "#b9d7a8",
               "drivers": "#a9cbe8", "recon": "#c5b3e0", "diffuserlab": "#e0e0e0"}
    centre: dict[str, tuple[float, float]] = {}
    for li, layer in enumerate(LAYERS):
        y0 = (len(LAYERS) - 1 - li) * 10 + 1.0
        total = sum(lines[p] for p in lines if p.split(".")[0] in layer)
        x = 1.0
        width_all = 98.0 - 2.0 * (len(layer) - 1)
        for pkg in layer:
            parts = sorted(((n, p) for p, n in lines.items() if p.split(".")[0] == pkg),
                           reverse=True)
            pkg_lines = sum(n for n, _ in parts)
            w_pkg = max(width_all * pkg_lines / max(total, 1), 9.0)
            ax.add_patch(Rectangle((x, y0), w_pkg, 8.0, fill=False, lw=1.6))
            ax.text(x + 0.3, y0 + 7.3, f"{pkg}/  {pkg_lines:,} lines", fontsize=9.5,
                    weight="bold", va="center")
            centre[pkg] = (x + w_pkg / 2, y0 + 4.0)
            px = x + 0.2
            for n, part in parts:
                w = (w_pkg - 0.4) * n / max(pkg_lines, 1)
                ax.add_patch(Rectangle((px, y0 + 0.3), w, 6.3, facecolor=colours[pkg],
                                       edgecolor="white", lw=0.8))
                label = part.split(".", 1)[1] if "." in part else "(top)"
                if w > 1.6:
                    ax.text(px + w / 2, y0 + 3.45, f"{label}\n{n:,}", ha="center",
                            va="center", fontsize=6.3 if w > 3.2 else 5.2,
                            rotation=0 if w > 4.5 else 90)
                px += w
            x += w_pkg + 2.0
    upward = 0
    for (a, b), n in sorted(edges.items(), key=lambda e: (e[1], e[0])):
        (xa, ya), (xb, yb) = centre[a], centre[b]
        up = LAYER_OF[b] < LAYER_OF[a] or (LAYER_OF[a] == LAYER_OF[b])
        upward += n if up else 0
        arrow = FancyArrowPatch((xa, ya - 3.6), (xb, yb + 3.6),
                                connectionstyle="arc3,rad=0.08", arrowstyle="-|>",
                                mutation_scale=9, lw=0.4 + 2.2 * min(n, 400) / 400,
                                color="crimson" if up else "#555555", alpha=0.55)
        ax.add_patch(arrow)
        if n >= 10:
            ax.text(xa + 0.3 * (xb - xa), ya - 3.6 + 0.3 * (yb - ya + 7.2), str(n), fontsize=7.5,
                    color="crimson" if up else "#333333", ha="center", va="center",
                    bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.6,
                          "alpha": 0.8})
    ax.set_title(f"The layers, measured: each box a part of a package sized by its lines; "
                 f"grey arrows: import statements between packages (width by count, "
                 f"{sum(edges.values())} in all); upward or sideways imports: {upward}",
                 fontsize=10.5)
    ax2 = fig.add_axes((0.01, 0.02, 0.98, 0.16))
    ax2.axis("off")
    if steps is None:
        ax2.text(0.0, 0.5, "walk of one diffuserlab recon: the tutorial sample was not "
                 "found (--sample DIR)", fontsize=10)
    else:
        ax2.set_title(f"The walk of one `diffuserlab recon` (tutorial hand, ADMM, imports "
                      f"left out): each step a move to another package, named by the part "
                      f"it enters; {len(steps) - 1} moves", fontsize=10.5, loc="left")
        n = len(steps)
        per_row = 8
        for i, part in enumerate(steps):
            r, c = divmod(i, per_row)
            xx, yy = c / per_row, 0.8 - 0.3 * r
            ax2.text(xx + 0.002, yy, f"{i + 1}. {part}" + (" >" if i < n - 1 else ""),
                     fontsize=7.6, va="center",
                     bbox={"facecolor": colours[part.split('.')[0]], "edgecolor": "none",
                           "pad": 2})
    # no Software (matplotlib's version): the same numbers give the same bytes
    fig.savefig(out, dpi=110, metadata={"Software": None, "Description": description})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the PNG to write (its summary: OUT.json)")
    parser.add_argument("--sample", type=Path,
                        default=REPO.parent / "shared" / "data" / "diffusercam-tutorial")
    parser.add_argument("--keep-walk", action="store_true",
                        help="take the walk from OUT.json instead of profiling one recon")
    parser.add_argument("--docs", type=Path, default=None,
                        help="also rewrite the table between this page's markers")
    args = parser.parse_args(argv)
    lines, edges = measure()
    beside = args.out.with_suffix(".json")
    if args.keep_walk:
        if not beside.exists():
            raise SystemExit(f"--keep-walk: {beside} does not exist; run without it once")
        steps = json.loads(beside.read_text(encoding="utf-8"))["walk"]
    elif (args.sample / "psf_sample.tif").exists():
        steps = walk(args.sample)
    else:
        steps = None
    data = summary(lines, edges, steps)
    draw(args.out, lines, edges, steps, description=digest(data))
    beside.write_text(summary_json(data), encoding="utf-8")
    if args.docs is not None:
        rewrite_docs(args.docs, data)
    for (a, b), n in sorted(edges.items()):
        print(f"{a} -> {b}: {n}")
    if steps is not None:
        print("walk:", " > ".join(steps))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
