"""3D speed benchmark: seconds per iteration of 3D FISTA and ADMM over the FFT floor.

Usage::

    python -m recon.benchmarks.volume [--quick] [--out DIR]

Both methods need ``n_z + 1`` rfft2 and ``n_z + 1`` irfft2 at the padded shape per
iteration (:func:`recon.volume.operator.fft_floor_seconds` times exactly that); the
ratio of a method's median seconds per iteration to that floor, each run bracketed
by two floor samples (paired, the host is shared and drifts), is its overhead. Goal:
at most 2.5x (issue 5). The problem is synthetic (a caustic-like pattern magnified
by ``1 + d/z`` per depth, a few beads); speed does not depend on the content. For
scale: the published C++/Halide implementation did 512 x 512 x 128 at about 1 s per
iteration on a 4-core laptop (not run here). Peak traced memory (tracemalloc) is
reported for each size.
"""

from __future__ import annotations

import argparse
import json
import sys
import tracemalloc
from pathlib import Path

import numpy as np
from scipy import ndimage

GOAL = 2.5
SIZES_FULL = ((256, 256, 16), (512, 512, 64))
SIZES_QUICK = ((64, 64, 4),)


def synthetic_problem(rows: int, cols: int, n_z: int, seed: int = 0):
    """A caustic-like PSF stack (n_z, rows, cols) float32 and a bead measurement."""
    from recon.volume import VolumeConvolutionOperator, normalize_psf_stack

    rng = np.random.default_rng(seed)
    core = ndimage.gaussian_filter(rng.standard_normal((rows // 2, cols // 2)), 2)
    base = np.zeros((rows, cols))
    r0, c0 = rows // 4, cols // 4
    base[r0:r0 + rows // 2, c0:c0 + cols // 2] = np.exp(-((core / 0.02) ** 2))
    stack = []
    for k in range(n_z):
        s = 1.0 + 0.4 * k / max(n_z - 1, 1)
        centre = np.array([(rows - 1) / 2, (cols - 1) / 2])
        stack.append(ndimage.affine_transform(base, np.eye(2) / s, centre - centre / s,
                                              order=1))
    stack, _ = normalize_psf_stack(np.asarray(stack, np.float32))
    op = VolumeConvolutionOperator(stack)
    x = np.zeros(op.shape_in, np.float32)
    for _ in range(8):
        x[rng.integers(n_z), rng.integers(op.shape_in[1]), rng.integers(op.shape_in[2])] = 1.0
    b = op.forward(x)
    return op, (b / np.abs(b).max()).astype(np.float32)


def measure(rows: int, cols: int, n_z: int, *, iterations: int, runs: int) -> dict:
    """Paired ratios of fista3d and admm3d (TV on) to the FFT floor at one size."""
    from recon.volume import admm3d, fista3d
    from recon.volume.operator import fft_floor_seconds

    tracemalloc.start()
    op, b = synthetic_problem(rows, cols, n_z)
    lip = op.lipschitz()
    out = {"shape": [rows, cols, n_z], "padded_shape": list(op.shape_in[1:]),
           "ffts_per_iteration": {"rfft2": n_z + 1, "irfft2": n_z + 1}, "methods": {}}
    floors = []
    for name, solver, kw in (("fista3d", fista3d, {"lipschitz": lip}), ("admm3d", admm3d, {})):
        paired, times = [], []
        for _ in range(runs):
            f0 = fft_floor_seconds(op.shape_in[1:], n_z, repeats=3)
            t = solver(op, b, iterations=iterations, tv=1e-4, **kw).history.seconds[1:]
            f1 = fft_floor_seconds(op.shape_in[1:], n_z, repeats=3)
            floors += [f0, f1]
            times += t
            paired.append(float(np.median(t)) / (0.5 * (f0 + f1)))
        out["methods"][name] = {"seconds_per_iteration": float(np.median(times)),
                                "ratio": float(np.median(paired)), "paired_ratios": paired,
                                "meets_goal": bool(np.median(paired) <= GOAL)}
    out["fft_floor_seconds"] = float(np.median(floors))
    out["peak_traced_bytes"] = int(tracemalloc.get_traced_memory()[1])
    tracemalloc.stop()
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print a table, write ``volume_speed.json``; returns 0."""
    p = argparse.ArgumentParser(prog="python -m recon.benchmarks.volume",
                                description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="one tiny size (tests)")
    p.add_argument("--out", type=Path, default=Path("out/benchmark"))
    args = p.parse_args(argv)
    sizes = SIZES_QUICK if args.quick else SIZES_FULL
    iterations, runs = (4, 2) if args.quick else (8, 3)
    results = [measure(*s, iterations=iterations, runs=runs) for s in sizes]
    print(f"3D speed: seconds per iteration / FFT floor (n_z + 1 rfft2 + irfft2), goal {GOAL}")
    for r in results:
        rows, cols, n_z = r["shape"]
        cells = ", ".join(f"{m} {d['ratio']:.2f}x ({d['seconds_per_iteration']:.3g} s/it)"
                          for m, d in r["methods"].items())
        print(f"  {rows}x{cols}x{n_z} (floor {r['fft_floor_seconds']:.3g} s): {cells}; "
              f"peak traced {r['peak_traced_bytes'] / 2**30:.2f} GiB")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "volume_speed.json").write_text(json.dumps({"goal": GOAL, "sizes": results},
                                                           indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
