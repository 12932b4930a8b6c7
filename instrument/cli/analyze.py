"""``diffuserlab analyze {resolution,similarity,condition,distinguish,grid,fov}``: a PSF stack.

Each analysis reads a PSF stack (a run store, a TIFF stack with its depths or a
TIFF / ``.npy`` stack with ``--depths``; sorted by depth), runs the
:mod:`recon.analysis` functions of G. Kuo's dissertation (2020) on it (the per-stack
numbers are :mod:`recon.analysis.reports`, callable from a notebook; the plots are
drawn here) and writes ``OUT/<analysis>.png`` (a plot) and ``OUT/<analysis>.json``
(the numbers):

* ``resolution``: per depth, the 70 % autocorrelation half width (Sec. 3.2) in
  sensor pixels and in object space (m = d/z), the 0.8 inner-product shift and
  scale (Sec. 6.4, Fig. 6.4), the hyperfocal distance and the depth of field;
* ``similarity``: App. A.2 / Fig. A.3: central autocorrelation lines of the
  nearest and farthest PSF, their cross-correlation, and the inner products of
  one PSF (default the middle) with all others;
* ``condition``: Fig. 4.5: local condition number of k neighbouring point sources
  (k = 2 .. --k-max) at given separations, laterally (``--separations-px``) or,
  with ``--axial``, across depth planes (``--separations-planes``; optionally an
  x-z grid with ``--xz-px``);
* ``distinguish``: Sec. 4.4 / Fig. 4.3-4.4: two-point and 16-point (4 x 4)
  distinguishability by reconstruction with the regulariser off (20 % dip);
* ``grid``: the reconstruction grid (depth planes uniform in 1/z and lateral
  binning) that Nyquist-samples the measured resolution, with the reasons;
* ``fov``: the angular field of view of Eq. 3.12 / Eq. 4.6 from the sensor's
  angular cutoff, the diffuser's deflection, the sensor width (stack shape times
  pitch) and the PSF width (the stack's support).

``analyze design`` (:mod:`.analyze_design`) reads no stack: it simulates a
microlens mask design and predicts its resolution (Sec. 6.4, Fig. 6.4a).

PSFs should be background-removed (run stores' ``psf_stack`` is); for raw stacks
pass ``--remove-background N`` (DCT, Sec. 6.2). Bad input exits with status 2 and
one line.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING

from diffuserlab.errors import InputError
from diffuserlab.jsonio import jsonable

from ..options import check_pitch_um
from .common import floats

if TYPE_CHECKING:  # pragma: no cover  (numpy is imported where the analyses run)
    import numpy as np

__all__ = ["ANALYSES", "add_subcommands", "run", "run_analysis"]

log = logging.getLogger(__name__)

#: The analyses of ``diffuserlab analyze``.
ANALYSES = ("resolution", "similarity", "condition", "distinguish", "grid", "fov")


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``analyze`` (with its five analyses) to the ``diffuserlab`` subparsers.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subparsers of the ``diffuserlab`` parser. The defaults carry
        ``handler=run``, so :func:`instrument.cli.main` dispatches to :func:`run`.
    """
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--psf-stack", required=True,
                        help="PSF stack: run store (RUN.zarr), TIFF stack, or TIFF/.npy with "
                        "--depths")
    common.add_argument("--psf-product", default="psf_stack",
                        help="which stack of a run store (default psf_stack)")
    common.add_argument("--depths", default=None,
                        help="comma-separated depths in mm, one per plane (unless recorded)")
    common.add_argument("--pitch-um", type=float, default=None,
                        help="sensor pixel pitch of the stack as stored, um")
    common.add_argument("--d-mm", type=float, default=None,
                        help="diffuser-to-sensor distance d, mm")
    common.add_argument("--bin", type=int, default=1, dest="bin_factor",
                        help="box-bin every plane first (the pitch is multiplied by it)")
    common.add_argument("--remove-background", type=int, default=0, metavar="N",
                        help="remove background by zeroing the N x N lowest DCT "
                        "coefficients of each plane (Sec. 6.2; 0: off, default)")
    common.add_argument("--threshold", type=float, default=0.8,
                        help="inner-product threshold of distinguishability (Sec. 6.4)")
    common.add_argument("--out", default="out/analysis",
                        help="directory for <analysis>.png and <analysis>.json")
    common.add_argument("--overwrite", action="store_true",
                        help="replace <analysis>.png and <analysis>.json of an earlier run")

    ap = sub.add_parser("analyze", help="system analysis of a PSF stack (plot + JSON)")
    asub = ap.add_subparsers(dest="analysis", required=True)
    rp = asub.add_parser("resolution", parents=[common],
                         help="lateral resolution (70%% autocorrelation, 0.8 inner product), "
                         "axial scale, hyperfocal distance, depth of field")
    rp.add_argument("--level", type=float, default=0.7,
                    help="autocorrelation level of the half width (Sec. 3.2)")
    sp = asub.add_parser("similarity", parents=[common],
                         help="PSF similarity across the stack (App. A.2, Fig. A.3)")
    sp.add_argument("--index", type=int, default=None,
                    help="plane (in depth order) compared with all others; default middle")
    cp = asub.add_parser("condition", parents=[common],
                         help="local condition number vs number of sources (Fig. 4.5)")
    cp.add_argument("--depth", type=float, default=None, dest="depth_mm",
                    help="depth (mm) of the PSF to use; default the middle plane")
    cp.add_argument("--separations-px", default="1,2,3,4,6,8",
                    help="comma-separated source separations on the sensor, px")
    cp.add_argument("--k-max", type=int, default=16, help="largest number of sources")
    cp.add_argument("--layout", choices=("line", "grid"), default="line")
    cp.add_argument("--axis", choices=("x", "y"), default="x")
    cp.add_argument("--axial", action="store_true",
                    help="sources at consecutive depth planes instead of side by side (the "
                    "first at --depth, default centred in the stack)")
    cp.add_argument("--separations-planes", default="1,2,3",
                    help="with --axial: comma-separated plane steps between neighbouring "
                    "sources (a stack uniform in 1/z: steps of its 1/z spacing)")
    cp.add_argument("--xz-px", type=float, default=0.0,
                    help="with --axial: lateral spacing (px, along --axis) of an x-z grid of "
                    "sources (Fig. 4.4's 4 x 4); 0 (default): one line along z")
    dp = asub.add_parser("distinguish", parents=[common],
                         help="two-point and 16-point distinguishability by reconstruction "
                         "(Sec. 4.4, 20%% dip)")
    dp.add_argument("--depth", type=float, default=None, dest="depth_mm",
                    help="depth (mm) of the PSF to use; default the middle plane")
    dp.add_argument("--separations-px", default="1,2,3,4,6,8",
                    help="comma-separated source separations on the sensor, px")
    dp.add_argument("--iterations", type=int, default=300,
                    help="FISTA iterations, regulariser off (default 300)")
    dp.add_argument("--axis", choices=("x", "y"), default="x")
    gp = asub.add_parser("grid", parents=[common],
                         help="recommended depth planes and lateral binning")
    gp.add_argument("--scene-range", default=None, metavar="ZMIN,ZMAX",
                    help="depth span of the scene, mm (default: the calibrated range)")
    fp = asub.add_parser("fov", parents=[common], help="angular field of view (Eq. 3.12/4.6)")
    fp.add_argument("--alpha-c-deg", type=float, default=None,
                    help="sensor angular cutoff (response at 20%% of normal incidence), deg")
    fp.add_argument("--beta-deg", type=float, default=0.0,
                    help="maximum deflection angle of the diffuser, deg (default 0)")
    fp.add_argument("--support-energy", type=float, default=0.99,
                    help="PSF width = extent holding this central fraction of its energy "
                    "along each axis (default 0.99)")
    ap.set_defaults(handler=run)
    from .analyze_design import add_parser as add_design

    add_design(asub)  # analyze design: a mask design, not a PSF stack


# ----------------------------------------------------------------------------- input


def _need(args: argparse.Namespace, *names: str) -> None:
    for name in names:
        value = getattr(args, name)
        if value is None:
            raise InputError(f"analyze {args.analysis} needs --{name.replace('_', '-')}")
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"--{name.replace('_', '-')} must be finite and > 0, got {value}")


def _fraction(args: argparse.Namespace, name: str) -> None:
    value = getattr(args, name, None)
    if value is not None and not 0 < value < 1:
        raise InputError(f"--{name.replace('_', '-')} must be between 0 and 1 (exclusive), "
                         f"got {value}")


def _check_options(args: argparse.Namespace) -> None:
    """Refuse option values no analysis can use, before any file is read or written."""
    if args.bin_factor < 1:
        raise InputError(f"--bin must be >= 1, got {args.bin_factor}")
    check_pitch_um(args.pitch_um)
    if args.remove_background < 0:
        raise InputError(f"--remove-background must be >= 0 (0: off), got "
                         f"{args.remove_background}")
    for name in ("threshold", "level"):
        _fraction(args, name)
    depth = getattr(args, "depth_mm", None)
    if depth is not None and not (math.isfinite(depth) and depth > 0):
        raise InputError(f"--depth must be finite and > 0 mm, got {depth}")
    xz = getattr(args, "xz_px", 0.0)
    if not (math.isfinite(xz) and xz >= 0):
        raise InputError(f"--xz-px must be finite and >= 0 (0: one line along z), got {xz}")


def _load(args: argparse.Namespace) -> tuple[np.ndarray, np.ndarray, dict]:
    """The stack sorted by depth (binned, background removed if asked), depths, header."""
    from recon.analysis import prepare_stack

    from ..runs.stacks import load_psf_stack

    depths = None if args.depths is None else floats(args.depths, "--depths")
    stack, z, _ = load_psf_stack(args.psf_stack, depths, product=args.psf_product)
    shape_in = list(stack.shape)
    stack, z = prepare_stack(stack, z, bin_factor=args.bin_factor,
                             remove_background=args.remove_background)
    pitch_um = None if args.pitch_um is None else args.pitch_um * args.bin_factor
    header = {"analysis": args.analysis, "psf_stack": str(args.psf_stack),
              "psf_product": args.psf_product, "stack_shape_in": shape_in,
              "stack_shape": list(stack.shape), "bin_factor": args.bin_factor,
              "remove_background_dct": args.remove_background, "depths_mm": z,
              "pitch_um": pitch_um, "d_mm": args.d_mm, "threshold": args.threshold}
    return stack, z, header


def _figure(n_panels: int):
    """An Agg figure with ``n_panels`` axes side by side (no pyplot, no display)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0 * n_panels, 4.0), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, [fig.add_subplot(1, n_panels, k + 1) for k in range(n_panels)]


# ----------------------------------------------------------------------------- analyses


def _resolution(args, stack, z, header) -> tuple[dict, object, list[str]]:
    import numpy as np

    from recon.analysis import autocorrelation, resolution_per_depth

    _need(args, "pitch_um", "d_mm")
    thr = args.threshold
    rows, warnings = resolution_per_depth(stack, z, pitch_mm=header["pitch_um"] * 1e-3,
                                          d_mm=args.d_mm, level=args.level, threshold=thr)
    result = {**header, "level": args.level, "per_depth": rows, "warnings": warnings}

    mid = len(z) // 2
    line = autocorrelation(stack[mid])[stack.shape[1] - 1]
    lags = np.arange(line.size) - (stack.shape[2] - 1)
    fig, (a0, a1, a2) = _figure(3)
    a0.plot(lags, line, lw=1)
    a0.axhline(args.level, color="C1", ls="--", lw=0.8, label=f"{args.level:g} (Sec. 3.2)")
    a0.axhline(thr, color="C2", ls=":", lw=0.8, label=f"{thr:g} (Sec. 6.4)")
    a0.set(xlim=(-30, 30), xlabel="lag x (px)", ylabel="autocorrelation",
           title=f"central autocorrelation line, z = {z[mid]:g} mm")
    a0.legend()
    for key, style in (("autocorrelation_half_width_object_mm", "o-"),
                       ("inner_product_shift_object_mm", "s--")):
        for ax_name in ("x", "y"):
            pts = [(r["depth_mm"], r[key][ax_name] * 1e3) for r in rows if r[key]]
            if pts:
                a1.plot(*zip(*pts, strict=True), style, label=f"{key.split('_')[0]} {ax_name}")
    a1.set(xlabel="depth z (mm)", ylabel="object-space resolution (um)",
           title="lateral resolution, m = d/z")
    a1.legend(fontsize=8)
    pts = [(r["depth_mm"], r["depth_of_field_near_mm"], r["depth_of_field_far_mm"])
           for r in rows if r["depth_of_field_near_mm"] is not None]
    if pts:
        zz, nn, ff = (np.array(v, float) for v in zip(*pts, strict=True))
        a2.plot(zz, nn, "o-", label="near side")
        finite = np.isfinite(ff)
        a2.plot(zz[finite], ff[finite], "s-", label="far side (inf beyond hyperfocal)")
        a2.legend(fontsize=8)
    a2.set(xlabel="depth z (mm)", ylabel="depth of field (mm)", yscale="log",
           title="smallest detectable axial separation")
    lines = [f"z = {r['depth_mm']:g} mm: 70% half width "
             + (f"{r['autocorrelation_half_width_px']['x']:.2f} x "
                f"{r['autocorrelation_half_width_px']['y']:.2f} px = "
                f"{r['autocorrelation_half_width_object_mm']['x'] * 1e3:.1f} x "
                f"{r['autocorrelation_half_width_object_mm']['y'] * 1e3:.1f} um"
                if r["autocorrelation_half_width_px"] else "n/a")
             + (f", scale s* = {r['inner_product_scale']:.4f}"
                if r["inner_product_scale"] else "")
             + (f", hyperfocal {r['hyperfocal_distance_mm']:.4g} mm"
                if r["hyperfocal_distance_mm"] else "")
             for r in rows]
    return result, fig, lines


def _similarity(args, stack, z, header):
    import numpy as np

    from recon.analysis import stack_similarity

    s = stack_similarity(stack, z, index=args.index)
    n, near, far, idx = len(z), s["nearest"], s["farthest"], s["index"]
    others = np.delete(s["inner_products"], idx)
    result = {
        **header,
        "nearest": near, "farthest": far,
        "nearest_depth_mm": float(z[near]), "farthest_depth_mm": float(z[far]),
        "lags_x_px": s["lags_x_px"],
        "autocorrelation_x_nearest": s["autocorrelation_x"][near],
        "autocorrelation_x_farthest": s["autocorrelation_x"][far],
        "autocorrelation_y_nearest": s["autocorrelation_y"][near],
        "autocorrelation_y_farthest": s["autocorrelation_y"][far],
        "lags_y_px": s["lags_y_px"],
        "cross_correlation_x": s["cross_correlation_x"],
        "cross_correlation_max": s["cross_correlation_max"],
        "cross_correlation_argmax_px": list(s["cross_correlation_argmax_px"]),
        "index": idx, "index_depth_mm": float(z[idx]),
        "inner_products": s["inner_products"],
        "inner_product_max_other": float(others.max()) if n > 1 else None,
    }
    fig, (a0, a1) = _figure(2)
    lags = s["lags_x_px"]
    a0.plot(lags, s["autocorrelation_x"][near], lw=1, label=f"autocorr. z = {z[near]:g} mm")
    a0.plot(lags, s["autocorrelation_x"][far], lw=1, label=f"autocorr. z = {z[far]:g} mm")
    a0.plot(lags, s["cross_correlation_x"], lw=1, label="cross-correlation")
    a0.set(xlabel="lag x (px)", ylabel="normalised correlation",
           title="nearest and farthest PSF (Fig. A.3a)")
    a0.legend(fontsize=8)
    a1.plot(z, s["inner_products"], "o-")
    a1.axhline(args.threshold, color="C1", ls="--", lw=0.8)
    a1.set(xlabel="depth z (mm)", ylabel="inner product",
           title=f"PSF at {z[idx]:g} mm with all others (Fig. A.3b)")
    lines = [f"nearest {z[near]:g} mm vs farthest {z[far]:g} mm: cross-correlation max "
             f"{s['cross_correlation_max']:.3f} at {tuple(s['cross_correlation_argmax_px'])} px",
             f"inner products of the {z[idx]:g} mm PSF with the others: max "
             + ("n/a" if n == 1 else f"{others.max():.3f}")]
    return result, fig, lines


def _psf_at(args, stack, z) -> tuple[np.ndarray, float]:
    """The PSF at ``--depth`` (nearest within 5 %) or the middle plane, and its depth."""
    from ..runs.stacks import pick_depth

    if args.depth_mm is None:
        k = len(z) // 2
        return stack[k], float(z[k])
    return pick_depth(stack, list(z), args.depth_mm)


def _condition_axial(args, stack, z, header):
    """``analyze condition --axial``: sources across depth planes (Fig. 4.5 axially)."""
    import numpy as np

    from recon.analysis import axial_condition

    steps = floats(args.separations_planes, "--separations-planes")
    if not all(s >= 1 and float(s).is_integer() for s in steps):
        raise InputError(f"--separations-planes {args.separations_planes!r}: use whole "
                         "numbers of planes >= 1")
    start = None
    if args.depth_mm is not None:
        start = int(np.argmin(np.abs(z - args.depth_mm)))
        if abs(z[start] - args.depth_mm) > 0.05 * args.depth_mm:
            raise InputError(f"no plane within 5% of --depth {args.depth_mm:g} mm")
    per_step, warnings = axial_condition(stack, z, steps, args.k_max, xz_px=args.xz_px,
                                         axis=args.axis, start_plane=start)
    result = {**header, "mode": "axial", "xz_px": args.xz_px, "axis": args.axis,
              "k_max": args.k_max, "per_separation": per_step, "warnings": warnings}
    fig, (a0,) = _figure(1)
    for r in per_step:
        c = np.asarray(r["condition_numbers"])
        a0.semilogy(r["ks"], np.where(np.isfinite(c), c, np.nan), "o-", ms=3,
                    label=f"{r['separation_planes']} plane(s), "
                    f"{r['separation_inverse_mm'] or 0:.3g} 1/mm")
    layout = f"x-z grid, {args.xz_px:g} px along {args.axis}" if args.xz_px > 0 else "along z"
    a0.set(xlabel="number of neighbouring sources k", ylabel="local condition number",
           title=f"Fig. 4.5 across depth ({layout})")
    a0.legend(title="separation in 1/z", fontsize=8)
    lines = [f"{r['separation_planes']} plane(s) apart ({r['separation_inverse_mm'] or 0:.3g} "
             f"1/mm in 1/z, from {r['source_depths_mm'][0]:g} mm): condition "
             f"{r['two_point']:.3g} (k = 2) -> {r['limit']:.3g} (k = {r['ks'][-1]})"
             for r in per_step]
    return result, fig, lines + [f"warning: {w}" for w in warnings]


def _condition(args, stack, z, header):
    import numpy as np

    from recon.analysis import lateral_condition, lateral_resolution_object_mm

    if args.k_max < 2:
        raise InputError(f"--k-max must be >= 2, got {args.k_max}")
    if args.axial:
        return _condition_axial(args, stack, z, header)
    seps = floats(args.separations_px, "--separations-px")
    psf, depth = _psf_at(args, stack, z)
    ks, cond, warnings = lateral_condition(psf, seps, args.k_max, layout=args.layout,
                                           axis=args.axis)
    obj = None
    if args.pitch_um is not None and args.d_mm is not None:
        _need(args, "pitch_um", "d_mm")
        obj = [lateral_resolution_object_mm(s, header["pitch_um"] * 1e-3, args.d_mm, depth)
               for s in seps]
    result = {**header, "depth_mm": depth, "layout": args.layout, "axis": args.axis,
              "separations_px": seps, "separations_object_mm": obj, "ks": ks,
              "condition_numbers": [list(c) for c in cond],
              "two_point": [float(c[0]) for c in cond],
              "limit": [float(c[-1]) for c in cond], "warnings": warnings}
    fig, (a0,) = _figure(1)
    for s, c in zip(seps, cond, strict=True):
        a0.semilogy(ks, np.where(np.isfinite(c), c, np.nan), "o-", ms=3, label=f"{s:g} px")
    a0.set(xlabel="number of neighbouring sources k", ylabel="local condition number",
           title=f"Fig. 4.5: z = {depth:g} mm, {args.layout} along {args.axis}")
    a0.legend(title="separation", fontsize=8)
    lines = [f"separation {s:g} px: condition {c[0]:.3g} (k = 2) -> {c[-1]:.3g} "
             f"(k = {ks[-1]})" for s, c in zip(seps, cond, strict=True)]
    lines += [f"warning: {w}" for w in warnings]
    return result, fig, lines


def _distinguish(args, stack, z, header):
    from recon.analysis import distinguishability, lateral_resolution_object_mm

    seps = floats(args.separations_px, "--separations-px")
    psf, depth = _psf_at(args, stack, z)
    out = distinguishability(psf, seps, axis=args.axis, iterations=args.iterations)
    obj = None
    if args.pitch_um is not None and args.d_mm is not None:
        obj = {n: (None if lim is None else lateral_resolution_object_mm(
            lim, header["pitch_um"] * 1e-3, args.d_mm, depth)) for n, (lim, _) in out.items()}
    result = {**header, "depth_mm": depth, "axis": args.axis, "iterations": args.iterations,
              "criterion": "dip of at least 20 % between neighbouring sources (Sec. 4.4)",
              "separations_px": seps,
              "two_point": {"limit_px": out[2][0], "dips": [r.dip for r in out[2][1]]},
              "sixteen_point": {"limit_px": out[16][0], "dips": [r.dip for r in out[16][1]]},
              "limits_object_mm": obj}
    fig, (a0,) = _figure(1)
    for n, label in ((2, "two points"), (16, "16 points (4 x 4)")):
        a0.plot(seps, [r.dip for r in out[n][1]], "o-", label=label)
    a0.axhline(0.2, color="k", lw=0.8, ls="--")
    a0.set(xlabel="separation on the sensor, px", ylabel="dip between sources",
           title=f"Sec. 4.4 distinguishability at z = {depth:g} mm")
    a0.legend(fontsize=8)
    lines = [f"{name}: resolved from {lim:g} px" if lim is not None else
             f"{name}: not resolved at any tested separation"
             for name, (lim, _) in (("two-point", out[2]), ("16-point", out[16]))]
    return result, fig, lines


def _grid(args, stack, z, header):
    from recon.analysis import recommend_grid

    _need(args, "pitch_um", "d_mm")
    scene = None
    if args.scene_range is not None:
        scene = floats(args.scene_range, "--scene-range")
        if len(scene) != 2 or not 0 < scene[0] <= scene[1]:
            raise InputError(f"--scene-range {args.scene_range!r}: give ZMIN,ZMAX in mm with "
                             "0 < ZMIN <= ZMAX")
    rec = recommend_grid(stack, z, pitch_mm=header["pitch_um"] * 1e-3, d_mm=args.d_mm,
                         threshold=args.threshold, scene_depth_range_mm=scene)
    result = {**header, "scene_range_mm": scene, **rec.to_dict()}
    fig, (a0, a1) = _figure(2)
    a0.vlines(1.0 / z, 0, 1, colors="C0", lw=1, label="calibrated PSFs")
    a0.vlines(1.0 / rec.depths_mm, 1.2, 2.2, colors="C1", lw=1, label="recommended planes")
    a0.set(xlabel="1/z (1/mm)", yticks=[], ylim=(-0.2, 2.6),
           title=f"{rec.depths_mm.size} planes, {rec.inverse_depth_step_per_mm:.3g} 1/mm apart")
    a0.legend(fontsize=8, loc="upper right")
    a1.plot(rec.depths_mm, rec.voxel_size_mm * 1e3, "o-")
    a1.set(xlabel="depth z (mm)", ylabel="binned pixel in object space (um)",
           title=f"lateral bin {rec.lateral_bin}")
    lines = [f"{rec.depths_mm.size} planes from {rec.span_mm[0]:g} to {rec.span_mm[1]:g} mm, "
             f"lateral bin {rec.lateral_bin}", *(f"  {r}" for r in rec.reasons)]
    return result, fig, lines


def _fov(args, stack, z, header):
    import numpy as np

    from recon.analysis import field_of_view

    _need(args, "pitch_um", "d_mm", "alpha_c_deg")
    fov = field_of_view(stack, z, pitch_mm=header["pitch_um"] * 1e-3, d_mm=args.d_mm,
                        alpha_c_deg=args.alpha_c_deg, beta_deg=args.beta_deg,
                        support_energy=args.support_energy)
    pitch_mm, per = header["pitch_um"] * 1e-3, fov["per_depth"]
    headline = fov["fov_half_angle_deg"]
    result = {**header, "alpha_c_deg": args.alpha_c_deg, "beta_deg": args.beta_deg,
              "support_energy": args.support_energy, **fov}
    fig, (a0, a1) = _figure(2)
    k = int(np.argmax(z))
    for a, axis in (("x", 0), ("y", 1)):
        m = np.clip(stack[k], 0, None).sum(axis=axis, dtype=np.float64)
        a0.plot((np.arange(m.size) - (m.size - 1) / 2) * pitch_mm, m / m.max(), lw=1,
                label=f"{a}: width {per[k]['psf_width_mm'][a]:.3g} mm")
    a0.set(xlabel="sensor position (mm)", ylabel="PSF marginal (norm.)",
           title=f"PSF support at z = {z[k]:g} mm ({args.support_energy:.0%} energy)")
    a0.legend(fontsize=8)
    for a, style in (("x", "o-"), ("y", "s--")):
        a1.plot(z, [p["fov_half_angle_deg"][a] for p in per], style, label=f"FoV {a}")
        a1.plot(z, [args.beta_deg + p["geometric_half_angle_deg"][a] for p in per], ":",
                label=f"beta + geometric limit {a}")
    a1.axhline(args.beta_deg + args.alpha_c_deg, color="k", lw=0.8, label="beta + alpha_c")
    a1.set(xlabel="depth z (mm)", ylabel="half angle (deg)", title="field of view (Eq. 3.12)")
    a1.legend(fontsize=8)
    lines = [f"half-angle FoV {headline['x']:.3g} deg (x), {headline['y']:.3g} deg (y); "
             f"limited by {per[0]['limited_by']['x']} (x), {per[0]['limited_by']['y']} (y)"]
    return result, fig, lines


_RUNNERS = {"resolution": _resolution, "similarity": _similarity, "condition": _condition,
            "grid": _grid, "fov": _fov, "distinguish": _distinguish}


def run_analysis(args: argparse.Namespace) -> tuple[dict, list[str]]:
    """Run one analysis and write ``OUT/<analysis>.png`` and ``OUT/<analysis>.json``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed by the parser of :func:`add_subcommands`.

    Returns
    -------
    result : dict
        The JSON record (also written), with ``output_png`` and ``output_json``.
    lines : list of str
        A short human-readable summary.

    Raises
    ------
    recon.errors.ReconInputError
        The analysis refuses the stack or a parameter.
    instrument.runs.runstore.RunStoreError
        Unreadable stack, missing or mismatched depths, no plane at ``--depth``.
    ValueError
        Missing or invalid options.
    """
    from ..atomic import write_json
    from ..writer.figures import save_figure
    from ..writer.guards import check_outputs

    _check_options(args)
    out = Path(args.out)
    png, js = out / f"{args.analysis}.png", out / f"{args.analysis}.json"
    check_outputs([png, js], {"--psf-stack": args.psf_stack},
                  getattr(args, "overwrite", False), directory=out)
    stack, z, header = _load(args)
    result, fig, lines = _RUNNERS[args.analysis](args, stack, z, header)
    save_figure(fig, png, dpi=100)
    result = jsonable({**result, "output_png": str(png), "output_json": str(js)},
                      nonfinite_to_none=True)
    write_json(js, result)
    log.debug("analyze %s: wrote %s and %s", args.analysis, png, js)
    return result, [*lines, f"wrote {png} and {js}"]


def run(args: argparse.Namespace) -> int:
    """Run ``analyze`` (:func:`run_analysis`) and print its summary; returns 0 (bad input
    exits 2 with one line through :func:`instrument.cli.main`)."""
    _, lines = run_analysis(args)
    print("\n".join(lines))
    return 0
