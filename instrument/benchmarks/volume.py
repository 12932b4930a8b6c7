"""3D speed benchmark: seconds per iteration of 3D FISTA and ADMM over the FFT floor.

Run with ``diffuserlab benchmark recon --only volume_speed [--quick] [--out DIR]``.

Both methods need ``n_z + 1`` rfft2 and ``n_z + 1`` irfft2 at the padded shape per
iteration (:func:`recon.volume.operator.fft_floor_seconds` times exactly that); the
ratio of a method's median seconds per iteration to that floor, each run bracketed
by two floor samples (paired, the host is shared and drifts), is its overhead. Goal:
at most 2.5x. The problem is synthetic (a caustic-like pattern magnified
by ``1 + d/z`` per depth, a few beads); speed does not depend on the content. For
scale: the published C++/Halide implementation did 512 x 512 x 128 at about 1 s per
iteration on a 4-core laptop (not run here).

Memory: peak traced memory (tracemalloc: numpy and Python allocations, not numba's)
per method and size, and each method alone at 512 x 512 x 64 (quick: the small
size) in a fresh process, for a clean peak resident set size (``VmHWM``:
everything, interpreter and numba included); the budget is 4 GB
(:data:`MEMORY_GOAL_BYTES`).
"""

from __future__ import annotations

import multiprocessing
import resource
import tracemalloc
from pathlib import Path

import numpy as np
from scipy import ndimage

from ..atomic import write_json

GOAL = 2.5
SIZES_FULL = ((256, 256, 16), (512, 512, 64))
SIZES_QUICK = ((64, 64, 4),)
#: Memory budget of a 512 x 512 x 64 solve, bytes.
MEMORY_GOAL_BYTES = 4 * 10**9


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
        tracemalloc.reset_peak()
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
                                "meets_goal": bool(np.median(paired) <= GOAL),
                                "peak_traced_bytes": int(tracemalloc.get_traced_memory()[1])}
    out["fft_floor_seconds"] = float(np.median(floors))
    out["peak_traced_bytes"] = int(tracemalloc.get_traced_memory()[1])
    tracemalloc.stop()
    return out


def peak_rss_bytes() -> tuple[int, str]:
    """This process's peak resident set size and where it came from.

    ``VmHWM`` of ``/proc/self/status`` (Linux: the high-water mark of this process
    image, reset by exec) when available; otherwise ``ru_maxrss``, which on Linux a
    spawned child inherits from its parent's high-water mark (an upper bound only).

    Returns
    -------
    bytes : int
    source : {"VmHWM", "ru_maxrss"}
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024, "VmHWM"
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, "ru_maxrss"


def _memory_child(method: str, rows: int, cols: int, n_z: int, iterations: int) -> dict:
    """In a fresh process: build the problem, run ``method``, report peak memory."""
    from recon.volume import admm3d, fista3d

    before = peak_rss_bytes()[0]
    tracemalloc.start()
    op, b = synthetic_problem(rows, cols, n_z)
    solver = {"admm3d": admm3d, "fista3d": fista3d}[method]
    solver(op, b, iterations=iterations, tv=1e-4)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    rss, source = peak_rss_bytes()
    return {"method": method, "shape": [rows, cols, n_z], "iterations": iterations,
            "peak_traced_bytes": int(peak), "max_rss_bytes": int(rss), "rss_source": source,
            "rss_before_problem_bytes": int(before)}


def memory_alone(method: str, rows: int, cols: int, n_z: int, iterations: int = 3) -> dict:
    """Peak memory of one 3D solve (TV on) run alone in a fresh (spawned) process.

    Parameters
    ----------
    method : {"admm3d", "fista3d"}
    rows, cols, n_z : int
        Sensor shape and planes of :func:`synthetic_problem`.
    iterations : int

    Returns
    -------
    dict
        ``peak_traced_bytes`` (tracemalloc: numpy and Python allocations from the
        problem set-up on, including allocated pages never touched),
        ``max_rss_bytes`` (the process's peak resident set, interpreter, libraries
        and numba included, :func:`peak_rss_bytes`), ``rss_source``,
        ``rss_before_problem_bytes`` (after the imports), ``meets_goal`` (max RSS
        under :data:`MEMORY_GOAL_BYTES`).
    """
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        out = pool.apply(_memory_child, (method, rows, cols, n_z, iterations))
    out["meets_goal"] = bool(out["max_rss_bytes"] < MEMORY_GOAL_BYTES)
    return out


def run_volume_speed(quick: bool = False, out: Path | None = None) -> dict:
    """Speed of fista3d and admm3d against the FFT floor, and their peak memory.

    Parameters
    ----------
    quick : bool
        One tiny size (64 x 64 x 4), 2 runs of 4 iterations (tests); otherwise
        256 x 256 x 16 and 512 x 512 x 64, 3 runs of 8 iterations.
    out : Path, optional
        Directory for ``volume_speed.json``.

    Returns
    -------
    dict
        ``goal``, ``memory_goal_bytes``, ``sizes`` (per size: ``fft_floor_seconds``,
        ``ffts_per_iteration``, per method ``ratio``, ``seconds_per_iteration``,
        ``peak_traced_bytes``), ``memory`` (each method alone at the largest size,
        :func:`memory_alone`).
    """
    sizes = SIZES_QUICK if quick else SIZES_FULL
    iterations, runs = (4, 2) if quick else (8, 3)
    results = [measure(*s, iterations=iterations, runs=runs) for s in sizes]
    memory = [memory_alone(m, *sizes[-1]) for m in ("admm3d", "fista3d")]
    result = {"quick": quick, "goal": GOAL, "memory_goal_bytes": MEMORY_GOAL_BYTES,
              "sizes": results, "memory": memory}
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        write_json(Path(out) / "volume_speed.json", result)
    return result


def volume_speed_table(result: dict) -> str:
    """Text summary of a :func:`run_volume_speed` result."""
    lines = [f"3D speed: seconds per iteration / FFT floor (n_z + 1 rfft2 + irfft2), goal "
             f"{result['goal']}"]
    for r in result["sizes"]:
        rows, cols, n_z = r["shape"]
        cells = ", ".join(f"{m} {d['ratio']:.2f}x ({d['seconds_per_iteration']:.3g} s/it)"
                          for m, d in r["methods"].items())
        lines.append(f"  {rows}x{cols}x{n_z} (floor {r['fft_floor_seconds']:.3g} s): {cells}; "
                     f"peak traced {r['peak_traced_bytes'] / 2**30:.2f} GiB")
    for m in result["memory"]:
        rows, cols, n_z = m["shape"]
        lines.append(f"  memory, {m['method']} alone at {rows}x{cols}x{n_z}: peak traced "
                     f"{m['peak_traced_bytes'] / 2**30:.2f} GiB, max RSS "
                     f"{m['max_rss_bytes'] / 2**30:.2f} GiB (budget "
                     f"{result['memory_goal_bytes'] / 1e9:g} GB: "
                     f"{'ok' if m['meets_goal'] else 'EXCEEDED'})")
    return "\n".join(lines)
