"""Draw the measured map of the code: the layers, the parts of each package sized by
their lines, the imports between packages, and the walk of one ``diffuserlab recon``.

Everything drawn is measured from the checkout when the script runs (``ast`` for the
imports and lines, ``sys.setprofile`` for the walk), so the picture cannot drift from
the code. Used for docs/images/architecture.png (docs/architecture.md)::

    python scripts/architecture_map.py docs/images/architecture.png

The walk needs the tutorial sample (``../shared/data/diffusercam-tutorial`` beside the
repository, or ``--sample DIR`` with ``psf_sample.tif`` and ``rawdata_hand_sample.tif``);
without it the walk panel says so and the map is drawn alone.
"""

from __future__ import annotations

import argparse
import ast
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


def walk(sample: Path) -> list[str]:
    """The packages one ``diffuserlab recon`` moves between, in order, each step named by
    the part it enters (a profile of every Python call made in our packages, imports
    left out)."""
    sys.path.insert(0, str(REPO))
    from instrument.cli import main

    seen: list[str] = []
    handler = str(REPO / "instrument" / "cli" / "recon.py")

    def profile(frame, event, arg):
        if event != "call":
            return
        path = frame.f_code.co_filename
        if not seen:  # from the command's handler on (the parser's building left out)
            if path != handler or frame.f_code.co_name != "run":
                return
        try:
            rel = Path(path).resolve().relative_to(REPO)
        except ValueError:
            return
        if rel.parts[0] not in PACKAGES or rel.parts[0] == "diffuserlab" \
                or frame.f_code.co_name == "<module>":  # an import, not the work
            return
        part = part_of(module_name(REPO / rel))
        # a step is a change of package, named by the part it enters
        if not seen or seen[-1].split(".")[0] != rel.parts[0]:
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


def draw(out: Path, lines: Counter, edges: Counter, steps: list[str] | None) -> None:
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
    for (a, b), n in sorted(edges.items(), key=lambda e: e[1]):
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
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("--sample", type=Path,
                        default=REPO.parent / "shared" / "data" / "diffusercam-tutorial")
    args = parser.parse_args(argv)
    lines, edges = measure()
    steps = walk(args.sample) if (args.sample / "psf_sample.tif").exists() else None
    draw(args.out, lines, edges, steps)
    for (a, b), n in sorted(edges.items()):
        print(f"{a} -> {b}: {n}")
    if steps is not None:
        print("walk:", " > ".join(steps))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
