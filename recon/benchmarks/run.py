"""Run the reconstruction benchmarks and write their results.

Usage::

    python -m recon.benchmarks.run [--out DIR] [--quick] [--only NAME]

Writes ``speed.json``, ``accuracy.json`` + ``accuracy_psnr_vs_seconds.png``,
``stability.json`` + ``stability.png``, ``erasure.json`` + ``erasure.png``, the 3D
benchmarks' ``volume_speed.json`` (:mod:`recon.benchmarks.volume`) and
``volume_accuracy.json`` + ``volume_accuracy.png``
(:mod:`recon.benchmarks.volume_accuracy`), and ``summary.json`` under ``--out`` and
prints a compact summary. The weights chosen by the accuracy sweep are used by the
stability and erasure benchmarks when they run in the same invocation; otherwise
:data:`recon.benchmarks.DEFAULT_WEIGHTS`. When the 2D and 3D accuracy benchmarks run
together, the speed-vs-accuracy chart ``accuracy_psnr_vs_seconds.png`` gets a last
panel with the 3D methods (tilted-target volume PSNR against seconds).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import ReconInputError
from . import DEFAULT_WEIGHTS, METHODS, fmt, write_json

BENCHMARKS = ("speed", "accuracy", "stability", "erasure", "volume_speed",
              "volume_accuracy")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m recon.benchmarks.run",
                                description="Speed, accuracy, stability and erasure "
                                            "benchmarks of the reconstruction layer, 2D and "
                                            "3D.")
    p.add_argument("--out", type=Path, default=Path("out/benchmark"),
                   help="output directory (default out/benchmark)")
    p.add_argument("--quick", action="store_true",
                   help="fewer iterations and sweep points, small 3D problems (tests/CI, "
                   "about 1 min)")
    p.add_argument("--only", choices=BENCHMARKS, help="run a single benchmark")
    return p


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


def main(argv: list[str] | None = None) -> int:
    """Run the selected benchmarks; returns the exit status (0, or 2 on input errors)."""
    args = _parser().parse_args(argv)
    from .accuracy import run_accuracy
    from .erasure import run_erasure
    from .speed import run_speed
    from .stability import run_stability
    from .volume import run_volume_speed
    from .volume_accuracy import run_volume_accuracy

    selected = [args.only] if args.only else list(BENCHMARKS)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    weights = dict(DEFAULT_WEIGHTS)
    timings = {}
    try:
        for name in selected:
            t0 = time.perf_counter()
            print(f"-- {name} --", flush=True)
            if name == "speed":
                results[name] = run_speed(args.quick, out)
            elif name == "accuracy":
                results[name] = run_accuracy(args.quick, out)
                weights.update(results[name]["chosen_weights"])
            elif name == "stability":
                results[name] = run_stability(args.quick, out, weights)
            elif name == "erasure":
                results[name] = run_erasure(args.quick, out, weights)
            elif name == "volume_speed":
                results[name] = run_volume_speed(args.quick, out)
            else:
                results[name] = run_volume_accuracy(args.quick, out)
            timings[name] = time.perf_counter() - t0
            print(f"({name}: {timings[name]:.1f} s)", flush=True)
    except ReconInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if "accuracy" in results and "volume_accuracy" in results:
        from .accuracy import plot_accuracy

        plot_accuracy(results["accuracy"], out / "accuracy_psnr_vs_seconds.png",
                      volume=results["volume_accuracy"])
    summary, text = summarise(results)
    summary.update(quick=args.quick, weights_used=weights, seconds=timings,
                   methods=list(METHODS))
    write_json(out / "summary.json", summary)
    print(text)
    print(f"results in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
