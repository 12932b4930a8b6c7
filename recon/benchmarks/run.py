"""Run the reconstruction benchmarks and write their results (:func:`run_benchmarks`).

``diffuserlab benchmark recon [--out DIR] [--quick] [--only NAME]`` calls it and
prints every benchmark's table (:func:`format_result`) and the summary. It writes
``speed.json``, ``accuracy.json`` + ``accuracy_psnr_vs_seconds.png``,
``stability.json`` + ``stability.png``, ``erasure.json`` + ``erasure.png``, the 3D
benchmarks' ``volume_speed.json`` (:mod:`recon.benchmarks.volume`) and
``volume_accuracy.json`` + ``volume_accuracy.png``
(:mod:`recon.benchmarks.volume_accuracy`), the spatially varying models'
``spatial_speed.json`` and ``spatial_accuracy.json`` + ``spatial_psnr_vs_seconds.png``
(:mod:`recon.benchmarks.spatial`), a far scene through the spatially varying camera's
``spatial_far.json`` + ``spatial_far.png`` (:mod:`recon.benchmarks.spatial_far`: the
two-part model and its ADMM), compressive calibration against centre-only and
grid calibration's ``blind_calibration.json`` + ``blind_calibration.png``
(:mod:`recon.benchmarks.blind`, Fig. 5.4d), the automatic 3D weight against the
oracle's ``volume_auto.json`` (:mod:`recon.benchmarks.volume_auto`), our 3D solvers
beside LenslessPiCam's on the external 3D sample's ``volume_external.json`` +
``volume_external.png`` (:mod:`recon.benchmarks.volume_external`), and
``summary.json`` under ``out`` and
returns a compact summary. The weights chosen by the accuracy sweep are used by the
stability and erasure benchmarks when they run in the same invocation; otherwise
:data:`recon.benchmarks.DEFAULT_WEIGHTS`. When the 2D and 3D accuracy benchmarks run
together, the speed-vs-accuracy chart ``accuracy_psnr_vs_seconds.png`` gets a
panel with the 3D methods (tilted-target volume PSNR against seconds), and one with
the spatially varying models when ``spatial_accuracy`` ran.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import ReconInputError
from ..options import BENCHMARKS  # the benchmarks, in the order they run
from . import DEFAULT_WEIGHTS, METHODS, fmt, machine_record, write_json

__all__ = ["BENCHMARKS", "format_result", "run_benchmarks", "summarise"]

log = logging.getLogger(__name__)


#: (module, function) of each benchmark's text table (imported when needed: the
#: benchmark modules are heavy).
_TABLES = {"speed": ("speed", "speed_table"), "accuracy": ("accuracy", "accuracy_table"),
           "stability": ("stability", "stability_table"),
           "erasure": ("erasure", "erasure_table"),
           "volume_speed": ("volume", "volume_speed_table"),
           "volume_accuracy": ("volume_accuracy", "volume_accuracy_table"),
           "spatial_speed": ("spatial", "spatial_speed_table"),
           "spatial_accuracy": ("spatial", "spatial_accuracy_table"),
           "spatial_far": ("spatial_far", "spatial_far_table"),
           "blind_calibration": ("blind", "blind_calibration_table"),
           "auto": ("auto", "auto_table"),
           "failure_maps": ("failure_maps", "failure_maps_table"),
           "failure_map_3d": ("failure_map_3d", "failure_map_3d_table"),
           "volume_auto": ("volume_auto", "volume_auto_table"),
           "volume_external": ("volume_external", "volume_external_table")}


def format_result(name: str, result: dict) -> str:
    """The text table of one benchmark's result (e.g. :func:`.speed.speed_table`).

    Parameters
    ----------
    name : str
        One of :data:`BENCHMARKS`.
    result : dict
        What its ``run_*`` function returned.

    Returns
    -------
    str
    """
    module, function = _TABLES[name]
    return getattr(importlib.import_module(f".{module}", __package__), function)(result)


def summarise(results: dict) -> tuple[dict, str]:
    """Compact figures and their text from the benchmark results."""
    summary: dict = {}
    lines = ["== summary =="]
    if "speed" in results:
        sp = {}
        for bf, r in results["speed"]["bins"].items():
            sp[bf] = {m: d["ratio"] for m, d in r["methods"].items()}
            lines.append(f"speed bin {bf} (x FFT floor {r['fft_floor_seconds'] * 1e3:.2f} ms): "
                         + ", ".join(f"{m} {d['ratio']:.2f}"
                                     + ("" if d["goal"] is None else
                                        (" ok" if d["meets_goal"] else " MISSED"))
                                     for m, d in r["methods"].items()))
        summary["speed_ratio"] = sp
    if "accuracy" in results:
        a = results["accuracy"]
        summary["chosen_weights"] = a["chosen_weights"]
        summary["accuracy_psnr"] = {m: f["psnr_mean"] for m, f in a["final"].items()}
        summary["accuracy_ssim"] = {m: f["ssim_mean"] for m, f in a["final"].items()}
        lines.append("accuracy (mean over scenes, largest budget): " + ", ".join(
            f"{m} {fmt(f['psnr_mean'])} dB/{fmt(f['ssim_mean'], '.3f')} (w {f['weight']:g}, "
            f"{fmt(f['seconds_mean'], '.2f')} s)" for m, f in a["final"].items()))
    if "stability" in results:
        s = results["stability"]
        summary["stability_failures"] = s["failures"]
        for sweep in ("noise", "erasure"):
            lines.append(f"stability {sweep} (first failing point: <bound / -3dB / no conv): "
                         + "; ".join(f"{m} {fmt(f['below_bound'], 'g')}/"
                                     f"{fmt(f['drop_from_best'], 'g')}/"
                                     f"{fmt(f['not_converged'], 'g')}"
                                     for m, f in s["failures"][sweep].items()))
    if "erasure" in results:
        e = results["erasure"]
        summary["erasure"] = {
            "real_vs_full_psnr": {k: v["psnr"] for k, v in e["real"]["vs_full"].items()},
            "sim_vs_truth_psnr": {k: v["psnr"] for k, v in e["simulated"]["vs_truth"].items()},
        }
        lines.append("erasure 80% real (PSNR vs full recon): " + ", ".join(
            f"{k} {fmt(v['psnr'])}" for k, v in e["real"]["vs_full"].items()))
        lines.append("erasure 80% simulated (PSNR vs truth): " + ", ".join(
            f"{k} {fmt(v['psnr'])}" for k, v in e["simulated"]["vs_truth"].items()))
    _summarise_volume(results, summary, lines)
    if "auto" in results:
        a = results["auto"]["summary"]
        summary["auto"] = a
        lines.append(f"auto TV weight: {fmt(a['mean_shortfall_db'])} dB below the oracle on "
                     f"average, {fmt(a['worst_shortfall_db'])} at worst; time "
                     f"x{fmt(a['cost_ratio_median'])} of a fixed run (median), "
                     f"x{fmt(a['cost_ratio_max'])} at most")
    if "spatial_far" in results:
        cases = results["spatial_far"]["cases"]
        gains = [c["methods"]["two-part auto"]["psnr_db"] - c["methods"]["on-axis"]["psnr_db"]
                 for c in cases]
        summary["spatial_far_gain_db"] = gains
        lines.append("far scene, spatially varying camera: two-part auto model (ADMM) "
                     f"{fmt(float(np.mean(gains)))} dB above the on-axis PSF on average "
                     f"({', '.join(fmt(g) for g in gains)})")
    for name in ("spatial_speed", "spatial_accuracy", "blind_calibration"):
        if name in results:  # the figure's image crops stay in their own JSON file
            summary[name] = {k: v for k, v in results[name].items() if k != "images"}
            lines.append(format_result(name, results[name]))
    return summary, "\n".join(lines)


def _summarise_volume(results: dict, summary: dict, lines: list[str]) -> None:
    """The 3D benchmarks' figures and lines (see :func:`summarise`)."""
    if "volume_speed" in results:
        v = results["volume_speed"]
        summary["volume_speed_ratio"] = {"x".join(map(str, r["shape"])): {
            m: d["ratio"] for m, d in r["methods"].items()} for r in v["sizes"]}
        summary["volume_memory_max_rss_bytes"] = {
            f"{m['method']} {'x'.join(map(str, m['shape']))}": m["max_rss_bytes"]
            for m in v["memory"]}
        for r in v["sizes"]:
            lines.append(f"3D speed {'x'.join(map(str, r['shape']))} (x FFT floor "
                         f"{r['fft_floor_seconds'] * 1e3:.1f} ms, goal {v['goal']}): " + ", ".join(
                             f"{m} {d['ratio']:.2f}" + (" ok" if d["meets_goal"] else " MISSED")
                             for m, d in r["methods"].items()))
        lines.append("3D memory alone (max RSS, budget 4 GB): " + ", ".join(
            f"{m['method']} {'x'.join(map(str, m['shape']))} {m['max_rss_bytes'] / 2**30:.2f} GiB"
            for m in v["memory"]))
    if "volume_auto" in results:
        a = results["volume_auto"]["summary"]
        summary["volume_auto"] = a
        lines.append(f"3D auto TV weight: {fmt(a['mean_shortfall_db'])} dB below the oracle on "
                     f"average, {fmt(a['worst_shortfall_db'])} at worst; objects off their "
                     f"depth {a['objects_off_depth']} of {a['objects']}")
    if "volume_external" in results:
        e = results["volume_external"]
        summary["volume_external"] = {k: e[k] for k in ("ratios", "agreement", "default")}
        lines.append(format_result("volume_external", e))
    if "volume_accuracy" in results:
        a = results["volume_accuracy"]
        fin = a["final"]
        summary["volume_accuracy"] = {
            m: {"bead_lateral_um_mean": fin["beads"][m].get("lateral_um_mean"),
                "bead_axial_planes_max_abs": fin["beads"][m].get("axial_planes_max_abs"),
                "beads_missed": fin["beads"][m].get("missed"),
                "beads_spurious": fin["beads"][m].get("spurious"),
                "target_psnr": fin["target"][m].get("psnr"),
                "target_ssim": fin["target"][m].get("ssim"),
                "ratio_to_fft_floor": a["speed"][m]["ratio_median"]} for m in fin["beads"]}
        summary["volume_chosen_weights"] = a["chosen"]
        lines.append("3D beads (largest budget): " + ", ".join(
            f"{m} lateral {fmt(b.get('lateral_um_mean'), '.1f')} um, max axial "
            f"{fmt(b.get('axial_planes_max_abs'))} planes, missed/spurious "
            f"{b.get('missed')}/{b.get('spurious')}" for m, b in fin["beads"].items()))
        lines.append("3D tilted target (largest budget): " + ", ".join(
            f"{m} {fmt(t.get('psnr'))} dB/{fmt(t.get('ssim'), '.3f')} (x floor "
            f"{fmt(a['speed'][m]['ratio_median'])})" for m, t in fin["target"].items())
            + f"; zero volume {a['baselines']['zero_volume']['psnr']:.2f} dB, back-projection "
            f"{a['baselines']['back_projection']['psnr']:.2f} dB")


def run_benchmarks(out: Path, *, quick: bool = False, only: str | None = None,
                   on_result: Callable[[str, dict, float], None] | None = None
                   ) -> tuple[dict, str]:
    """Run the selected benchmarks and write their files and ``summary.json``.

    The weights chosen by the accuracy sweep are used by the stability and erasure
    benchmarks of the same call (otherwise :data:`recon.benchmarks.DEFAULT_WEIGHTS`).
    Progress is logged (``-- NAME --`` at INFO, seconds at DEBUG).

    Parameters
    ----------
    out : Path
        Output directory (created).
    quick : bool
        Fewer iterations and sweep points, small 3D problems (tests/CI, about 1 min).
    only : str, optional
        One name of :data:`BENCHMARKS`; default all.
    on_result : callable, optional
        Called as ``on_result(name, result, seconds)`` after each benchmark (the CLI
        prints ``format_result(name, result)``).

    Returns
    -------
    summary : dict
        What ``summary.json`` holds: :func:`summarise`'s figures plus ``quick``,
        ``weights_used``, ``seconds`` per benchmark and ``methods``.
    text : str
        The summary lines.

    Raises
    ------
    ReconInputError
        ``only`` is not a benchmark, or a benchmark refused its input (e.g. the
        DiffuserCam sample is missing).
    """
    from .accuracy import plot_accuracy, run_accuracy
    from .erasure import run_erasure
    from .speed import run_speed
    from .stability import run_stability
    from .volume import run_volume_speed
    from .volume_accuracy import run_volume_accuracy

    if only is not None and only not in BENCHMARKS:
        raise ReconInputError(f"unknown benchmark {only!r}; choose one of "
                              f"{', '.join(BENCHMARKS)}")
    selected = [only] if only else list(BENCHMARKS)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    machine = machine_record()
    weights = dict(DEFAULT_WEIGHTS)
    timings = {}
    for name in selected:
        t0 = time.perf_counter()
        log.info("-- %s --", name)
        if name == "speed":
            results[name] = run_speed(quick, out)
        elif name == "accuracy":
            results[name] = run_accuracy(quick, out)
            weights.update(results[name]["chosen_weights"])
        elif name == "stability":
            results[name] = run_stability(quick, out, weights)
        elif name == "erasure":
            results[name] = run_erasure(quick, out, weights)
        elif name == "volume_speed":
            results[name] = run_volume_speed(quick, out)
        elif name in ("auto", "failure_maps", "failure_map_3d", "volume_auto",
                      "volume_external"):
            from . import auto, failure_map_3d, failure_maps, volume_auto, volume_external

            run = {"auto": auto.run_auto, "failure_maps": failure_maps.run_failure_maps,
                   "failure_map_3d": failure_map_3d.run_failure_map_3d,
                   "volume_auto": volume_auto.run_volume_auto,
                   "volume_external": volume_external.run_volume_external}[name]
            results[name] = run(quick, out)
        elif name == "blind_calibration":
            from .blind import run_blind_calibration

            results[name] = run_blind_calibration(quick, out)
        elif name == "spatial_far":
            from .spatial_far import run_spatial_far

            results[name] = run_spatial_far(quick, out)
        elif name.startswith("spatial_"):
            from . import spatial

            results[name] = getattr(spatial, f"run_{name}")(quick, out)
        else:
            results[name] = run_volume_accuracy(quick, out)
        timings[name] = time.perf_counter() - t0
        log.debug("(%s: %.1f s)", name, timings[name])
        if on_result is not None:
            on_result(name, results[name], timings[name])
    if "accuracy" in results and ("volume_accuracy" in results
                                  or "spatial_accuracy" in results):
        plot_accuracy(results["accuracy"], out / "accuracy_psnr_vs_seconds.png",
                      volume=results.get("volume_accuracy"),
                      spatial=results.get("spatial_accuracy"))
    summary, text = summarise(results)
    summary.update(quick=quick, weights_used=weights, seconds=timings,
                   methods=list(METHODS), machine=machine)
    write_json(out / "summary.json", summary)
    return summary, text
