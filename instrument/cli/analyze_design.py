"""``diffuserlab analyze design``: predicted resolution of a microlens mask design.

A user's own mask (random or regular microlenses of a given size and focal length,
at a given distance from the sensor) is ray-traced at 12 field positions per depth
(:mod:`recon.optics.design_masks`) and the inner-product predictor of Sec. 6.4 /
Fig. 6.4a (:func:`recon.analysis.design.design_resolution`) gives, per position,
the lateral resolution (shift at which the PSF's normalised inner product with its
shifted copy falls to 0.8), the axial resolution (the same with a scaled copy) and
the ghost inner product (the largest inner product with a copy shifted by more
than three resolutions: near 1 for a periodic array, whose PSF shifted by one
period is a copy of itself). Writes ``OUT/design.png`` (resolution against depth
with the range over the field positions, as Fig. 6.4a, and the on-axis PSF) and
``OUT/design.json``; refuses existing outputs without ``--overwrite``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from diffuserlab.errors import InputError

from .common import floats

__all__ = ["add_parser", "run_design"]


def add_parser(asub: argparse._SubParsersAction) -> None:
    """Add ``design`` to the ``analyze`` subparsers (called by :mod:`.analyze`)."""
    p = asub.add_parser(
        "design", help="predicted lateral/axial resolution and ghosts of a microlens mask "
        "design at 12 field positions (Sec. 6.4, Fig. 6.4a)",
        description="Ray-trace a random (default) or regular microlens mask in front of a "
        "sensor patch and predict its resolution with the inner-product criterion of Sec. "
        "6.4 (threshold 0.8) at 12 field positions per depth.")
    p.add_argument("--lenslet-um", type=float, default=250.0,
                   help="lenslet size (lattice period / mean spacing), um (default 250)")
    p.add_argument("--focal-mm", type=float, default=1.5,
                   help="lenslet focal length, mm (default 1.5)")
    p.add_argument("--distance-mm", type=float, default=3.8,
                   help="mask-to-sensor distance d, mm (default 3.8)")
    p.add_argument("--z-mm", default=None,
                   help="comma-separated object depths in front of the mask, mm (default: "
                   "the plane the lenslets image, 1/(1/f - 1/d))")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--random", dest="layout", action="store_const", const="random",
                      help="random lenslet layout (the random microlens diffuser, default)")
    kind.add_argument("--regular", dest="layout", action="store_const", const="regular",
                      help="square lattice (a regular microlens array)")
    p.set_defaults(layout="random")
    p.add_argument("--pitch-um", type=float, default=5.8,
                   help="sensor pixel pitch, um (default 5.8: the IMX290 binned 2 x 2, "
                   "Sec. 6.4)")
    p.add_argument("--sensor-px", type=int, default=384,
                   help="side of the square sensor patch, px (default 384; it should hold "
                   "a few lenslet images)")
    p.add_argument("--wavelength-nm", type=float, default=520.0,
                   help="emission wavelength for the diffraction blur, nm (default 520)")
    p.add_argument("--falloff-deg", type=float, default=13.0,
                   help="sigma of the pixels' Gaussian angular response, deg (default 13; "
                   "0: none)")
    p.add_argument("--threshold", type=float, default=0.8,
                   help="inner product below which points are resolvable (default 0.8, "
                   "Sec. 6.4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random layout")
    p.add_argument("--out", default="out/analysis",
                   help="directory for design.png and design.json (default out/analysis)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace design.png and design.json of an earlier run")
    p.set_defaults(handler=run_design)


def _checked(args: argparse.Namespace):
    """The MaskDesign and depths of the options; ValueError naming a bad option."""
    from recon.optics.design_masks import MaskDesign

    for name, unit in (("lenslet_um", "um"), ("focal_mm", "mm"), ("distance_mm", "mm"),
                       ("pitch_um", "um"), ("wavelength_nm", "nm")):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"--{name.replace('_', '-')} must be finite and > 0 {unit}, "
                             f"got {v:g}")
    if not (math.isfinite(args.falloff_deg) and args.falloff_deg >= 0):
        raise InputError(f"--falloff-deg must be >= 0 (0: none), got {args.falloff_deg:g}")
    if not 0 < args.threshold < 1:
        raise InputError(f"--threshold must be between 0 and 1 (exclusive), got "
                         f"{args.threshold:g}; e.g. 0.8")
    if not 32 <= args.sensor_px <= 2048:
        raise InputError(f"--sensor-px must be 32 .. 2048, got {args.sensor_px}")
    if args.focal_mm >= args.distance_mm:
        raise InputError(f"--focal-mm {args.focal_mm:g} must be below --distance-mm "
                         f"{args.distance_mm:g}: lenslets that do not focus before the sensor "
                         "image no object plane onto it")
    design = MaskDesign(args.layout, (args.sensor_px, args.sensor_px), args.pitch_um,
                        args.distance_mm, args.lenslet_um, args.focal_mm,
                        args.wavelength_nm, args.falloff_deg or None, seed=args.seed)
    if args.z_mm is None:
        depths = [design.conjugate_z_mm]
    else:
        depths = floats(args.z_mm, "--z-mm")
        bad = [z for z in depths if not (math.isfinite(z) and z > 0)]
        if bad or not depths:
            raise InputError(f"--z-mm {args.z_mm!r}: give depths > 0 mm in front of the mask, "
                             "e.g. 2.0,2.5,3.0")
    period_px = args.lenslet_um * (1 + args.distance_mm / min(depths)) / args.pitch_um
    if period_px > args.sensor_px / 3:
        raise InputError(f"--sensor-px {args.sensor_px} holds less than 3 lenslet images "
                         f"({period_px:.0f} px apart at z = {min(depths):g} mm); use at "
                         f"least {math.ceil(3 * period_px)} px or a coarser --pitch-um")
    return design, sorted(depths)


def run_design(args: argparse.Namespace) -> int:
    """Run ``analyze design``: write ``OUT/design.png`` and ``OUT/design.json``, print a
    line per depth; returns 0 (bad input: one line, exit 2, through the boundary)."""
    from recon.analysis.design import design_resolution

    from ..atomic import write_json
    from ..writer.figures import save_figure
    from ..writer.guards import check_outputs

    design, depths = _checked(args)
    out = Path(args.out)
    png, js = out / "design.png", out / "design.json"
    check_outputs([png, js], None, args.overwrite, directory=out)
    result = design_resolution(design, depths, threshold=args.threshold)
    fig = _plot(design, result)
    save_figure(fig, png, dpi=100)
    record = {"analysis": "design", "layout": args.layout, "lenslet_um": args.lenslet_um,
              "focal_mm": args.focal_mm, "distance_mm": args.distance_mm,
              "pitch_um": args.pitch_um, "sensor_px": args.sensor_px,
              "wavelength_nm": args.wavelength_nm, "falloff_deg": args.falloff_deg,
              "seed": args.seed, **result, "output_png": str(png), "output_json": str(js)}
    write_json(js, record)
    for d in result["depths"]:
        s = d["summary"]
        print(f"z = {d['z_mm']:.3g} mm: lateral {s['lateral_um']['mean']:.1f} um "
              f"({s['lateral_um']['min']:.1f}-{s['lateral_um']['max']:.1f}), axial "
              f"{s['axial_um']['mean']:.0f} um ({s['axial_um']['min']:.0f}-"
              f"{s['axial_um']['max']:.0f}), ghost inner product "
              f"{s['ghost_inner_product']['mean']:.2f} (max {s['ghost_inner_product']['max']:.2f})"
              " over 12 field positions")
    print(f"wrote {png} and {js}")
    return 0


def _plot(design, result):
    """Fig. 6.4a-style plot: lateral and axial resolution vs depth (mean, range over
    the field positions), the ghost inner product, and the on-axis PSF."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(16.0, 4.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(1, 4, k + 1) for k in range(4)]
    z = np.array([d["z_mm"] for d in result["depths"]])
    for ax, key, label in ((axes[0], "lateral_um", "lateral resolution (um)"),
                           (axes[1], "axial_um", "axial resolution (um)"),
                           (axes[2], "ghost_inner_product", "ghost inner product")):
        mean = np.array([d["summary"][key]["mean"] for d in result["depths"]])
        lo = np.array([d["summary"][key]["min"] for d in result["depths"]])
        hi = np.array([d["summary"][key]["max"] for d in result["depths"]])
        ax.fill_between(z, lo, hi, alpha=0.3, label="range over 12 field positions")
        ax.plot(z, mean, "o-", label="mean")
        ax.set(xlabel="depth z (mm)", ylabel=label)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"inner product {result['threshold']:g} (Sec. 6.4)")
    axes[0].legend(fontsize=8)
    axes[1].set_title("scaled PSF (axial)")
    axes[2].axhline(result["threshold"], color="C1", ls="--", lw=0.8)
    axes[2].set(ylim=(0, 1.05), title="ghosts: inner product, shift > 3 res.")
    mid = result["depths"][len(z) // 2]["z_mm"]
    psf = design.psf((0.0, 0.0, mid), 1)
    axes[3].imshow(psf ** 0.5, cmap="gray")
    axes[3].set(title=f"{design.kind} lenslets: on-axis PSF\nat {mid:.3g} mm (sqrt)",
                xticks=[], yticks=[])
    return fig
