"""``diffuserlab align mask BENCH.toml [--simulate]``: SLM-mask alignment with spot feedback.

Registered through the entry-point group ``diffuserlab.commands``. Prints progress
per step, writes the alignment record (``--out``, default
``out/align/mask-TIME.align``) and exits 0 when the alignment completed and every
section passed the verification, 1 when it failed or completed with sections below
the verification bound (the record says which), 2 on bad input and 130 when
interrupted (Ctrl-C aborts between readings; the record keeps what was measured).

With ``--simulate`` the virtual bench is given a known misalignment (the
``--sim-*`` options; default 5.3 / -3.6 mask px and 2 mrad; ``--sim-distortion-px 1``
adds a quadratic distortion the 3 x 5 integer sections can only partly follow)
and the recovered values are printed next to the truth.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import logging
import sys
from pathlib import Path

__all__ = ["add_subcommands", "run"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``align`` (and ``align mask``) to the ``diffuserlab`` subparsers."""
    ap = sub.add_parser("align", help="alignment routines (SLM mask with spot feedback)")
    asub = ap.add_subparsers(dest="routine", required=True)
    mp = asub.add_parser("mask", help="align the holography mask to the SLM (Sec. 7.4)")
    mp.add_argument("bench", help="bench TOML file (e.g. examples/bench-simulated.toml)")
    mp.add_argument("--simulate", action="store_true", help="run on the virtual bench")
    mp.add_argument("--seed", type=int, default=0, help="seed of the virtual bench")
    mp.add_argument("--out", default=None, help="record directory to create (default "
                    "out/align/mask-TIME.align)")
    mp.add_argument("--mask-seed", type=int, default=None,
                    help="seed of the installed mask's pattern (default: the virtual bench's)")
    mp.add_argument("--k", type=int, default=4, help="mask pixels per SLM pixel (default 4)")
    mp.add_argument("--lut", default=None, help="SLM LUT to load first: a `calibrate "
                    "slm-lut` run store (RUN.zarr) or its exported LUT file")
    mp.add_argument("--coarse-range-px", type=int, default=12,
                    help="half-width of the coarse software search, mask px (widened x2 once)")
    mp.add_argument("--frames", type=int, default=3, help="frames averaged per reading")
    mp.add_argument("--no-rotation", action="store_true", help="do not rotate the stage")
    mp.add_argument("--sim-translation-px", type=float, nargs=2, default=(5.3, -3.6),
                    metavar=("TX", "TY"), help="--simulate: true mask offset, mask px")
    mp.add_argument("--sim-rotation-mrad", type=float, default=2.0,
                    help="--simulate: true mask rotation, mrad")
    mp.add_argument("--sim-distortion-px", type=float, default=0.0,
                    help="--simulate: quadratic distortion at the footprint edge, mask px")
    mp.set_defaults(handler=run)


def _truth(args):
    import numpy as np

    from recon.optics.holography import MaskTransform

    poly = np.zeros((2, 3, 3))
    poly[0, 0, 2] = args.sim_distortion_px
    poly[1, 2, 0] = -0.8 * args.sim_distortion_px
    return MaskTransform(translation=tuple(args.sim_translation_px),
                         theta=args.sim_rotation_mrad * 1e-3, poly=poly)


def run(args: argparse.Namespace) -> int:
    """Run ``align mask``; returns the exit status."""
    from drivers.errors import DeviceError
    from instrument.bench import Bench
    from instrument.config import load_bench
    from instrument.plan import PlanError
    from instrument.runner import RunAborted, RunControl
    from instrument.virtual_bench import VirtualBench
    from recon.optics.holography import MaskModel

    from ..holo_bench import holography_branch
    from ..slm_lut_io import apply_lut
    from .procedure import AlignmentConfig, MaskAligner
    from .record import AlignmentRecord

    logging.basicConfig(level=logging.WARNING)
    out = Path(args.out or Path("out/align") / (
        f"mask-{_dt.datetime.now():%Y%m%d-%H%M%S}.align"))
    try:
        config = load_bench(args.bench, simulate=args.simulate)
        cfg = AlignmentConfig(coarse_range_px=args.coarse_range_px, frames=args.frames,
                              rotation=not args.no_rotation)
        if not args.simulate and args.mask_seed is None:
            raise PlanError("on a real bench, pass --mask-seed (the installed mask's pattern)")
        bench = (VirtualBench(config, seed=args.seed).open() if args.simulate
                 else Bench.open(config, on_prompt=_ask))
    except (OSError, ValueError, PlanError, DeviceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    control = RunControl()
    try:
        with bench, holography_branch(bench):
            if args.lut:
                lut = apply_lut(bench.slm, args.lut)
                print(f"SLM LUT loaded from {args.lut} ({lut.wavelength_nm:g} nm)")
            elif args.simulate:
                print("note: the SLM LUT is the driver's linear default; run `diffuserlab "
                      "calibrate slm-lut ... --simulate --out LUT.zarr` and pass --lut LUT.zarr")
            slm = bench.slm
            if args.simulate:
                truth = _truth(args)
                bench.hologram.mask.truth = truth
                seed = bench.hologram.mask.seed if args.mask_seed is None else args.mask_seed
            else:
                seed = args.mask_seed
            model = MaskModel(slm.resolution, slm.pixel_pitch_um, args.k, 4, seed)
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
    except (PlanError, DeviceError, OSError, ValueError) as exc:
        print(f"alignment failed: {exc}\nrecord: {out}", file=sys.stderr)
        return 1
    s = report["summary"]
    v = report["steps"]["verify"]
    print(f"translation {s['translation_px'][0]:+.3f}, {s['translation_px'][1]:+.3f} mask px; "
          f"rotation {s['theta_rad'] * 1e3:+.3f} mrad; {s['captures']} frames")
    if args.simulate:
        print(f"truth       {truth.translation[0]:+.3f}, {truth.translation[1]:+.3f} mask px; "
              f"rotation {truth.theta * 1e3:+.3f} mrad")
    print("section eta / aligned simulation: " + " ".join(f"{r:.2f}" for r in v["eta_ratio"]))
    for w in v["warnings"]:
        print(f"warning: {w}")
    print(f"corrected mask: {out / 'corrected_mask.npy'}")
    return 0 if v["passed"] else 1


def _ask(action: str, message: str) -> bool:
    reply = input(f"{message} - done? [y/N] ")
    return reply.strip().lower() in ("y", "yes")
