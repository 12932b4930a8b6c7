"""The evaluation reproducing Table 7.1 (``diffuserlab holo evaluate``).

:func:`run_evaluation` evaluates the images and returns what the command writes
(:func:`instrument.writer.evaluation.write_evaluation`): the records (``records.csv``,
one row per image, factor, method, seed), the summary record (``summary.json``: means,
spreads, acceptance rules, settings), the table (``table.md``, ours next to the
dissertation's, :func:`format_table`) and the chart (``psnr_vs_seconds.png``,
:func:`psnr_vs_seconds_figure`). The command line (N = 480 is the benchmark, N = 240
the test-suite variant)::

    diffuserlab holo evaluate --size 480 --factors 4,16,36 --seeds 0,1,2 --out holo_eval
    diffuserlab holo evaluate --images my_photos/ --size 240 --out eval_mine
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ..backend import resolve_device
from ..errors import ReconInputError
from .evaluation import LABELS, METHODS, TABLE_7_1, acceptance, evaluate_images, summarise

__all__ = ["HONESTY", "format_table", "psnr_vs_seconds_figure", "run_evaluation"]

HONESTY = (
    "Notes: the images are scikit-image's bundled photographs, not the dissertation's 40; "
    "the grid is scaled down (N x N instead of 960 x 540 SLM pixels times k); the 1st-99th "
    "percentile contrast stretch is part of the protocol; the Butterworth filter and the mean "
    "normalisation are the loss's own and are never tuned per image.")


def format_table(summary: dict, rules: list[dict], settings: dict) -> str:
    """Markdown table: our mean (std) next to Table 7.1 per factor, region and method.

    Parameters
    ----------
    summary : dict
        From :func:`.evaluation.summarise`.
    rules : list of dict
        From :func:`.evaluation.acceptance`.
    settings : dict
        Run settings shown in the header (size, seeds, iterations, images).

    Returns
    -------
    str
    """
    cells = summary["cells"]
    lines = [f"# Table 7.1 reproduction (N = {settings['size']}, "
             f"{settings['n_images']} images, seeds {settings['seeds']}, "
             f"{settings['iterations']} iterations)", ""]
    factors = sorted({f for f, _, _ in cells})
    methods = [m for m in (*METHODS, "no-mask") if any(m == mm for _, mm, _ in cells)]
    for f in factors:
        lines += [f"## {f}x expansion", "",
                  "| region | method | PSNR ours | PSNR Kuo | dPSNR | SSIM ours | SSIM Kuo "
                  "| dSSIM | s/hologram |", "|---|---|---|---|---|---|---|---|---|"]
        for region in ("full", "centre"):
            for m in methods:
                c = cells.get((f, m, region))
                if c is None:
                    continue
                ref = TABLE_7_1.get((f, region, m))
                rp = f"{ref[0]:.2f}" if ref else "-"
                rs = f"{ref[1]:.3f}" if ref else "-"
                dp = f"{c['psnr'] - ref[0]:+.2f}" if ref else "-"
                ds = f"{c['ssim'] - ref[1]:+.3f}" if ref else "-"
                name = "Full FoV" if region == "full" else "Central quarter"
                lines.append(f"| {name} | {LABELS[m]} | {c['psnr']:.2f} ({c['psnr_std']:.2f}) "
                             f"| {rp} | {dp} | {c['ssim']:.3f} ({c['ssim_std']:.3f}) | {rs} "
                             f"| {ds} | {c['seconds']:.2f} |")
        lines.append("")
    lines += ["## Acceptance rules", ""]
    for r in rules:
        mark = {True: "PASS", False: "FAIL", None: "n/a"}[r["passed"]]
        lines.append(f"- **{mark}** {r['rule']}: {r['detail']}")
    lines += ["", HONESTY, ""]
    return "\n".join(lines)


def psnr_vs_seconds_figure(records):
    """Chart of mean full-FoV PSNR against mean seconds, one panel per factor.

    Iterative methods are drawn through their checkpoints (PSNR after 10, 25, 50,
    100, ... iterations against the seconds spent so far); one-step is a point.

    Parameters
    ----------
    records : list of dict
        From :func:`.evaluation.evaluate_images` (with ``curve``).

    Returns
    -------
    matplotlib.figure.Figure
        The chart (Agg backend); the caller saves and closes it.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    factors = sorted({r["factor"] for r in records})
    fig, axes = plt.subplots(1, len(factors), figsize=(4.2 * len(factors), 3.6), squeeze=False)
    for ax, f in zip(axes[0], factors, strict=True):
        for m in (*METHODS, "no-mask"):
            curves = [r["curve"] for r in records if r["factor"] == f and r["method"] == m]
            if not curves:
                continue
            n = min(len(c) for c in curves)
            secs = np.mean([[p[0] for p in c[:n]] for c in curves], axis=0)
            psnr = np.mean([[p[2] for p in c[:n]] for c in curves], axis=0)
            ax.plot(secs, psnr, "o-" if n > 1 else "s", label=LABELS[m])
        for m in METHODS:
            ref = TABLE_7_1.get((f, "full", m))
            if ref:
                ax.axhline(ref[0], lw=0.6, ls=":", color="grey")
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(f"{f}x expansion (dotted: Table 7.1)")
        ax.set_xlabel("seconds per hologram")
        ax.set_ylabel("PSNR, full FoV (dB)")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return fig


def _summary_record(summary, rules, settings) -> dict:
    cells = [{"factor": f, "method": m, "region": reg, **{k: v for k, v in c.items()
                                                          if k != "seed_psnr"},
              "seed_psnr": {str(s): p for s, p in c["seed_psnr"].items()},
              "table_7_1": TABLE_7_1.get((f, reg, m))}
             for (f, m, reg), c in sorted(summary["cells"].items())]
    return {"settings": settings, "cells": cells, "acceptance": rules}


def run_evaluation(images: list[tuple[str, object]], *, size: int,
                   factors: tuple[int, ...], seeds: tuple[int, ...], steps: int,
                   methods: tuple[str, ...], source: str,
                   progress: Callable[[int, int, dict], None] | None = None,
                   device: str = "cpu") -> dict:
    """Evaluate the images; return the records, summary, rules and table (no files).

    Parameters
    ----------
    images : list of (str, ndarray)
        Named images (:func:`.protocol.load_bundled` / :func:`.protocol.load_folder`).
    size, factors, seeds, steps, methods
        Passed to :func:`.evaluation.evaluate_images` (target grid N, expansion
        factors, mask seeds, optimiser steps, methods); ``steps`` is recorded in the
        settings as ``iterations`` (``holo evaluate --iterations``).
    source : str
        Where the images came from, recorded in the settings.
    progress : callable, optional
        ``progress(done, total, record)`` after each hologram.
    device : {"cpu", "cuda", "auto"}
        Where the optimiser runs (:func:`.evaluation.evaluate_images`); recorded in the
        settings as the optimiser reports it.

    Returns
    -------
    dict
        ``records``, ``summary``, ``rules`` (acceptance), ``settings`` (with
        ``wall_seconds``), ``table`` (the Markdown of ``table.md``) and ``record``
        (the content of ``summary.json``).

    Raises
    ------
    ReconInputError
        ``size < 8``, ``steps < 1``, a grid the factors do not divide, or an
        unusable ``device``.
    """
    if size < 8 or steps < 1:
        raise ReconInputError("--size must be >= 8 and --iterations >= 1")
    where = resolve_device(device).label  # an unusable device is refused before any work
    t0 = time.perf_counter()
    records = evaluate_images(images, size, factors, methods, seeds, steps,
                              progress=progress, device=device)
    summary = summarise(records)
    rules = acceptance(summary, records)
    settings = {"size": size, "factors": list(factors), "seeds": list(seeds),
                "iterations": steps, "methods": list(methods),
                "images": [n for n, _ in images], "n_images": len(images),
                "source": source, "device": where,
                "wall_seconds": time.perf_counter() - t0}
    return {"records": records, "summary": summary, "rules": rules, "settings": settings,
            "table": format_table(summary, rules, settings),
            "record": _summary_record(summary, rules, settings)}
