"""Run the reconstruction benchmarks and studies and write their results
(:func:`run_benchmarks`).

``python -m benchmarks [--out DIR] [--quick] [--only NAME]`` (from a checkout) calls it
and prints every benchmark's table (:func:`format_result`) and the summary; the two
speed benchmarks are the package's (``diffuserlab benchmark recon``,
:mod:`instrument.benchmarks.run`). It writes
``speed.json``, ``accuracy.json`` + ``accuracy_psnr_vs_seconds.png``,
``stability.json`` + ``stability.png``, ``erasure.json`` + ``erasure.png``, the 3D
benchmarks' ``volume_speed.json`` (:mod:`instrument.benchmarks.volume`) and
``volume_accuracy.json`` + ``volume_accuracy.png``
(:mod:`benchmarks.volume_accuracy`), the spatially varying models'
``spatial_speed.json`` and ``spatial_accuracy.json`` + ``spatial_psnr_vs_seconds.png``
(:mod:`benchmarks.spatial`), a far scene through the spatially varying camera's
``spatial_far.json`` + ``spatial_far.png`` (:mod:`benchmarks.spatial_far`: the
two-part model and its ADMM), compressive calibration against centre-only and
grid calibration's ``blind_calibration.json`` + ``blind_calibration.png``
(:mod:`benchmarks.blind`, Fig. 5.4d), the automatic 3D weight against the
oracle's ``volume_auto.json`` (:mod:`benchmarks.volume_auto`), our 3D solvers
beside LenslessPiCam's on the external 3D sample's ``volume_external.json`` +
``volume_external.png`` (:mod:`benchmarks.volume_external`), and
``summary.json`` under ``out`` and
returns a compact summary. The weights chosen by the accuracy sweep are used by the
stability and erasure benchmarks when they run in the same invocation; otherwise
:data:`instrument.benchmarks.DEFAULT_WEIGHTS`. When the 2D and 3D accuracy benchmarks run
together, the speed-vs-accuracy chart ``accuracy_psnr_vs_seconds.png`` gets a
panel with the 3D methods (tilted-target volume PSNR against seconds), and one with
the spatially varying models when ``spatial_accuracy`` ran.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np

from instrument.benchmarks import DEFAULT_WEIGHTS, METHODS, fmt, machine_record, write_json
from instrument.benchmarks import run as speed_run
from recon.errors import ReconInputError

#: The benchmarks and studies, in the order they run (the package's speed benchmarks
#: among them).
BENCHMARKS = ("speed", "accuracy", "stability", "erasure", "volume_speed",
              "volume_accuracy", "spatial_speed", "spatial_accuracy", "spatial_far",
              "blind_calibration", "auto", "priors", "failure_maps", "failure_map_3d",
              "volume_auto", "volume_external")

__all__ = ["BENCHMARKS", "format_result", "run_benchmarks", "summarise"]

log = logging.getLogger(__name__)


#: (module, function) of each benchmark's text table (imported when needed: the
#: benchmark modules are heavy).
_TABLES = {"accuracy": ("accuracy", "accuracy_table"),
           "stability": ("stability", "stability_table"),
           "erasure": ("erasure", "erasure_table"),
           "volume_accuracy": ("volume_accuracy", "volume_accuracy_table"),
           "spatial_speed": ("spatial", "spatial_speed_table"),
           "spatial_accuracy": ("spatial", "spatial_accuracy_table"),
           "spatial_far": ("spatial_far", "spatial_far_table"),
           "blind_calibration": ("blind", "blind_calibration_table"),
           "auto": ("auto", "auto_table"),
           "priors": ("priors", "priors_table"),
           "failure_maps": ("failure_maps", "failure_maps_table"),
           "failure_map_3d": ("failure_map_3d", "failure_map_3d_table"),
           "volume_auto": ("volume_auto", "volume_auto_table"),
           "volume_external": ("volume_external", "volume_external_table")}


def format_result(name: str, result: dict) -> str:
    """:func:`instrument.benchmarks.run.format_result` for every name of :data:`BENCHMARKS`."""
    if name in speed_run.TABLES:
        return speed_run.format_result(name, result)
    module, function = _TABLES[name]
    return getattr(importlib.import_module(f".{module}", __package__), function)(result)


def summarise(results: dict) -> tuple[dict, str]:
    """Compact figures and their text from the benchmark results."""
    summary, text = speed_run.summarise(results)  # speed and volume_speed
    lines = text.splitlines()
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
                     f"x{fmt(a['cost_ratio_max'])} at most (CPU time "
                     f"x{fmt(a.get('cost_ratio_cpu_median'))} median)")
    if "priors" in results:
        p = results["priors"]["summary"]
        summary["priors"] = p
        lines.append(f"automatic prior: {fmt(p['mean_gain_over_tv_oracle_db'])} dB over the "
                     f"oracle TV weight on average (natural and textured scenes), "
                     f"{fmt(p['worst_gain_over_tv_oracle_db'])} at worst; chose "
                     + ", ".join(f"{k} {v}" for k, v in p["chosen"].items()))
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
    """Run the selected benchmarks and studies and write their files and
    ``summary.json``: :func:`instrument.benchmarks.run.run_benchmarks` (the same parameters,
    returns and errors) over every name of :data:`BENCHMARKS`.

    The weights chosen by the accuracy sweep are used by the stability and erasure
    benchmarks of the same call (otherwise :data:`instrument.benchmarks.DEFAULT_WEIGHTS`);
    ``summary.json`` also holds ``weights_used``. ``quick``: fewer iterations and sweep
    points, small 3D problems (tests/CI, about 1 min each).
    """
    from .accuracy import plot_accuracy, run_accuracy
    from .erasure import run_erasure
    from .stability import run_stability
    from .volume_accuracy import run_volume_accuracy

    if only is not None and only not in BENCHMARKS:
        raise ReconInputError(f"unknown benchmark {only!r}; choose one of "
                              f"{', '.join(BENCHMARKS)}")
    selected = [only] if only else list(BENCHMARKS)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    machine = machine_record()
    weights = dict(DEFAULT_WEIGHTS)

    def run(name: str) -> dict:
        if name in speed_run.BENCHMARKS:
            return speed_run.run_one(name, quick, out)
        if name == "accuracy":
            result = run_accuracy(quick, out)
            weights.update(result["chosen_weights"])
            return result
        if name == "stability":
            return run_stability(quick, out, weights)
        if name == "erasure":
            return run_erasure(quick, out, weights)
        if name in ("auto", "priors", "failure_maps", "failure_map_3d", "volume_auto",
                    "volume_external"):
            from . import auto, failure_map_3d, failure_maps, priors, volume_auto, volume_external

            return {"auto": auto.run_auto, "priors": priors.run_priors,
                    "failure_maps": failure_maps.run_failure_maps,
                    "failure_map_3d": failure_map_3d.run_failure_map_3d,
                    "volume_auto": volume_auto.run_volume_auto,
                    "volume_external": volume_external.run_volume_external}[name](quick, out)
        if name == "blind_calibration":
            from .blind import run_blind_calibration

            return run_blind_calibration(quick, out)
        if name == "spatial_far":
            from .spatial_far import run_spatial_far

            return run_spatial_far(quick, out)
        if name.startswith("spatial_"):
            from . import spatial

            return getattr(spatial, f"run_{name}")(quick, out)
        return run_volume_accuracy(quick, out)

    results, timings = speed_run.run_each(selected, run, on_result)
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
