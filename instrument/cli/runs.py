"""``diffuserlab runs {show,verify,export,upgrade,import-psf,list}``: look into, check and
convert run stores (``list``: :mod:`instrument.cli.runs_list`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from diffuserlab.errors import InputError

from ..options import check_pitch_um
from .common import floats

__all__ = ["add_subcommands", "format_summary", "run", "verify"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``runs`` (with ``show``, ``verify``, ``export``, ``upgrade``, ``import-psf``) to the
    subparsers."""
    rp = sub.add_parser("runs", help="show, export or import runs (Zarr stores)")
    rsub = rp.add_subparsers(dest="runs_command", required=True)
    sp = rsub.add_parser("show", help="plan, status, progress, times, products of a run")
    sp.add_argument("run", help="run store directory (RUN.zarr)")
    sp.add_argument("--json", action="store_true", help="print the full summary as JSON")
    vp = rsub.add_parser("verify", help="check every stored frame and product against its "
                         "checksum; exit 0 intact, 1 damaged, 2 unreadable")
    vp.add_argument("run", help="run store directory (RUN.zarr)")
    ep = rsub.add_parser("export", help="write a product (default psf_stack) or the frames "
                         "as TIFF: an ImageJ hyperstack (Fiji) or an OME-TIFF, with axes, "
                         "pixel size, spacing and units")
    ep.add_argument("run")
    ep.add_argument("--out", required=True, help="TIFF file to write (.tif or .tiff; "
                    ".ome.tif for an OME-TIFF)")
    ep.add_argument("--format", choices=("auto", "imagej", "ome"), default="auto",
                    help="imagej: an ImageJ hyperstack; ome: an OME-TIFF; auto (default): "
                    "OME-TIFF for a .ome.tif name, else ImageJ")
    ep.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    group = ep.add_mutually_exclusive_group()
    group.add_argument("--product", default="psf_stack", help="product name (default "
                       "psf_stack)")
    group.add_argument("--frames", action="store_true",
                       help="export the raw frames instead: the stored frames whose "
                       "checksums hold (a killed recording's, a damaged frame left out; "
                       "each skipped range is listed)")
    up = rsub.add_parser("upgrade", help="bring a run written before to the OME-Zarr 0.5 "
                         "layout in place: axis names, units, scales, each image product "
                         "its own image group; no data chunk is touched")
    up.add_argument("run", help="run store directory (RUN.zarr)")
    ip = rsub.add_parser("import-psf", help="store a PSF stack (TIFF or .npy) as a run")
    ip.add_argument("stack", help="TIFF or .npy, (depths, rows, cols) or one 2D PSF")
    ip.add_argument("--depths", default=None,
                    help="comma-separated depths in mm, one per plane (unless recorded)")
    ip.add_argument("--out", required=True, help="run store to create (RUN.zarr)")
    ip.add_argument("--pitch-um", type=float, default=None,
                    help="the stack's pixel pitch on the sensor, um (camera pitch times "
                    "binning): its pixel size in the run; default none (no unit)")
    ip.add_argument("--note", default="")
    ip.add_argument("--overwrite", action="store_true")
    rp.set_defaults(handler=run)
    from .runs_list import add_list

    add_list(rsub)  # its own handler


def format_summary(s: dict) -> str:
    """Human-readable lines of :meth:`RunStore.summary`."""
    from ..runs.runstore_records import VIDEO_PLAN

    problems = s.get("problems", [])
    state = f"{s['status']}, DAMAGED" if problems else s["status"]
    lines = [
        f"run      {s['path']}",
        f"plan     {s['plan']}  ({state})",
        f"progress {s['points_done']}/{s['points']} points, {s['frames_done']}/{s['frames']} "
        f"frames of {s['frame_shape'][0]}x{s['frame_shape'][1]}",
        f"times    created {s['created_utc']}, started {s['started_utc']}, "
        f"ended {s['ended_utc']}",
        f"software diffuserlab {s['software_version']} (run schema {s['schema_version']})",
    ]
    if s["note"]:
        lines.append(f"note     {s['note']}")
    for r in s["resumes"]:
        lines.append(f"resumed  {r['utc']} at point {r['point']}")
    if s["error"]:
        lines.append(f"error    {s['error']}")
    for w in s["warnings"]:
        lines.append(f"warning  {w}")
    for p in problems:
        lines.append(f"damaged  {p}")
    if s.get("lock"):
        lines.append(f"locked   {s['lock']}")
    if not s.get("checksums", True):
        lines.append("checks   none: this run (schema 1) carries no checksums")
    for name, info in s["products"].items():
        planes = (f"  ({info['planes_done']} of {info['shape'][0]} frames done)"
                  if "planes_done" in info else "")
        lines.append(f"product  {name}: {'x'.join(map(str, info['shape']))} {info['dtype']}"
                     f"{planes}")
    coords = s.get("coords") or {}
    if coords:
        lines.append("coords   " + ", ".join(_coord_text(n, c) for n, c in coords.items()))
    for key, value in s["summary"].items():
        text = json.dumps(value)
        lines.append(f"result   {key} = {text if len(text) < 100 else text[:97] + '...'}")
    if s["plan"] == VIDEO_PLAN:
        if s["status"] == "recording" and "is writing it" not in (s.get("lock") or ""):
            lines.append(f"ended    killed while recording: its {s['frames_done']} stored "
                         "frames are kept (runs export --frames and recon-run use them)")
    elif s["status"] in ("aborted", "failed", "running"):
        lines.append(f"resume   diffuserlab calibrate resume {s['path']} BENCH.toml [--simulate]")
    return "\n".join(lines)


def _coord_text(name: str, info: dict) -> str:
    """``source_stage.z [mm] (z)``: a coordinate with its stored unit and dimension
    name (``[-]`` dimensionless, ``[?]`` a run written before units were stored)."""
    unit = info.get("unit")
    unit = "?" if unit is None else unit or "-"
    dim = info.get("dim")
    return f"{name} [{unit}]" + (f" ({dim})" if dim and dim != name.rpartition(".")[2]
                                 else "")


def verify(path: str) -> int:
    """``runs verify``: print one line per damaged frame or product and a summary.

    Parameters
    ----------
    path : str
        The run store (RUN.zarr).

    Returns
    -------
    int
        0 when every done frame and product matches its checksum, 1 when damaged.

    Raises
    ------
    instrument.runs.runstore.RunStoreError
        No readable run at ``path`` (exit 2 through :func:`instrument.cli.main`).
    """
    from ..runs.run_description import description_note
    from ..runs.run_layout import layout_note
    from ..runs.runstore import RunStore

    store = RunStore.open(path)
    problems = store.verify()
    for p in problems:
        print(p)
    checked = (f"{int(store.done_or_none().sum())} frames and {len(store.products())} "
               f"products of {store.path}")
    for note in (layout_note(store.path), description_note(store.path)):
        if note:
            print(note)
    if not store.has_checksums:
        print(f"{store.path} (run schema 1) carries no checksums: only unreadable chunks "
              "can be found, not deleted or altered ones")
    if problems:
        print(f"damaged: {len(problems)} problem(s) in {checked}; each line above says how "
              "to repair it")
        return 1
    print(f"intact: {checked} verified")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run a ``runs`` subcommand; 0 on success (a RunStoreError or ValueError exits 2
    through :func:`instrument.cli.main`)."""
    from ..runs.runstore import RunStore
    from ..writer.guards import check_outputs

    if args.runs_command == "show":
        summary = RunStore.open(args.run).summary()
        print(json.dumps(summary, indent=1) if args.json else format_summary(summary))
    elif args.runs_command == "verify":
        return verify(args.run)
    elif args.runs_command == "export":
        check_outputs([args.out], {"run": args.run}, args.overwrite)
        if Path(args.out).suffix.lower() not in (".tif", ".tiff"):
            raise InputError(f"--out {args.out}: runs export writes a TIFF; give a .tif or "
                             ".tiff name")
        from ..runs.stacks import export_tiff

        out, skipped = export_tiff(args.run, args.out,
                                   product=None if args.frames else args.product,
                                   fmt=args.format)
        print(f"wrote {out}")
        for line in skipped:
            print(f"skipped  {line}")
    elif args.runs_command == "upgrade":
        store = RunStore.open(args.run, "r+")
        changed = store.upgrade()
        named, moved = changed["named"], changed["moved"]
        print(f"{store.path}: named the dimensions of {len(named)} arrays"
              + (f" ({', '.join(named)})" if named else "")
              + f"; moved {len(moved)} image products into their own groups"
              + (f" ({', '.join(f'products/{n}/0' for n in moved)})" if moved else "")
              + "; OME-Zarr 0.5 description written (no data chunk touched)")
    elif args.runs_command == "import-psf":
        check_outputs([args.out], {"stack": args.stack}, True)  # existing: the store decides
        depths = None if args.depths is None else floats(args.depths, "--depths")
        check_pitch_um(args.pitch_um)
        from ..runs.stacks import import_psf_stack

        store = import_psf_stack(args.stack, args.out, depths_mm=depths, note=args.note,
                                 overwrite=args.overwrite, pitch_um=args.pitch_um)
        print(f"stored {store.n_points} depths in {store.path}")
    return 0
