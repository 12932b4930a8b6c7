"""Speed per device and backend: ``diffuserlab benchmark gpu``.

For each backend present -- the NumPy path (numba, scipy.fft) and the array-API path
on PyTorch's CPU backend, CuPy and PyTorch on a CUDA GPU -- and each case of the GPU
issue (2D ADMM at 300 x 400 and 1200 x 1600, 3D ADMM at 256 x 256 x 32 and
512 x 512 x 128, the hologram at 960 x 540 and 16x, live ADMM x5 at full sensor size),
it prints seconds per iteration, the ratio to that device's FFT floor (measured in the
same process on the same backend) and the speed-up over the NumPy path on the CPU. A
backend that is not installed or sees no device is listed as "unmeasured" with the
reason; a case that does not fit in a device's memory says so ("not run: ...").
Every case runs the project's own solver on each backend (the live case the
warm-started :class:`recon.live.LiveReconstructor`, the hologram
:func:`recon.cgh.optimize_hologram`).

Problems are synthetic (a random sparse PSF or PSF stack at the sensor size and a
random scene): the time of an iteration does not depend on the content.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from recon.backend import (
    NUMPY,
    Backend,
    check_memory,
    free_device_bytes,
    resolve_device,
    to_device,
    torch_cpu,
)
from recon.errors import ReconInputError

__all__ = ["CASES", "Case", "format_table", "run_gpu_benchmark"]


@dataclass(frozen=True)
class Case:
    """One benchmark case.

    Attributes
    ----------
    name : str
        As printed.
    kind : {"admm2d", "admm3d", "holo", "live"}
    shape : tuple of int
        Sensor (rows, cols); for 3D (rows, cols, n_z); for the hologram the SLM
        (rows, cols) and the expansion factor k (k^2 x).
    """

    name: str
    kind: str
    shape: tuple


#: The cases of the full run.
CASES = (Case("2D ADMM 300x400", "admm2d", (300, 400)),
         Case("2D ADMM 1200x1600", "admm2d", (1200, 1600)),
         Case("3D ADMM 256x256x32", "admm3d", (256, 256, 32)),
         Case("3D ADMM 512x512x128", "admm3d", (512, 512, 128)),
         Case("hologram 960x540 16x", "holo", (540, 960, 4)),
         Case("live ADMM x5 1200x1600", "live", (1200, 1600)))

#: ``--quick``: the 3D cases one size down (the 512 x 512 x 128 volume needs ~6 GiB).
QUICK = (CASES[0], CASES[1], Case("3D ADMM 128x128x16", "admm3d", (128, 128, 16)),
         CASES[2], CASES[4], CASES[5])


def _sync(backend: Backend) -> None:
    """Wait for the device's queued work (GPU timings)."""
    if backend.name == "cupy":
        import cupy

        cupy.cuda.Device().synchronize()
    elif backend.name == "torch" and backend.device.type == "cuda":
        import torch

        torch.cuda.synchronize()


def fft_floor(backend: Backend, shape: tuple[int, int], n_z: int = 0,
              repeats: int = 7) -> float:
    """Median seconds of the solvers' FFT floor on ``backend``: one rfft2 + irfft2 pair
    at ``shape`` (2D), or a batched pair on ``n_z`` planes plus one plane (3D ADMM's
    ``n_z + 1`` pairs), float32 (:func:`recon.fft.time_ffts` on the NumPy path)."""
    if backend.is_numpy:
        from recon.fft import time_ffts

        return time_ffts(shape, stacks=(n_z, 1) if n_z else (1,), repeats=repeats)
    xp = backend.xp
    rng = np.random.default_rng(0)
    bufs = [to_device(rng.random((n, *shape) if n > 1 else shape, dtype=np.float32), backend)
            for n in ((n_z, 1) if n_z else (1,))]

    def once():
        for buf in bufs:
            xp.fft.irfftn(xp.fft.rfftn(buf, axes=(-2, -1)), s=shape, axes=(-2, -1))
        _sync(backend)

    once()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        once()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _psf(shape, rng) -> np.ndarray:
    """A random caustic-like PSF (sparse bright points on the central half), unit sum."""
    psf = np.zeros(shape, np.float32)
    r, c = shape
    n = max(8, r * c // 200)
    psf[rng.integers(r // 4, 3 * r // 4, n), rng.integers(c // 4, 3 * c // 4, n)] = rng.random(n)
    return psf / psf.sum()


def _median(seconds) -> float:
    s = list(seconds)[1:] or list(seconds)  # the first iteration carries the set-up
    return float(np.median(s))


def _admm2d(backend: Backend, shape, iterations: int) -> tuple[float, float]:
    from recon.operators import ConvolutionOperator
    from recon.solvers import admm
    from recon.solvers.xp_admm import memory_bytes

    rng = np.random.default_rng(0)
    op = ConvolutionOperator(_psf(shape, rng))
    b = op.forward(rng.random(op.padded_shape, dtype=np.float32))
    b /= b.max()
    if not backend.is_numpy:
        check_memory(memory_bytes(op.padded_shape), free_device_bytes(backend),
                     what="2D ADMM", where=backend.label)
    res = admm(op, to_device(b, backend), iterations=iterations, tv=1e-3)
    return _median(res.history.seconds), fft_floor(backend, op.padded_shape)


def _admm3d(backend: Backend, shape, iterations: int) -> tuple[float, float]:
    from recon.volume import VolumeConvolutionOperator, admm3d
    from recon.volume.xp_admm3d import memory_bytes

    rows, cols, n_z = shape
    rng = np.random.default_rng(0)
    stack = np.stack([_psf((rows, cols), rng) for _ in range(n_z)])
    stack /= np.sqrt((stack.sum(axis=(1, 2)) ** 2).sum())
    op = VolumeConvolutionOperator(stack)
    if not backend.is_numpy:
        check_memory(memory_bytes(n_z, op.padded_shape) + op.spectra.nbytes,
                     free_device_bytes(backend), what=f"3D ADMM {rows}x{cols}x{n_z}",
                     where=backend.label)
    x = np.zeros(op.shape_in, np.float32)
    x[:, op.crop[0], op.crop[1]] = rng.random((n_z, rows, cols), dtype=np.float32)
    b = op.forward(x)
    b /= b.max()
    del x
    res = admm3d(op, to_device(b, backend), iterations=iterations, tv=1e-3)
    return _median(res.history.seconds), fft_floor(backend, op.padded_shape, n_z)


def _live(backend: Backend, shape, frames: int) -> tuple[float, float]:
    """Seconds per frame of :class:`recon.live.LiveReconstructor` on ``backend``: 5 ADMM
    iterations warm-started from the previous frame's state (kept on the device), on a
    new frame each time (raw conversion on the host, the frame moved to the device and
    the sensor image back included), and the 2D floor."""
    from recon.live import LiveReconstructor
    from recon.options import ReconOptions

    rng = np.random.default_rng(1)
    psf = _psf(shape, rng)
    live = LiveReconstructor(psf, ReconOptions.from_defaults(dark="none", device=backend),
                             tv=1e-3)
    op = live.operator
    truth = rng.random(op.padded_shape, dtype=np.float32)
    frame_b = [op.forward(np.roll(truth, k, axis=1)) for k in range(2)]
    times = []
    for k in range(frames + 1):
        t0 = time.perf_counter()
        res = live.admm(frame_b[k % 2], iterations=5)
        times.append(time.perf_counter() - t0)
        assert res.image.shape == op.sensor_shape and res.warm == (k > 0)
    return float(np.median(times[1:])), fft_floor(backend, op.padded_shape)


def _hologram(backend: Backend, shape, iterations: int) -> tuple[float, float]:
    """Median seconds per iteration of the hologram optimiser (frequency loss, the
    bundled astronaut as target) on ``backend`` for an SLM of ``shape[:2]`` at
    ``shape[2]^2`` x, and that device's floor: one complex64 FFT at the grid
    (:func:`instrument.benchmarks.hologram.run_benchmark`)."""
    from instrument.benchmarks.hologram import run_benchmark

    rows, cols, k = shape
    rep = run_benchmark(slm_shape=(rows, cols), k=k, steps=iterations, fft_repeats=5,
                        backend=backend)
    return rep["median_seconds_per_iteration"], rep["fft_seconds"]


def _backends(include_torch_cpu: bool) -> list[tuple[str, Backend | None, str]]:
    """(label, backend or None, why unmeasured) for every backend of the table."""
    rows = [(NUMPY.label, NUMPY, "")]
    if include_torch_cpu:
        tc = torch_cpu()
        rows.append(("cpu (torch, generic path)", tc, "" if tc else "PyTorch not installed"))
    try:
        gpu = resolve_device("cuda")
        rows.append((gpu.label, gpu, ""))
    except ReconInputError as exc:
        rows.append(("cuda", None, str(exc)))
    return rows


def run_gpu_benchmark(*, quick: bool = False, iterations: int | None = None,
                      include_torch_cpu: bool = True, cases=None, log=print) -> dict:
    """Run every case on every backend; returns the rows (also logged as they finish).

    Parameters
    ----------
    quick : bool
        :data:`QUICK` cases (3D one size down), 4 iterations; else :data:`CASES`, 12.
    iterations : int, optional
        Iterations per timed solve (the median of all but the first is reported).
    include_torch_cpu : bool
        Also time the generic path on PyTorch's CPU backend.
    cases : sequence of Case, optional
        Instead of the default list.
    log : callable
        Receives each row's line as it is measured.

    Returns
    -------
    dict
        ``rows``: one dict per (case, backend) with ``case``, ``backend``,
        ``seconds_per_iteration`` (per frame for the live case), ``fft_floor_seconds``,
        ``ratio_to_fft_floor`` (per ADMM iteration for the live case too),
        ``speedup_vs_cpu``, ``per_second`` (iterations or frames per second) and ``note``
        (why a row is unmeasured).
    """
    cases = (QUICK if quick else CASES) if cases is None else cases
    iterations = iterations or (4 if quick else 12)
    rows = []
    backends = _backends(include_torch_cpu)
    for case in cases:
        cpu_s = None
        for label, backend, why in backends:
            row = {"case": case.name, "backend": label, "seconds_per_iteration": None,
                   "fft_floor_seconds": None, "ratio_to_fft_floor": None,
                   "speedup_vs_cpu": None, "per_second": None, "note": why and "unmeasured: "
                   + why}
            if backend is not None:
                try:
                    row.update(_measure(case, backend, iterations))
                except (ReconInputError, MemoryError) as exc:
                    row["note"] = f"not run: {exc}"
            s = row["seconds_per_iteration"]
            if s is not None:
                per_iteration = s / row.pop("iterations_per_unit", 1)
                row["ratio_to_fft_floor"] = per_iteration / row["fft_floor_seconds"]
                row["per_second"] = 1.0 / s
                if backend.is_numpy:
                    cpu_s = s
                if cpu_s is not None:
                    row["speedup_vs_cpu"] = cpu_s / s
            rows.append(row)
            log(format_row(row))
    return {"rows": rows, "iterations": iterations, "quick": quick}


def _measure(case: Case, backend: Backend, iterations: int) -> dict:
    if case.kind == "holo":
        s, floor = _hologram(backend, case.shape, max(2, iterations // 2))
    elif case.kind == "admm2d":
        s, floor = _admm2d(backend, case.shape, iterations)
    elif case.kind == "admm3d":
        s, floor = _admm3d(backend, case.shape, iterations)
    else:
        s, floor = _live(backend, case.shape, max(3, iterations // 2))
        return {"seconds_per_iteration": s, "fft_floor_seconds": floor,
                "iterations_per_unit": 5}
    return {"seconds_per_iteration": s, "fft_floor_seconds": floor}


def format_row(row: dict) -> str:
    """One table line: case, backend, s/it (or s/frame), ratio, speed-up, rate."""
    unit = "frame" if row["case"].startswith("live") else "it"
    if row["seconds_per_iteration"] is None:
        return f"{row['case']:<24} {row['backend']:<28} {row['note']}"
    speed = ("" if row["speedup_vs_cpu"] is None
             else f"  {row['speedup_vs_cpu']:6.2f}x vs cpu (numpy)")
    return (f"{row['case']:<24} {row['backend']:<28} {row['seconds_per_iteration']:9.4f} s/{unit}"
            f"  {row['per_second']:8.2f} {unit}/s  {row['ratio_to_fft_floor']:6.2f}x FFT floor"
            f" ({row['fft_floor_seconds'] * 1e3:.2f} ms){speed}")


def format_table(result: dict) -> str:
    """The whole table (:func:`format_row` per row) with its header."""
    head = (f"benchmark gpu: median s per iteration of {result['iterations']} (live: per "
            "frame of 5 ADMM iterations), ratio of one iteration to the backend's FFT floor, "
            "speed-up over the NumPy path")
    return "\n".join([head, *(format_row(r) for r in result["rows"])])
