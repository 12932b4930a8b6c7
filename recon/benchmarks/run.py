"""Run the reconstruction benchmarks and write their results.

Usage::

    python -m recon.benchmarks.run [--out DIR] [--quick] [--only NAME]

Writes ``speed.json``, ``accuracy.json`` + ``accuracy_psnr_vs_seconds.png``,
``stability.json`` + ``stability.png``, ``erasure.json`` + ``erasure.png`` and
``summary.json`` under ``--out`` and prints a compact summary. The weights chosen by
the accuracy sweep are used by the stability and erasure benchmarks when they run
in the same invocation; otherwise :data:`recon.benchmarks.DEFAULT_WEIGHTS`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import ReconInputError
from . import DEFAULT_WEIGHTS, METHODS, fmt, write_json

BENCHMARKS = ("speed", "accuracy", "stability", "erasure")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m recon.benchmarks.run",
                                description="Speed, accuracy, stability and erasure "
                                            "benchmarks of the reconstruction layer.")
    p.add_argument("--out", type=Path, default=Path("out/benchmark"),
                   help="output directory (default out/benchmark)")
    p.add_argument("--quick", action="store_true",
                   help="fewer iterations and sweep points (tests/CI, < 1 min)")
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
    return summary, "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the selected benchmarks; returns the exit status (0, or 2 on input errors)."""
    args = _parser().parse_args(argv)
    from .accuracy import run_accuracy
    from .erasure import run_erasure
    from .speed import run_speed
    from .stability import run_stability

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
            else:
                results[name] = run_erasure(args.quick, out, weights)
            timings[name] = time.perf_counter() - t0
            print(f"({name}: {timings[name]:.1f} s)", flush=True)
    except ReconInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    summary, text = summarise(results)
    summary.update(quick=args.quick, weights_used=weights, seconds=timings,
                   methods=list(METHODS))
    write_json(out / "summary.json", summary)
    print(text)
    print(f"results in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
