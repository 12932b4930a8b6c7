"""``diffuserlab align mask [BENCH.toml] [--simulate]``: SLM-mask alignment with spot feedback.

Registered through the entry-point group ``diffuserlab.commands``. Prints progress
per step, writes the alignment record (``--out``, default
``out/align/mask-TIME.align``) and exits 0 when the alignment completed and every
section passed the verification, 1 when it failed or completed with sections below
the verification bound (the record says which), 2 on bad input and 130 when
interrupted (Ctrl-C aborts between readings; the record keeps what was measured).

With ``--simulate`` (and the bench file, or without one the built-in simulated
bench) the virtual bench is given a known misalignment (the
``--sim-*`` options; default 5.3 / -3.6 mask px, 2 mrad and 0.08 mm of defocus;
``--sim-distortion-px 1`` adds a quadratic distortion the 3 x 5 integer sections can
only partly follow; ``--sim-tip-mrad`` / ``--sim-tilt-mrad`` tilt the mount) and the
recovered values are printed next to the truth.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import logging
import math
import sys
from pathlib import Path

from ..parameters import AlignMaskParams
from .common import add_bench_arguments, make_bench

__all__ = ["add_subcommands", "run", "simulated_truth"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``align`` (and ``align mask``) to the ``diffuserlab`` subparsers."""
    ap = sub.add_parser("align", help="alignment routines (SLM mask with spot feedback)")
    asub = ap.add_subparsers(dest="routine", required=True)
    mp = asub.add_parser("mask", help="align the holography mask to the SLM (Sec. 7.4)")
    add_bench_arguments(mp)
    mp.add_argument("--out", default=None, help="record directory to create (default "
                    "out/align/mask-TIME.align)")
    AlignMaskParams.add_arguments(mp)  # the procedure's parameters, declared once
    mp.set_defaults(handler=run)


def simulated_truth(args):
    """The misalignment ``align mask --simulate`` gives the virtual mask, from the
    ``--sim-*`` options (translation and distortion in px, rotation in mrad, defocus in
    mm, tip and tilt in mrad).

    Returns
    -------
    recon.optics.holo_display.MaskTransform
    """
    import numpy as np

    from recon.optics.holo_display import MaskTransform

    poly = np.zeros((2, 3, 3))
    poly[0, 0, 2] = args.sim_distortion_px
    poly[1, 2, 0] = -0.8 * args.sim_distortion_px
    return MaskTransform(translation=tuple(args.sim_translation_px),
                         theta=args.sim_rotation_mrad * 1e-3, poly=poly,
                         defocus_mm=args.sim_defocus_mm, tip_rad=args.sim_tip_mrad * 1e-3,
                         tilt_rad=args.sim_tilt_mrad * 1e-3)


def _load_pattern(path: str):
    """The ``--mask-pattern`` array, or PlanError naming the file (np.load's own errors
    name neither the file nor the option)."""
    import numpy as np

    from instrument.acquisition.plan import PlanError

    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, EOFError) as exc:  # empty, truncated, text or object arrays
        raise PlanError(f"--mask-pattern {path}: cannot read it as a .npy array ({exc}); "
                        "give the installed mask's pattern as saved by numpy.save") from None


def run(args: argparse.Namespace) -> int:
    """Run ``align mask``; returns the exit status."""
    from drivers.errors import DeviceError
    from instrument.acquisition.plan import PlanError
    from instrument.acquisition.runner import RunAborted, RunControl
    from instrument.config import BenchConfigError
    from instrument.devices.bench_file import MissingBenchFile
    from instrument.runs.runstore import RunStoreError
    from instrument.writer.guards import check_outputs
    from recon.errors import ReconInputError
    from recon.optics.holo_display import MaskModel

    from ..holo_bench import holography_branch
    from ..mask_alignment.procedure import AlignmentConfig, MaskAligner
    from ..mask_alignment.record import AlignmentRecord
    from ..slm_lut_io import apply_lut

    logging.basicConfig(level=logging.WARNING)
    out = Path(args.out or Path("out/align") / (
        f"mask-{_dt.datetime.now():%Y%m%d-%H%M%S}.align"))
    try:
        AlignMaskParams.from_namespace(args)  # limits (InputError), before the bench opens
        # before the bench opens; an empty directory made for the record is fine
        if out.exists() and not (out.is_dir() and not any(out.iterdir())):
            raise PlanError(f"output {out} exists (an alignment record is never replaced); "
                            "choose another --out")
        check_outputs([out], {"--mask-pattern": args.mask_pattern, "--lut": args.lut},
                      overwrite=True, store=True)
        if not args.simulate and args.mask_seed is None and args.mask_pattern is None:
            raise PlanError("on a real bench, pass --mask-pattern FILE.npy or --mask-seed "
                            "(the installed mask's pattern)")
        pattern = None if args.mask_pattern is None else _load_pattern(args.mask_pattern)
        lut = None
        if args.lut:
            from ..slm_lut_io import load_lut

            lut = load_lut(args.lut)  # RunStoreError: not a run, or no slm_lut product
        bench = make_bench(args, "align mask")
        relay_na = args.relay_na
        if relay_na is None and args.simulate:
            relay_na = bench.relay_na
        cfg = AlignmentConfig(coarse_range_px=args.coarse_range_px, frames=args.frames,
                              rotation=not args.no_rotation, focus=not args.no_focus,
                              relay_na=relay_na, focus_range_mm=args.focus_range_mm)
        if args.simulate:
            bench.open()
    except BenchConfigError as exc:  # one line per problem of the bench file
        for line in exc.lines():
            print(f"diffuserlab: error: {line}", file=sys.stderr)
        return 2
    except (OSError, ValueError, PlanError, DeviceError, ReconInputError, RunStoreError,
            MissingBenchFile) as exc:
        print(f"diffuserlab: error: {exc}", file=sys.stderr)
        return 2
    control = RunControl()
    try:
        with bench, holography_branch(bench):
            if lut is not None:
                apply_lut(bench.slm, lut)
                print(f"SLM LUT loaded from {args.lut} ({lut.wavelength_nm:g} nm)")
            elif args.simulate:
                print("note: the SLM LUT is the driver's linear default; run `diffuserlab "
                      "calibrate slm-lut ... --simulate --out LUT.zarr` and pass --lut LUT.zarr")
            slm = bench.slm
            if args.simulate:
                truth = simulated_truth(args)
                bench.hologram.mask.truth = truth
                seed = bench.hologram.mask.seed if args.mask_seed is None else args.mask_seed
            else:
                seed = args.mask_seed
            try:
                model = MaskModel(slm.resolution, slm.pixel_pitch_um, args.k, 4,
                                  0 if seed is None else seed, margin=args.mask_margin,
                                  bits=pattern)
            except ReconInputError as exc:
                print(f"diffuserlab: error: --mask-pattern {args.mask_pattern}: {exc}",
                      file=sys.stderr)
                return 2
            record = AlignmentRecord(out)
            print(f"alignment record: {out}")
            aligner = MaskAligner(bench, model, cfg, record=record, control=control,
                                  on_event=lambda step, msg, data: print(f"[{step}] {msg}",
                                                                         flush=True))
            try:
                report = aligner.run()
            except KeyboardInterrupt:
                print("interrupted: the record keeps every reading taken", file=sys.stderr)
                return 130
    except RunAborted as exc:
        print(f"aborted: {exc}", file=sys.stderr)
        return 130
    except OSError as exc:  # the disk or the system, not the alignment: one line, exit 2
        from instrument.cli import os_error_line

        print(f"diffuserlab: error: {os_error_line(exc)} (the record {out} keeps what was "
              "written before)", file=sys.stderr)
        return 2
    except (PlanError, DeviceError, ValueError) as exc:
        print(f"alignment failed: {exc}\nrecord: {out}", file=sys.stderr)
        return 1
    s = report["summary"]
    v = report["steps"]["verify"]
    print(f"translation {s['translation_px'][0]:+.3f}, {s['translation_px'][1]:+.3f} mask px; "
          f"rotation {s['theta_rad'] * 1e3:+.3f} mrad; {s['captures']} frames")
    focus = report["steps"].get("focus", {})
    if "z_mm" in focus:
        tilt = ", ".join(f"{a} {v:+.3f} deg" for a, v in focus["tilt_applied_deg"].items())
        print(f"focus: stage z {focus['z_mm']:+.4f} mm ({focus['stop']}); {tilt}")
    if args.simulate:
        print(f"truth       {truth.translation[0]:+.3f}, {truth.translation[1]:+.3f} mask px; "
              f"rotation {truth.theta * 1e3:+.3f} mrad; focus at stage z "
              f"{-truth.defocus_mm:+.4f} mm; tip {-math.degrees(truth.tip_rad):+.3f} deg, "
              f"tilt {-math.degrees(truth.tilt_rad):+.3f} deg")
    print("section eta / aligned simulation: " + " ".join(f"{r:.2f}" for r in v["eta_ratio"]))
    for w in v["warnings"]:
        print(f"warning: {w}")
    print(f"corrected mask: {out / 'corrected_mask.npy'}")
    return 0 if v["passed"] else 1

