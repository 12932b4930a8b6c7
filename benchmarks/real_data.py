"""Reconstruction methods on real measurements with ground truth, leave-one-out.

Run with ``python -m benchmarks.real_data [--data DIR] [--psf-dir DIR] [--out DIR]
[--pairs N] [--bin B] [--iterations N] [--weights W,...] [--methods M,...]
[--lensless-path DIR] [--overwrite]``.

Data: the five DiffuserCam pairs of ``shared/data/mirflickr-real`` (a photograph on a
monitor, captured by the lensless camera and, registered, by a lensed one). Each pair
is reconstructed with the PSF estimated from the *other* pairs as the scene calibration
makes it: with the sensor response fitted on those pairs
(:func:`benchmarks.real_priors.load_sensor_psfs`; ``--without-sensor-response``: the
PSF alone, :func:`benchmarks.real_priors.load_psfs`), read from ``--psf-dir`` when
there, else computed and saved there (with ``--bin`` above 1 or fewer ``--pairs``
always computed, in memory). Every method gets that PSF and the measurement as
captured (the response is a nuisance of the PSF's estimate).
The estimate is scored against the lensed image after a per-channel least-squares
gain, clipped to [0, 1] (:func:`benchmarks.real_priors.score`: PSNR and SSIM by
scikit-image); each reconstruction is timed (wall clock), and the
time is also stated over the FFT floor (:func:`recon.fft.fft_pair_seconds`: one rfft2 +
irfft2 pair at the padded grid, float32) measured in the same run, so that runs on
machines under different load compare.

The methods are the entries of :data:`METHODS` (:class:`Method`), in order:

- ``default``: :func:`recon.reconstruct` as ``diffuserlab recon --dark none`` runs it
  (automatic method, the declared default prior -- isotropic TV --, automatic weight,
  its own iteration cap);
- ``admm-tv-auto``: the same with ``prior="tv"`` (anisotropic TV, the default before
  issue 65: block mosaics);
- ``admm-<prior>-oracle``: our ADMM with each prior of :data:`ORACLE_PRIORS` at every
  fixed weight of ``--weights``; the oracle is the one weight of that grid with the best
  mean PSNR over the pairs (it sees the truth: an upper bound for a fixed weight);
- ``lensless-admm``: LenslessPiCam's ADMM (``lensless.ADMM``, its default
  parameters, 100 iterations), when the package imports (it pins an old NumPy, so it
  is no dependency of the project: install it with ``pip install --no-deps
  --target DIR lensless`` and give ``--lensless-path DIR`` or
  ``DIFFUSERLAB_LENSLESS_PATH``); otherwise one line says so and its column is left out;
- ``lensless-admm-field``: the same, its image multiplied by the field response of the
  scene-calibrated recipe fitted without the pair (:mod:`recon.field_response`): the
  peer given what our calibration learns besides the PSF.

Another method is one more :class:`Method` in :data:`METHODS` (or passed to
:func:`run_benchmark`): a name, a label and ``solve(psf, raw, weight, iterations)``
returning the (H, W, 3) estimate on the sensor grid.

Writes in ``--out`` (default ``out/benchmark/real_data``): ``real_data.json`` (the
machine, the FFT floor, every pair and method: PSNR, SSIM, seconds, time ratio, the
block-tiling score of :func:`tiling_score` and the truth's; the means and each oracle's
weight), ``contact.png`` (one row per pair: the lensed truth,
then each method, gain-fitted) and ``speed_accuracy.png`` (PSNR against the time
ratio, each pair and the means); an ``--out`` holding them is refused (one line, exit
status 2) unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import platform
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.psf_from_scenes import NAMES, load_pairs
from benchmarks.real_priors import (
    add_pair_options,
    contact_sheet,
    gain_fit,
    load_psfs,
    load_sensor_psfs,
    score,
)
from benchmarks.real_recipe import calibrate_recipe, family_oracle, solve_recipe

__all__ = ["AXIS_TOLERANCE_DEG", "METHODS", "Method", "ORACLE_PRIORS", "import_lensless", "main",
           "plot_speed_accuracy", "run_benchmark", "summary_lines", "tiling_score"]

#: Priors of the oracle ADMM entries, and their default weight grid.
ORACLE_PRIORS = ("tv", "tv-iso")
WEIGHTS = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2)
#: Where ``--lensless-path`` is read from when not given.
LENSLESS_ENV = "DIFFUSERLAB_LENSLESS_PATH"
LENSLESS_HINT = ("LenslessPiCam is not importable: install it with `pip install --no-deps "
                 "--target DIR lensless==1.0.8` and give --lensless-path DIR (or "
                 f"{LENSLESS_ENV}=DIR); running without its column")
LENSLESS_ITERATIONS = 100
#: What a run writes in ``--out`` (refused when there, unless ``--overwrite``).
OUTPUTS = ("real_data.json", "contact.png", "speed_accuracy.png")


@dataclass(frozen=True)
class Method:
    """One column of the benchmark.

    Parameters
    ----------
    name : str
        Key in the JSON and for ``--methods``.
    label : str
        Title in the contact sheet and the chart.
    solve : callable
        ``solve(psf, raw, weight, iterations) -> ndarray``: ``psf`` and ``raw`` float32
        (H, W, 3) (dark-subtracted), ``weight`` one of ``weights`` (None when
        ``weights`` is empty), ``iterations`` the ``--iterations`` cap or None (the
        method's own); returns the (H, W, 3) estimate on the sensor grid (any scale:
        a per-channel gain is fitted before scoring).
    oracle : bool
        Run at every weight of the ``--weights`` grid and report the one with the best
        mean PSNR (the weight is chosen on the truth).
    available : callable or None
        ``available() -> str | None``: None when the method can run, else the one
        line that says how to get it (the column is then left out).
    calibrate : callable or None
        ``calibrate(k, scenes, measurements, psf) -> dict``: a calibration fitted on
        the pairs other than ``k`` before pair ``k`` is solved (timed apart, as
        ``calibration_seconds``); the dict's items are passed to
        ``solve`` as keywords. Such a method also gets its family's per-pair oracle
        (:func:`benchmarks.real_recipe.family_oracle`), unless ``scores_family`` is
        False.
    scores_family : bool
        With ``calibrate``: also score the recipe's grid on the pair (its family's
        oracle); False for a column whose solve is not the recipe's.
    """

    name: str
    label: str
    solve: Callable = field(repr=False)
    oracle: bool = False
    available: Callable | None = field(default=None, repr=False)
    calibrate: Callable | None = field(default=None, repr=False)
    scores_family: bool = True


def _automatic(prior: str | None):
    """``recon.reconstruct(psf, raw, dark="none")``: the default, or with ``prior`` named."""
    def solve(psf, raw, weight, iterations):
        import recon

        kw = {} if iterations is None else {"iterations": iterations}
        kw.update({} if prior is None else {"prior": prior})
        return np.asarray(recon.reconstruct(psf, raw, dark="none", **kw).image)
    return solve


def _admm(prior: str):
    def solve(psf, raw, weight, iterations):
        import recon

        kw = {} if iterations is None else {"iterations": iterations}
        return np.asarray(recon.reconstruct(psf, raw, method="admm", prior=prior, tv=weight,
                                            dark="none", **kw).image)
    return solve


#: Angle (degrees) from the pixel axes within which a gradient counts as axis-aligned
#: in :func:`tiling_score`.
AXIS_TOLERANCE_DEG = 1.0


def tiling_score(image: np.ndarray, tolerance_deg: float = AXIS_TOLERANCE_DEG) -> float:
    """The fraction of an image's gradient energy on axis-aligned edges: block tiling.

    Anisotropic TV (the l1 norm of the x and y differences separately) makes
    piecewise-constant blocks whose edges lie along the pixel axes: one of the two
    differences is exactly zero across most of its edges. So the share of the squared
    gradient whose direction lies within ``tolerance_deg`` of an axis measures the
    tiling: about ``4 tolerance_deg / 180`` (0.022 at 1 degree) for gradients of
    every direction alike, 0.04-0.28 for the lensed truths of the real pairs (their
    monitor's edges are axis-aligned), 0.3-0.45 for anisotropic TV's mosaics there.

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C), real
        The estimate (a colour image is averaged over its channels first).
    tolerance_deg : float
        Half-width of the axis-aligned sector, degrees.

    Returns
    -------
    float
        In [0, 1] (0 for a flat image). Forward differences dx = y[i, j+1] - y[i, j],
        dy = y[i+1, j] - y[i, j] on the (H-1, W-1) grid; the angle is
        atan2(|dy|, |dx|).
    """
    y = np.asarray(image, np.float64)
    y = y.mean(-1) if y.ndim == 3 else y
    dx, dy = np.diff(y, axis=1)[:-1, :], np.diff(y, axis=0)[:, :-1]
    energy = dx * dx + dy * dy
    total = float(energy.sum())
    if total <= 0:
        return 0.0
    angle = np.degrees(np.arctan2(np.abs(dy), np.abs(dx)))
    near = (angle < tolerance_deg) | (angle > 90.0 - tolerance_deg)
    return float(energy[near].sum() / total)


def import_lensless(path: str | os.PathLike | None = None):
    """The ``lensless`` package (LenslessPiCam), from ``path`` (or
    :data:`LENSLESS_ENV`) put first on ``sys.path``; None when it does not import."""
    path = path or os.environ.get(LENSLESS_ENV)
    if path and str(path) not in sys.path:
        sys.path.insert(0, str(path))
    try:
        return importlib.import_module("lensless")
    except Exception:  # noqa: BLE001 - any failure to import means "not available"
        return None


def _lensless_available():
    return None if import_lensless() is not None else LENSLESS_HINT


def _lensless_admm(psf, raw, weight, iterations):
    lensless = import_lensless()
    h = psf.astype(np.float32)
    h = h / np.linalg.norm(h.ravel())
    rec = lensless.ADMM(h[None])
    rec.set_data(raw.astype(np.float32)[None])
    est = np.asarray(rec.apply(n_iter=iterations or LENSLESS_ITERATIONS, disp_iter=None,
                               plot=False))
    return est.reshape(raw.shape)


def _lensless_admm_field(psf, raw, weight, iterations, recipe=None):
    """LenslessPiCam's ADMM, its image multiplied by the field response of the
    scene-calibrated recipe fitted for the pair (what the calibration's field response,
    not the solver, buys; none when the recipe kept none)."""
    from recon.field_response import apply_field_response

    return apply_field_response(_lensless_admm(psf, raw, weight, iterations),
                                recipe.field_response)


#: The benchmark's columns, in order (append a :class:`Method` to add one).
METHODS: list[Method] = [
    Method("scene-recipe", "default, scene-calibrated (recon --psf RUN)", solve_recipe,
           calibrate=calibrate_recipe),
    Method("default", "point-source default (recon --dark none)", _automatic(None)),
    Method("admm-tv-auto", "ADMM tv, automatic weight (the former default)",
           _automatic("tv")),
    *[Method(f"admm-{p}-oracle", f"ADMM {p}, oracle weight", _admm(p), oracle=True)
      for p in ORACLE_PRIORS],
    Method("lensless-admm", "LenslessPiCam ADMM (100 it.)", _lensless_admm,
           available=_lensless_available),
    Method("lensless-admm-field", "LenslessPiCam ADMM x the recipe's field response",
           _lensless_admm_field, available=_lensless_available, calibrate=calibrate_recipe,
           scores_family=False),
]


def machine() -> dict:
    """The machine's description for the JSON: platform, CPUs, Python, NumPy, load."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {"platform": platform.platform(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__,
            "load_average_at_start": load,
            "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime())}


def _psfs(psf_dir, names, bin_factor, scenes, measurements, sensor: bool):
    """Each pair's leave-one-out PSF (with the sensor response, or without)."""
    kept = bin_factor == 1 and len(names) == len(NAMES) and psf_dir is not None
    if sensor:
        return load_sensor_psfs(Path(psf_dir) if kept else None, names, scenes, measurements)
    if kept:
        return load_psfs(Path(psf_dir), names, scenes, measurements)
    from recon.analysis.psf_from_scenes import leave_one_out

    return [np.asarray(p, np.float32) for p in leave_one_out(scenes, measurements).psfs]


def _run_one(method, psf, raw, truth, weight, iterations, floor_s, context=None):
    t0 = time.perf_counter()
    image = method.solve(psf, raw, weight, iterations, **(context or {}))
    seconds = time.perf_counter() - t0
    est = gain_fit(np.asarray(image, np.float32), truth)
    psnr, ssim = score(est, truth)
    return est, {"psnr_db": psnr, "ssim": ssim, "seconds": seconds,
                 "time_ratio": seconds / floor_s, "tiling": tiling_score(est),
                 "tiling_truth": tiling_score(truth)}


def _warm_up(method, psf, raw, weight):
    """One untimed solve on a small centre crop, 2 iterations: imports, plans, caches."""
    r, c = psf.shape[0] // 4, psf.shape[1] // 4
    before = logging.root.manager.disable
    logging.disable(logging.WARNING)  # two iterations do not settle: not news
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            method.solve(psf[r:-r or None, c:-c or None], raw[r:-r or None, c:-c or None],
                         weight, 2)
    finally:
        logging.disable(before)


def _mean(rows, key):
    return float(np.mean([r[key] for r in rows]))


def run_benchmark(out: Path, data_dir: Path | None = None, psf_dir: Path | None = None,
                  pairs: int = len(NAMES), bin_factor: int = 1,
                  iterations: int | None = None, weights=WEIGHTS, methods=None,
                  log=print, sensor_response: bool = True) -> dict:
    """Every method of ``methods`` (default :data:`METHODS`) on the first ``pairs`` pairs.

    Parameters
    ----------
    out : Path
        Directory of ``real_data.json``, ``contact.png`` and ``speed_accuracy.png``.
    data_dir : Path or None
        The pairs (default: ``shared/data/mirflickr-real`` next to the repository).
    psf_dir : Path or None
        Cache of the leave-one-out PSFs (used at full size with all five pairs only).
    pairs : int
        How many pairs, from the first (>= 2: each PSF comes from the others).
    bin_factor : int
        Box binning of scenes and measurements before everything.
    iterations : int or None
        Iteration cap for every method (None: each method's own).
    weights : sequence of float
        The oracle methods' weight grid.
    methods : list of Method or None
        The columns.
    log : callable
        Receives one line per reconstruction.

    Returns
    -------
    dict
        What ``real_data.json`` holds: ``machine``, ``setup``, ``fft_floor_seconds``,
        ``methods`` (name, label, and ``skipped`` with its reason or the
        ``weight`` chosen and ``weight_at_grid_edge``: an oracle's best weight is the
        grid's smallest or largest, so a wider grid may do better), ``rows`` (pair,
        method, weight, psnr_db, ssim, seconds, time_ratio) and ``means`` (per
        method, the oracles' at their chosen weight).

    Raises
    ------
    FileNotFoundError
        A pair is missing.
    """
    from recon.fft import fft_pair_seconds

    methods = list(METHODS if methods is None else methods)
    names = NAMES[:pairs]
    scenes, measurements = load_pairs(data_dir, names, bin_factor)
    psfs = _psfs(psf_dir, names, bin_factor, scenes, measurements, sensor_response)
    rows_px, cols_px = scenes[0].shape[:2]
    floor_s = fft_pair_seconds((2 * rows_px, 2 * cols_px))
    result = {"machine": machine(),
              "setup": {"pairs": list(names), "bin_factor": bin_factor,
                        "shape": [rows_px, cols_px], "iterations": iterations,
                        "weights": [float(w) for w in weights],
                        "sensor_response": bool(sensor_response)},
              "fft_floor_seconds": floor_s, "methods": [], "rows": [], "means": []}
    log(f"FFT floor {floor_s * 1e3:.2f} ms at {2 * rows_px} x {2 * cols_px}")
    sheet, titles = [[s] for s in scenes], ["lensed (truth)"]
    for m in methods:
        why = m.available() if m.available is not None else None
        if m.calibrate is not None and len(names) < 3:
            why = (f"{m.name} needs at least three pairs (each calibration leaves one out "
                   f"of the others); give --pairs 3 or more")
        if why:
            log(why)
            result["methods"].append({"name": m.name, "label": m.label, "skipped": why})
            continue
        grid = [float(w) for w in weights] if m.oracle else [None]
        contexts = [None] * len(names)
        if m.calibrate is not None:  # fitted per pair on the others; also warms up
            contexts, calibration_s = [], []
            for k in range(len(names)):
                t0 = time.perf_counter()
                contexts.append(m.calibrate(k, scenes, measurements, psfs[k], log=log))
                calibration_s.append(time.perf_counter() - t0)
        else:
            _warm_up(m, psfs[0], measurements[0], grid[0])
        mine, images = [], {}
        for w in grid:
            for k, n in enumerate(names):
                est, r = _run_one(m, psfs[k], measurements[k], scenes[k], w, iterations,
                                  floor_s, contexts[k])
                if contexts[k] is not None:
                    recipe = contexts[k]["recipe"]
                    r.update(calibration_seconds=calibration_s[k], recipe=recipe.record())
                    if m.scores_family:
                        r["family_oracle"] = family_oracle(psfs[k], measurements[k],
                                                           scenes[k], recipe)
                mine.append({"pair": n, "method": m.name, "weight": w, **r})
                images[(w, k)] = est
                log(f"{m.name:18s} {w!s:8s} {n:6s} {r['psnr_db']:6.2f} dB {r['ssim']:.3f} "
                    f"{r['seconds']:6.1f} s {r['time_ratio']:8.0f}x floor tiling "
                    f"{r['tiling']:.3f}")
        best = max(grid, key=lambda w: _mean([r for r in mine if r["weight"] == w], "psnr_db"))
        sel = [r for r in mine if r["weight"] == best]
        result["rows"] += mine
        edge = m.oracle and len(grid) > 1 and best in (min(grid), max(grid))
        if edge:
            log(f"{m.name}: the best weight {best:g} is at the edge of the grid; widen "
                "--weights")
        result["methods"].append({"name": m.name, "label": m.label, "weight": best,
                                  "weight_at_grid_edge": bool(edge)})
        result["means"].append({"method": m.name, "weight": best,
                                **{key: _mean(sel, key) for key in
                                   ("psnr_db", "ssim", "seconds", "time_ratio",
                                    "tiling", "tiling_truth")}})
        titles.append(m.label + (f" ({best:g})" if best is not None else ""))
        for k in range(len(names)):
            sheet[k].append(images[(best, k)])
    out.mkdir(parents=True, exist_ok=True)
    (out / "real_data.json").write_text(json.dumps(result, indent=1) + "\n")
    contact_sheet(sheet, titles, names, out / "contact.png")
    plot_speed_accuracy(result, out / "speed_accuracy.png")
    return result


def plot_speed_accuracy(result: dict, path: Path) -> Path:
    """PSNR against wall time over the FFT floor: each pair (small) and each method's
    mean (large), the oracles at their chosen weight."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 4.8))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    marks = "osD^vP*X"
    for i, (m, mean) in enumerate(zip([m for m in result["methods"] if "skipped" not in m],
                                      result["means"], strict=True)):
        sel = [r for r in result["rows"] if r["method"] == m["name"] and r["weight"] == m["weight"]]
        color = f"C{i}"
        ax.plot([r["time_ratio"] for r in sel], [r["psnr_db"] for r in sel], marks[i % 8],
                color=color, ms=5, mfc="none", alpha=0.6)
        ax.plot(mean["time_ratio"], mean["psnr_db"], marks[i % 8], color=color, ms=11,
                label=f"{m['label']}: {mean['psnr_db']:.2f} dB, {mean['seconds']:.1f} s")
    st = result["setup"]
    ax.set(xscale="log", ylabel="PSNR after per-channel gain (dB)",
           xlabel="wall time per image / FFT floor (one rfft2 + irfft2 pair, same run)")
    ax.set_title(f"real pairs ({len(st['pairs'])}, leave-one-out PSFs, {st['shape'][0]} x "
                 f"{st['shape'][1]}): small marks each pair, large the mean", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    if result["means"]:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def main(argv=None) -> int:
    """The command line (module docstring)."""
    prog = "python -m benchmarks.real_data"
    p = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    add_pair_options(p, Path("out/benchmark/real_data"))
    p.add_argument("--bin", type=int, default=1, choices=(1, 2, 3, 5, 6), dest="bin_factor",
                   help="box binning (divides 270 x 480)")
    p.add_argument("--iterations", type=int, default=None,
                   help="iteration cap for every method (default: each method's own)")
    p.add_argument("--weights", default=",".join(f"{w:g}" for w in WEIGHTS),
                   help="the oracle entries' weight grid, comma-separated")
    p.add_argument("--methods", default=None, help="comma-separated names of the columns "
                   f"(default all: {', '.join(m.name for m in METHODS)})")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results of an earlier run in --out")
    p.add_argument("--without-sensor-response", action="store_false",
                   dest="sensor_response",
                   help="estimate each pair's PSF without the sensor response (as before "
                   "2026-11-29)")
    p.add_argument("--lensless-path", default=None,
                   help=f"directory holding the lensless package (or {LENSLESS_ENV})")
    args = p.parse_args(argv)
    try:
        weights = [float(w) for w in args.weights.split(",") if w.strip()]
    except ValueError:
        weights = []
    if not weights:
        print(f"{prog}: error: --weights {args.weights!r}: give numbers separated by commas, "
              "e.g. 1e-4,1e-3", file=sys.stderr)
        return 2
    if args.iterations is not None and args.iterations < 1:
        print(f"{prog}: error: --iterations {args.iterations}: give at least 1", file=sys.stderr)
        return 2
    methods = METHODS
    if args.methods is not None:
        known = {m.name: m for m in METHODS}
        picked = [s.strip() for s in args.methods.split(",") if s.strip()]
        if not picked or any(s not in known for s in picked):
            print(f"{prog}: error: --methods {args.methods!r}: name some of "
                  f"{', '.join(known)}", file=sys.stderr)
            return 2
        methods = [known[s] for s in picked]
    from instrument.writer.guards import OutputError, check_outputs

    try:
        check_outputs([args.out / f for f in OUTPUTS], {"--data": args.data},
                      args.overwrite, directory=args.out)
    except OutputError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    if args.lensless_path:
        os.environ[LENSLESS_ENV] = str(args.lensless_path)
    try:
        r = run_benchmark(args.out, args.data, args.psf_dir, args.pairs, args.bin_factor,
                          args.iterations, weights, methods,
                          sensor_response=args.sensor_response)
    except FileNotFoundError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print("\n".join(summary_lines(r) + [f"wrote {args.out}/real_data.json, contact.png, "
                                        "speed_accuracy.png"]))
    return 0


def summary_lines(result: dict) -> list[str]:
    """One line per method of :func:`run_benchmark`'s result: its means (the oracles'
    at their weight), then a line per method left out."""
    lines = [f"mean {m['method']:18s} {m['weight']!s:8s} {m['psnr_db']:6.2f} dB "
             f"{m['ssim']:.3f} {m['seconds']:6.1f} s {m['time_ratio']:8.0f}x floor "
             f"tiling {m['tiling']:.3f} (truth {m['tiling_truth']:.3f})"
             for m in result["means"]]
    return lines + [f"left out {m['name']}: {m['skipped']}" for m in result["methods"]
                    if "skipped" in m]


if __name__ == "__main__":
    sys.exit(main())
