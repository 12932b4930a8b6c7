"""Trace one ``diffuserlab recon`` and one recording through the project's modules
(docs/architecture.md, "The rooms, traced").

Run from a repository root (or give --repo): profiles, with ``sys.setprofile``, every
Python call made in the project's packages from the command's handler on (imports and
the parser's building left out; every thread) and writes, per command, JSON with

- ``modules``: each module of ours the run entered, in first-entry order, with its
  number of calls;
- ``arrows``: caller module -> callee module (distinct pairs, with counts; a call's
  caller is the nearest frame in our packages);
- ``walk``: the steps of scripts/architecture_map.py's walk (a move to another
  package, named by the part it enters: ``instrument.X`` where X is a top-level
  module or subpackage of instrument);
- ``rooms``: the same walk at the depth of instrument's rooms (top-level modules or
  subpackages), every change of room counted (instrument -> instrument too);
- a summary: modules, instrument modules, distinct arrows, room changes.

    python scripts/trace_run.py --out DIR [--repo ROOT] [--sample DIR] [--only recon|record]
    python scripts/trace_run.py --compare BEFORE_DIR AFTER_DIR   (the docs' tables)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
from collections import Counter
from pathlib import Path

PACKAGES = ("benchmarks", "soak", "gui", "calibration_routines", "instrument", "drivers",
            "recon", "diffuserlab")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, help="the folder of the traces (NAME.json, NAME.txt)")
    ap.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"),
                    help="print the Markdown comparison of two such folders instead")
    ap.add_argument("--repo", type=Path, default=Path.cwd())
    ap.add_argument("--sample", type=Path, default=None)
    ap.add_argument("--only", choices=("recon", "record"), default=None)
    args = ap.parse_args()
    if args.compare:
        print(compare(*args.compare))
        return 0
    if args.out is None:
        ap.error("--out DIR (or --compare BEFORE AFTER)")
    repo = args.repo.resolve()
    sample = args.sample or repo.parent / "shared" / "data" / "diffusercam-tutorial"
    sys.path.insert(0, str(repo))
    os.chdir(repo)
    from instrument.cli import main as cli_main

    mod_of_file: dict[str, str | None] = {}

    def module_of(path: str) -> str | None:
        if path in mod_of_file:
            return mod_of_file[path]
        name = None
        try:
            rel = Path(path).resolve().relative_to(repo)
        except ValueError:
            rel = None
        if rel is not None and rel.parts and rel.parts[0] in PACKAGES and rel.suffix == ".py":
            bits = list(rel.with_suffix("").parts)
            if bits[-1] == "__init__":
                bits = bits[:-1]
            name = ".".join(bits)
        mod_of_file[path] = name
        return name

    def room(mod: str) -> str:
        bits = mod.split(".")
        return ".".join(bits[:2])

    def trace(argv: list[str], handler_file: str, handler: str) -> dict:
        calls: Counter = Counter()
        order: list[str] = []
        arrows: Counter = Counter()
        walk: list[str] = []
        rooms: list[str] = []
        started = [False]
        lock = threading.Lock()

        def profile(frame, event, arg):
            if event != "call":
                return
            code = frame.f_code
            if code.co_name == "<module>":
                return
            mod = module_of(code.co_filename)
            if mod is None or mod == "instrument":  # instrument/__init__: its import finder
                return
            if not started[0]:
                if code.co_filename != handler_file or code.co_name != handler:
                    return
                started[0] = True
            caller = None
            f = frame.f_back
            while f is not None:
                caller = module_of(f.f_code.co_filename)
                if caller is not None and f.f_code.co_name != "<module>":
                    break
                caller = None
                f = f.f_back
            with lock:
                if mod not in calls:
                    order.append(mod)
                calls[mod] += 1
                if caller is not None and caller != mod:
                    arrows[(caller, mod)] += 1
                if mod.split(".")[0] != "diffuserlab":
                    part = room(mod)
                    if not walk or walk[-1].split(".")[0] != part.split(".")[0]:
                        walk.append(part)
                    if not rooms or rooms[-1] != part:
                        rooms.append(part)

        sys.setprofile(profile)
        threading.setprofile(profile)
        try:
            status = cli_main(argv)
        finally:
            sys.setprofile(None)
            threading.setprofile(None)
        inst = [m for m in order if m.startswith("instrument")]
        return {
            "argv": argv, "status": status,
            "modules": [[m, calls[m]] for m in order],
            "arrows": [[a, b, n] for (a, b), n in sorted(arrows.items())],
            "walk": walk, "rooms": rooms,
            "summary": {"modules": len(order), "instrument_modules": len(inst),
                        "instrument_rooms": len({room(m) for m in inst}),
                        "arrows": len(arrows),
                        "instrument_arrows": sum(1 for a, b in arrows
                                                 if a.startswith("instrument")
                                                 and b.startswith("instrument")),
                        "walk_moves": len(walk) - 1, "room_changes": len(rooms) - 1},
        }

    args.out.mkdir(parents=True, exist_ok=True)
    import instrument.cli as cli_pkg

    cli_dir = Path(cli_pkg.__file__).parent
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        if args.only in (None, "recon"):
            results["recon"] = trace(
                ["recon", "--psf", str(sample / "psf_sample.tif"),
                 "--raw", str(sample / "rawdata_hand_sample.tif"), "--method", "admm",
                 "--iterations", "5", "--bin", "4", "--out", str(Path(tmp) / "hand.tif")],
                str(cli_dir / "recon.py"), "run")
        if args.only in (None, "record"):
            results["record"] = trace(
                ["capture", "video", "--simulate", "--seed", "1", "--frames", "8",
                 "--out", str(Path(tmp) / "run.zarr")],
                str(cli_dir / "capture.py"), "run_video")
    for name, data in results.items():
        (args.out / f"{name}.json").write_text(json.dumps(data, indent=1) + "\n")
        shown = " ".join(a if "/" not in a else Path(a).name for a in data["argv"])
        lines = [f"# {name}: diffuserlab {shown}",
                 f"exit status {data['status']}; " + ", ".join(
                     f"{k} {v}" for k, v in data["summary"].items()),
                 "", "walk (package moves): " + " > ".join(data["walk"]),
                 "", "rooms (every change of instrument room or package): "
                 + " > ".join(data["rooms"]), "", "instrument modules entered, in order (calls):"]
        lines += [f"  {m} ({n})" for m, n in data["modules"] if m.startswith("instrument")]
        lines += ["", "arrows between instrument modules (calls):"]
        lines += [f"  {a} -> {b} ({n})" for a, b, n in data["arrows"]
                  if a.startswith("instrument") and b.startswith("instrument")]
        (args.out / f"{name}.txt").write_text("\n".join(lines) + "\n")
        print("\n".join(lines[:6]))
    return 0


def _part(mod):
    return ".".join(mod.split(".")[:2])


def _facts(d):
    inst = [m for m, _ in d["modules"] if m.startswith("instrument.")]
    parts = []
    for m in inst:
        p = _part(m)
        if p not in parts:
            parts.append(p)
    arrows = {(a, b) for a, b, _ in d["arrows"]
              if a.startswith("instrument.") and b.startswith("instrument.")}
    part_arrows = {(_part(a), _part(b)) for a, b in arrows if _part(a) != _part(b)}
    pkg_walk = d["walk"]
    return {"modules": inst, "parts": parts, "arrows": arrows, "part_arrows": part_arrows,
            "walk": pkg_walk}


def compare(before: Path, after: Path) -> str:
    """The Markdown tables of docs/architecture.md's \"The rooms, traced\"."""
    out = []
    for name in ("recon", "record"):
        b = _facts(json.loads((before / f"{name}.json").read_text()))
        a = _facts(json.loads((after / f"{name}.json").read_text()))
        argv = json.loads((after / f"{name}.json").read_text())["argv"]
        shown = " ".join(Path(x).name if "/" in x else x for x in argv)
        out.append(f"**`diffuserlab {shown}`**\n")
        out.append("| | before | after |\n|---|---:|---:|")
        rows = (("modules of `instrument` entered", "modules", 0),
                ("... in top-level parts of `instrument`", "parts", 0),
                ("calls between two modules of `instrument` (distinct caller -> callee)",
                 "arrows", 0),
                ("... of them between two parts", "part_arrows", 0),
                ("moves between packages (the map's walk)", "walk", 1))
        for label, key, less in rows:
            out.append(f"| {label} | {len(b[key]) - less} | {len(a[key]) - less} |")
        out.append("")
        out.append("Parts entered, in order: before " + " > ".join(
            f"`{p.split('.', 1)[1]}`" for p in b["parts"]) + "; after " + " > ".join(
            f"`{p.split('.', 1)[1]}`" for p in a["parts"]) + ".")
        out.append("")
        out.append("Calls between parts, after: " + ", ".join(
            f"{x.split('.', 1)[1]} -> {y.split('.', 1)[1]}"
            for x, y in sorted(a["part_arrows"])) + ".")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
