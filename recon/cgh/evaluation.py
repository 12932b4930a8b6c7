"""Table 7.1 reproduction: run the methods on a set of images and score them.

The protocol (images, preprocessing, metrics) is :mod:`.protocol`; the acceptance
rules are pre-registered in docs/protocols.md ("Table 7.1") and checked by
:func:`acceptance`. :mod:`.evaluate` is the command-line front end.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from ..errors import ReconInputError
from ..options import HOLOGRAM_METHODS
from .baselines import one_step_hologram
from .losses import IntensityLoss
from .optimize import optimize_hologram
from .protocol import image_metrics, prepare_target
from .scattering_display import ScatteringDisplay

__all__ = [
    "LABELS",
    "METHODS",
    "TABLE_7_1",
    "acceptance",
    "evaluate_images",
    "summarise",
]

#: Methods of Table 7.1 in order (:data:`recon.options.HOLOGRAM_METHODS`); LABELS also
#: names the reference "no-mask" (native étendue).
METHODS = HOLOGRAM_METHODS
LABELS = {"one-step": "One-step backpropagation", "l2": "Ours: No constraints",
          "frequency": "Ours: Frequency constraints", "spatial": "Ours: Spatial constraints",
          "no-mask": "No mask, native étendue (reference)"}

#: Kuo 2020, Table 7.1: (factor, region, method) -> (PSNR dB, SSIM); 40 images.
TABLE_7_1 = {
    (4, "full", "one-step"): (12.059, 0.064), (4, "full", "l2"): (18.510, 0.286),
    (4, "full", "frequency"): (26.958, 0.624), (4, "full", "spatial"): (19.267, 0.472),
    (4, "centre", "one-step"): (12.163, 0.069), (4, "centre", "l2"): (18.996, 0.316),
    (4, "centre", "frequency"): (27.412, 0.655), (4, "centre", "spatial"): (36.811, 0.903),
    (16, "full", "one-step"): (12.720, 0.197), (16, "full", "l2"): (15.128, 0.363),
    (16, "full", "frequency"): (18.486, 0.552), (16, "full", "spatial"): (15.341, 0.455),
    (16, "centre", "one-step"): (13.044, 0.194), (16, "centre", "l2"): (15.883, 0.373),
    (16, "centre", "frequency"): (19.773, 0.572), (16, "centre", "spatial"): (27.266, 0.829),
    (36, "full", "one-step"): (12.891, 0.389), (36, "full", "l2"): (14.217, 0.509),
    (36, "full", "frequency"): (16.167, 0.633), (36, "full", "spatial"): (14.371, 0.541),
    (36, "centre", "one-step"): (13.272, 0.383), (36, "centre", "l2"): (14.912, 0.515),
    (36, "centre", "frequency"): (17.344, 0.650), (36, "centre", "spatial"): (21.500, 0.806),
}

_LOSSES = {"l2": IntensityLoss.l2, "frequency": IntensityLoss.frequency,
           "spatial": IntensityLoss.spatial}
#: Seed offset of the one-step target phase (kept apart from the mask seed's stream).
PHASE_SEED_OFFSET = 10_000


def factor_to_k(factor: int) -> int:
    """Mask pixels per SLM pixel ``k = sqrt(q)`` for an étendue factor ``q`` (Eq. 7.10).

    Parameters
    ----------
    factor : int
        Expansion factor, a perfect square (4, 16, 36, ...).

    Returns
    -------
    int

    Raises
    ------
    ReconInputError
        If ``factor`` is not a positive perfect square.
    """
    k = math.isqrt(int(factor))
    if factor < 1 or k * k != factor:
        raise ReconInputError(f"expansion factor {factor} is not a perfect square (4, 16, 36...)")
    return k


def _curve(display, target, result) -> list:
    n_slm = display.slm_shape[0] * display.slm_shape[1]
    pts = []
    for it, field in sorted(result.checkpoints.items()):
        m = image_metrics(display.intensity(field), target, n_slm)
        pts.append((result.checkpoint_seconds[it], it, m["psnr_full"]))
    return pts


def evaluate_images(images, size: int, factors=(4, 16, 36), methods=METHODS, seeds=(0,),
                    steps: int = 200, checkpoints=(10, 25, 50, 100),
                    progress=None, device: str = "cpu") -> list[dict]:
    """Run every method on every image, factor and mask seed; one record per run.

    Parameters
    ----------
    images : list of (str, numpy.ndarray)
        ``(name, image)`` pairs (raw images; :func:`.protocol.prepare_target` is
        applied here at ``size x size``).
    size : int
        Target grid ``N`` (480 for the benchmark, 240 in the test suite); divisible
        by ``sqrt(factor)`` for every factor.
    factors : iterable of int
        Étendue factors (perfect squares).
    methods : iterable of str
        From :data:`METHODS` and ``"no-mask"``.
    seeds : iterable of int
        Mask seeds; the one-step target phase uses ``seed + PHASE_SEED_OFFSET``.
    steps : int
        Most gradient steps (iterations) of the optimiser
        (:func:`recon.cgh.optimize_hologram`'s ``steps``).
    checkpoints : iterable of int
        Iterations at which the PSNR curve (for the PSNR-vs-seconds chart) is sampled.
    progress : callable, optional
        ``progress(done, total, record)`` after each run.
    device : {"cpu", "cuda", "auto"}
        Where the optimiser runs (:func:`.optimize.optimize_hologram`); the one-step
        baseline and the metrics run on the CPU.

    Returns
    -------
    list of dict
        ``image, factor, method, seed, size, seconds, iterations,
        ffts_per_iteration`` and the metrics of :func:`.protocol.image_metrics`,
        plus ``curve`` = ``[(seconds, iteration, psnr_full), ...]``.
    """
    methods = tuple(methods)
    bad = [m for m in methods if m not in (*METHODS, "no-mask")]
    if bad:
        raise ReconInputError(f"unknown method(s) {bad}; choose from {(*METHODS, 'no-mask')}")
    ks = {int(f): factor_to_k(int(f)) for f in factors}
    for f, k in ks.items():
        if size % k:
            raise ReconInputError(f"size {size} is not divisible by k = {k} (factor {f}); use "
                                  "a multiple of 6 such as 240 or 480")
    if not images:
        raise ReconInputError("no images to evaluate")
    targets = [(name, prepare_target(img, size)) for name, img in images]
    raw = dict(images)
    marks = tuple(c for c in checkpoints if c < steps) + (steps,)
    total = len(targets) * len(ks) * len(tuple(seeds)) * len(methods)
    records = []
    for f, k in ks.items():
        for seed in seeds:
            display = ScatteringDisplay((size // k, size // k), k, mask_seed=int(seed))
            n_slm = (size // k) ** 2
            phase_seed = int(seed) + PHASE_SEED_OFFSET
            for name, target in targets:
                for method in methods:
                    rec = {"image": name, "factor": f, "method": method, "seed": int(seed),
                           "size": size}
                    if method == "no-mask":
                        native = prepare_target(raw[name], size // k)
                        nd = ScatteringDisplay.no_mask(native.shape)
                        res = optimize_hologram(nd, native, IntensityLoss.frequency(),
                                                steps, seed=phase_seed, checkpoints=marks,
                                                device=device)
                        rec.update(image_metrics(nd.intensity(res.field), native, n_slm))
                        rec["curve"] = _curve(nd, native, res)
                    else:
                        if method == "one-step":
                            res = one_step_hologram(display, target, seed=phase_seed)
                        else:
                            res = optimize_hologram(display, target, _LOSSES[method](),
                                                    steps, seed=phase_seed,
                                                    checkpoints=marks, device=device)
                        rec.update(image_metrics(display.intensity(res.field), target, n_slm))
                        rec["curve"] = (_curve(display, target, res) if res.iterations else
                                        [(res.seconds, 0, rec["psnr_full"])])
                    rec.update(seconds=res.seconds, iterations=res.iterations,
                               ffts_per_iteration=res.ffts_per_iteration)
                    records.append(rec)
                    if progress is not None:
                        progress(len(records), total, rec)
    return records


def summarise(records) -> dict:
    """Means and spreads per cell ``(factor, method, region)``.

    Returns
    -------
    dict
        ``cells``: ``{(factor, method, region): {"psnr", "ssim", "psnr_std",
        "ssim_std", "n", "seed_psnr": {seed: mean}, "seconds"}}``.
    """
    groups = defaultdict(list)
    for r in records:
        groups[(r["factor"], r["method"])].append(r)
    cells = {}
    for (f, m), rs in groups.items():
        for region in ("full", "centre"):
            p = np.array([r[f"psnr_{region}"] for r in rs])
            s = np.array([r[f"ssim_{region}"] for r in rs])
            per_seed = defaultdict(list)
            for r in rs:
                per_seed[r["seed"]].append(r[f"psnr_{region}"])
            cells[(f, m, region)] = {
                "psnr": float(p.mean()), "ssim": float(s.mean()),
                "psnr_std": float(p.std()), "ssim_std": float(s.std()), "n": len(rs),
                "seed_psnr": {k: float(np.mean(v)) for k, v in sorted(per_seed.items())},
                "seconds": float(np.mean([r["seconds"] for r in rs])),
            }
    return {"cells": cells}


def acceptance(summary: dict, records, psnr_tol: float = 1.5, ssim_tol: float = 0.07,
               seed_tol: float = 0.3) -> list[dict]:
    """The pre-registered acceptance rules (docs/protocols.md, "Table 7.1").

    1. ordering freq > L2 > one-step (full-FoV PSNR) on >= 90 % of the images for
       every factor and seed (9 of 10);
    2. the freq - L2 gap shrinks from the smallest to the largest factor;
    3. one-step SSIM rises with the factor;
    4. every mean cell within ``psnr_tol`` dB and ``ssim_tol`` of Table 7.1 (also
       reported for the core cells: full FoV, one-step / L2 / frequency);
    5. every cell's mean PSNR varies by at most ``seed_tol`` dB across mask seeds.

    Returns
    -------
    list of dict
        ``{"rule", "passed" (bool or None when not applicable), "detail"}``.
    """
    cells = summary["cells"]
    out = []
    by = defaultdict(dict)
    for r in records:
        by[(r["factor"], r["seed"], r["image"])][r["method"]] = r["psnr_full"]
    counts = defaultdict(lambda: [0, 0])
    for (f, seed, _), m in by.items():
        if all(k in m for k in ("one-step", "l2", "frequency")):
            c = counts[(f, seed)]
            c[0] += m["frequency"] > m["l2"] > m["one-step"]
            c[1] += 1
    ok = [c[0] >= math.ceil(0.9 * c[1]) for c in counts.values()]
    out.append({"rule": "1 ordering freq > L2 > one-step on >= 90% of images",
                "passed": all(ok) if ok else None,
                "detail": ", ".join(f"{f}x seed {s}: {c[0]}/{c[1]}"
                                    for (f, s), c in sorted(counts.items()))})
    fs = sorted({f for f, _, _ in cells})
    if len(fs) >= 2 and all((f, m, "full") in cells for f in fs for m in ("l2", "frequency")):
        gaps = [cells[(f, "frequency", "full")]["psnr"] - cells[(f, "l2", "full")]["psnr"]
                for f in fs]
        out.append({"rule": "2 freq - L2 gap shrinks with the factor",
                    "passed": bool(all(a > b for a, b in zip(gaps, gaps[1:], strict=False))),
                    "detail": ", ".join(f"{f}x {g:.2f} dB" for f, g in zip(fs, gaps,
                                                                          strict=True))})
    if len(fs) >= 2 and all((f, "one-step", "full") in cells for f in fs):
        ss = [cells[(f, "one-step", "full")]["ssim"] for f in fs]
        out.append({"rule": "3 one-step SSIM rises with the factor",
                    "passed": bool(all(a < b for a, b in zip(ss, ss[1:], strict=False))),
                    "detail": ", ".join(f"{f}x {s:.3f}" for f, s in zip(fs, ss, strict=True))})
    for label, core in (("4 all cells", False), ("4 core cells (full FoV, 3 methods)", True)):
        fails, n = [], 0
        for key, (p_ref, s_ref) in TABLE_7_1.items():
            f, region, m = key
            if (f, m, region) not in cells or (core and (region != "full" or m == "spatial")):
                continue
            n += 1
            c = cells[(f, m, region)]
            dp, ds = c["psnr"] - p_ref, c["ssim"] - s_ref
            if abs(dp) > psnr_tol or abs(ds) > ssim_tol:
                fails.append(f"{f}x {region} {m}: {dp:+.2f} dB, {ds:+.3f}")
        out.append({"rule": f"{label} within {psnr_tol} dB / {ssim_tol} SSIM of Table 7.1",
                    "passed": (not fails) if n else None,
                    "detail": f"{n - len(fails)}/{n} cells pass" + (
                        "; misses: " + "; ".join(fails) if fails else "")})
    spreads = {k: max(v["seed_psnr"].values()) - min(v["seed_psnr"].values())
               for k, v in cells.items() if len(v["seed_psnr"]) >= 2}
    if spreads:
        worst = max(spreads, key=spreads.get)
        out.append({"rule": f"5 seed stability <= {seed_tol} dB",
                    "passed": bool(spreads[worst] <= seed_tol),
                    "detail": f"largest spread {spreads[worst]:.2f} dB at "
                              f"{worst[0]}x {worst[1]} {worst[2]} over "
                              f"{len(cells[worst]['seed_psnr'])} seeds"})
    else:
        out.append({"rule": f"5 seed stability <= {seed_tol} dB", "passed": None,
                    "detail": "needs at least 2 seeds"})
    return out
