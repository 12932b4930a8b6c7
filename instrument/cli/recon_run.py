"""``diffuserlab recon-run``: reconstruct every frame of a recorded run, in parallel.

``diffuserlab recon-run RUN.zarr --psf PSF|SWEEP.zarr [--depth Z] --method M
--iterations N [--frames A:B] [--scheduler ADDRESS | --workers K] [--dff PERCENTILE]
[--device cpu|cuda|auto]``
    Reconstructs the selected frames with dask (:func:`instrument.processing.batch.reconstruct_run`:
    local worker processes, or a dask.distributed cluster given its scheduler's
    address), shows a progress bar, stores the images in the run as the per-frame
    product ``recon_<method>`` next to the raw frames, and resumes where it stopped
    (frames already reconstructed with the same settings are skipped). Each frame
    equals ``diffuserlab recon`` of that frame with the same method, weights and
    iterations. ``--dff`` adds the ΔF/F product against a per-pixel percentile
    baseline (Kuo 2020, Fig. 6.5b: 20). ``--device cuda`` solves on a GPU in every
    worker (one local worker unless ``--workers``; a cluster's workers use their own
    GPU); an unusable device exits 2 before the run is opened. A frame whose data
    cannot be reconstructed (a dark frame: no light) is named with its reason and
    left out, the others go on. Exit 0; 1 when a frame failed so (the others are
    stored); 2 bad input; 130 Ctrl-C or SIGTERM (the frames done are kept: run the
    same command again to finish).

``diffuserlab recon-run RUN.zarr --psf-grid GRID.zarr [--model auto|convolution|local|pca]
[--background estimate|none] ...``
    The same with a spatially varying model (Ch. 5): the ``calibrate psf-grid`` run's
    model is chosen once for the batch (:mod:`instrument.processing.batch_grid`; ``--model``,
    ``--pca-k``, ``--background``, ``--l1`` as for ``recon --psf-grid``; FISTA), every
    frame reconstructed with its own background estimate (Eq. 6.2); the product is
    ``recon_grid_<model>`` (``local``, ``convolution``, ``pcaK``) with the backgrounds
    in ``recon_grid_<model>_background``. The grid's PSFs are dark-subtracted, so the
    frames' dark level comes from ``--dark``, or with ``auto`` a simulated run's camera
    offset, else nothing: the background fits the offset (docs/cli.md).
"""

from __future__ import annotations

import argparse
import sys
import threading

from ..options import RunOptions

__all__ = ["add_subcommands", "run"]


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Add ``recon-run`` to the ``diffuserlab`` subparsers (``handler=run``)."""
    from .recon_flags import add_recon_flags

    rp = sub.add_parser(
        "recon-run", help="reconstruct every frame of a recorded run with dask (resumable)",
        description="Reconstruct the frames of a run store (e.g. from `capture video`) in "
        "parallel with dask and store them in the run as a product; run it again to "
        "resume. Ctrl-C stops and keeps the frames done.")
    rp.add_argument("run", help="the run store, RUN.zarr")
    where = rp.add_mutually_exclusive_group()
    RunOptions.add_arguments(rp, {"workers": where, "scheduler": where},
                             fields=("psf", "depth_mm", "psf_product"))
    add_recon_flags(rp, "recon-run")  # per frame, as for `recon`
    RunOptions.add_arguments(rp, {"workers": where, "scheduler": where},
                             fields=("frames", "workers", "scheduler", "dff", "product",
                                     "overwrite"))
    from .grid_options import add_grid_options

    add_grid_options(rp, volume=False, grid_dark=False)
    rp.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Run ``recon-run``; returns the exit status (module docstring)."""
    from tqdm import tqdm

    from recon.early_stop import named
    from recon.errors import ReconInputError

    from ..processing.batch import batch_psf, parse_frames, recipe_record, reconstruct_run
    from ..processing.reconstruct_files import read_recipe_once, scene_recipe_default
    from ..runs.runstore import RunStore, RunStoreError
    from .recon_flags import check_device, check_recon_flags

    options = check_recon_flags(args)  # --iterations, --bin, --tv, --l1 against their limits
    if args.workers is not None:
        from ..processing.batch import check_workers

        check_workers(args.workers, 1)  # the machine's bound, before any work
    if args.dff is not None and not 0 <= args.dff <= 100:
        raise ReconInputError(f"--dff {args.dff}: give a percentile in [0, 100] (e.g. 20)")
    if (args.psf is None) == (args.psf_grid is None):
        raise ReconInputError("recon-run needs --psf (a PSF) or --psf-grid (a psf-grid run), "
                              "not both")
    if args.psf_grid and named(getattr(args, "early_stop", None)):
        raise ReconInputError("--early-stop names a scene calibration's recipe for one PSF; "
                              "a --psf-grid run has none: give --psf RUN with it, or leave "
                              "--early-stop out")
    check_device(args.device)  # before the run is opened
    store = RunStore.open(args.run)
    frames = None if args.frames is None else parse_frames(args.frames, store.n_frames)
    recipe = None
    if args.psf_grid:
        psf, dark, source, how = _grid(args, store)
    else:
        psf, dark, source = batch_psf(args.psf, store.attrs, depth_mm=args.depth_mm,
                                      psf_product=args.psf_product, dark=args.dark)
        # the recipe read once: every frame is solved with it and the product records it
        options = read_recipe_once(scene_recipe_default(args.psf, options))
        recipe = recipe_record(options.early_stop, psf, dark)
        how = (f"{args.method} x{args.iterations}" if recipe is None else
               f"the PSF's scene-calibration recipe (threshold {recipe['psf_threshold']:g}, "
               f"FISTA x{recipe['iterations']}, TV denoising {recipe['denoise_weight']:g}; "
               "--early-stop off declines it)")
    name = args.product or (psf.product_name if args.psf_grid else
                            "recon_recipe" if recipe is not None else f"recon_{args.method}")
    which = ("the stored frames" if frames is None
             else f"frames {frames.start}:{frames.stop}")
    print(f"{args.run}: {which} of {store.n_frames}, "
          f"{how}, PSF {source}; "
          + (f"scheduler {args.scheduler}" if args.scheduler else
             f"{args.workers or 'one per core'} local workers" if args.device == "cpu"
             or args.workers else "one local worker")
          + ("" if args.device == "cpu" else f", device {args.device}"), flush=True)
    bars: list = []

    def progress(p: dict) -> None:
        if not bars:
            bars.append(tqdm(total=p["total"], initial=p["skipped"], unit="frame",
                             file=sys.stderr, dynamic_ncols=True))
        bars[0].update(p["done"] - bars[0].n)

    cancel = threading.Event()
    try:
        out = reconstruct_run(
            args.run, psf, options, dark=dark, frames=frames, product=args.product,
            workers=args.workers, scheduler=args.scheduler, dff_percentile=args.dff,
            overwrite=args.overwrite, psf_source=source, on_progress=progress,
            cancel=cancel)
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP (instrument.cli.interrupts)
        from .interrupts import exit_status, signal_text

        for bar in bars:
            bar.close()
        try:
            done = RunStore.open(args.run).product_info(name).get("planes_done", 0)
        except RunStoreError:  # stopped before the product was made
            done = 0
        print(f"stopped ({signal_text(getattr(exc, 'signum', None))}): {done} frames of "
              f"{args.run} are reconstructed; run the same command again to finish",
              flush=True)
        return exit_status(exc)
    for bar in bars:
        bar.close()
    if out["not_stored"]:
        print(f"left out: frames {out['not_stored']} (not stored: the recording ended "
              "there)")
    for line in out["damaged"]:
        print(f"left out: {line}")
    for line in out["failed"]:
        print(f"failed:   {line}")
    print(f"{out['product']}: {out['reconstructed']} frames reconstructed, {out['skipped']} "
          f"already done, {out['seconds']:.1f} s ({out['fps']:.2f} frames/s with "
          f"{out['workers'] or 0} workers)"
          + (f"; backgrounds in {out['background_product']}"
             if out.get("background_product") else "")
          + (f"; ΔF/F in {out['dff_product']}" if out.get("dff_product") else ""))
    if out["failed"]:
        print(f"diffuserlab: error: {len(out['failed'])} frame(s) could not be reconstructed "
              f"(listed above with the reason; the others are stored): fix their cause "
              "and run the same command again, or leave them out with --frames",
              file=sys.stderr)
        return 1
    return 0


def _grid(args: argparse.Namespace, store):
    """``--psf-grid``: the grid model chosen once for the batch, the frames' dark level,
    the source and the model's description."""
    from recon.errors import ReconInputError

    from ..processing.batch_grid import prepare_grid_batch
    from .recon_flags import dark_for_grid, grid_method

    if len(args.psf_grid) > 1:
        raise ReconInputError("recon-run reconstructs images: give one --psf-grid run (one "
                              "depth)")
    if args.depth_mm is not None:
        raise ReconInputError("--depth selects a plane of a --psf stack; a --psf-grid run "
                              "has one depth: drop --depth")
    grid_method(args.method, ("fista",))
    path = args.psf_grid[0]
    prepared = prepare_grid_batch(path, store.frame_shape, model=args.model, k=args.k,
                                  bin_factor=args.bin_factor)
    # --dark's one meaning for a grid (docs/cli.md): its PSFs are dark-subtracted, so
    # auto is the frames' recorded level, else nothing (the background fits the offset)
    dark = dark_for_grid(args.dark)
    recorded = (store.attrs.get("simulated") or {}).get("dark_offset_dn")
    if dark == "auto":
        dark = 0.0 if recorded is None else float(recorded)
    elif dark == "none":
        dark = 0.0
    c = prepared.choice
    how = (f"{c.label()} model ({prepared.operator.n_kernels} convolutions per apply; "
           f"{c.reason}), background {args.background}, FISTA x{args.iterations}")
    return prepared, dark, path, how
