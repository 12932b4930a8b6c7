"""``diffuserlab benchmark volume-scale``: the seed-size 3D problem, streamed or sharded.

Generates the problem on the fly (:mod:`instrument.benchmarks.volume_scale_scenes`: a depth-scaled
stack from the tutorial PSF in a per-plane-chunked Zarr store under a temporary
directory, a scene of beads and extended objects, its noisy measurement), measures
the streamed FFT floor (:func:`recon.volume.streamed.streamed_fft_floor_seconds`) in
the same process, and solves with streamed 3D FISTA in this process
(``workers=0``) or sharded over a LocalCluster of worker processes
(:mod:`instrument.processing.volume_shards`). Reports the peak resident set against the
estimate printed before the solve, seconds per iteration against the floor,
CPU seconds per iteration, the bytes each worker moved per iteration, and which
objects sit at their depth (within one plane, and within one axial resolution,
:func:`instrument.benchmarks.volume_scale_scenes.axial_resolution_planes`). Nothing is
kept unless asked (``save_estimate``).
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["run_volume_scale", "volume_scale_table"]

log = logging.getLogger(__name__)


def run_volume_scale(*, sensor: int = 2048, planes: int = 128, iterations: int = 4,
                     tv: float = 1e-5, workers: int = 0, worker_memory: str = "10GB",
                     work_dir: str | None = None, save_estimate: str | None = None,
                     compare_with: str | None = None, bead_light: float | None = None,
                     announce=print) -> dict:
    """Generate the problem, solve it streamed or sharded, and measure.

    Parameters
    ----------
    sensor : int
        Sensor side, pixels (the seed's 2048).
    planes : int
        Depth planes (the seed's 128).
    iterations : int
        FISTA iterations (a few suffice for per-iteration figures).
    tv : float
        Fixed 3D TV weight in the scaled problem.
    workers : int
        0: streamed in this process; K >= 1: a LocalCluster of K worker processes.
    worker_memory : str
        Memory limit per worker (dask's ``memory_limit``).
    work_dir : str, optional
        Where the temporary Zarr store goes (default the system's temporary directory).
    save_estimate : str, optional
        Write the estimate (``.npy``) here, for ``compare_with`` of another run.
    compare_with : str, optional
        An earlier run's estimate: the relative difference is reported.
    bead_light : float, optional
        Each bead's light relative to one pixel of an extended object (default
        :func:`instrument.benchmarks.volume_scale_scenes.bead_light` of ``sensor``: the
        same scene at every size; the fixed 50 of earlier runs makes beads 16x fainter at
        2048 than at 512).
    announce : callable
        Progress and the memory estimate, before the solve.

    Returns
    -------
    dict
        JSON-ready figures (see :func:`volume_scale_table`).
    """
    import zarr

    from instrument.benchmarks import machine_record
    from instrument.benchmarks.volume_scale_scenes import (
        axial_resolution_planes,
        objects_at_depth,
        render_measurement,
        scene_objects,
        window_energies,
        write_psf_store,
    )
    from recon.io import load_image
    from recon.operators import padded_grid
    from recon.sample import PSF_FILE, data_dir
    from recon.volume.streamed import (
        peak_rss_bytes,
        plan_slabs,
        streamed_fft_floor_seconds,
        streamed_fista3d,
        streamed_memory_bytes,
    )

    rec = {"machine": machine_record(), "sensor": [sensor, sensor], "planes": planes,
           "iterations": iterations, "tv": tv, "workers": workers}
    with tempfile.TemporaryDirectory(dir=work_dir, prefix="volume-scale-") as tmp:
        store_path = str(Path(tmp) / "psf.zarr")
        t0 = time.perf_counter()
        psf_scale, depths = write_psf_store(store_path, load_image(data_dir() / PSF_FILE),
                                            sensor, planes)
        store = zarr.open_array(store_path, mode="r")
        objects = scene_objects(sensor, planes, light=bead_light)
        rec["bead_light"] = objects[0].light
        raw = render_measurement(store, psf_scale, objects)
        b = (raw / np.abs(raw).max()).astype(np.float32)
        del raw
        rec["seconds_generate"] = time.perf_counter() - t0
        rec["axial_resolution"] = axial_resolution_planes(store, depths)
        padded = padded_grid((sensor, sensor))[0]
        rec["padded_shape"] = list(padded)
        announce(f"generated {planes} planes of {sensor}x{sensor} (padded {padded[0]}x"
                 f"{padded[1]}) and {len(objects)} objects in {rec['seconds_generate']:.0f} s")
        rec["fft_floor_seconds"] = streamed_fft_floor_seconds(padded, planes, repeats=5)
        rec["fft_floor_transforms"] = (f"{planes + 1} rfft2 + irfft2 pairs at "
                                       f"{padded[0]}x{padded[1]}, one plane at a time")
        rec["fft_floor_cpu_seconds"] = (planes + 1) * _pair_cpu_seconds(padded)
        cpu = []
        energies = np.zeros((len(objects), planes))
        ref = None if compare_with is None else np.load(compare_with, mmap_mode="r")
        diff = [0.0, 0.0]
        saved = (None if save_estimate is None else np.lib.format.open_memmap(
            save_estimate, "w+", np.float32, (planes, sensor, sensor)))

        def take(a, z, x):  # one slab of the estimate: scored, compared, saved, dropped
            energies[:, a:z] = window_energies(x, objects)
            if saved is not None:
                saved[a:z] = x
            if ref is not None:
                for k in range(a, z):
                    diff[0] += float(np.sum((x[k - a] - ref[k]) ** 2, dtype=np.float64))
                    diff[1] += float(np.sum(np.square(ref[k], dtype=np.float64)))

        if workers == 0:
            est = streamed_memory_bytes((sensor, sensor), planes)
            baseline = _warm_rss()
            rec["memory_estimate_bytes"] = baseline + est["total"]
            announce(f"estimated peak memory {rec['memory_estimate_bytes'] / 1e9:.2f} GB "
                     f"(process now {baseline / 1e9:.2f} GB + arrays {est['total'] / 1e9:.2f}"
                     " GB)")
            marks = [time.process_time()]
            def tick(k):
                marks.append(time.process_time())
                announce(f"iteration {k + 1}: {marks[-1] - marks[-2]:.0f} CPU s")

            result = streamed_fista3d(store, b, psf_scale=psf_scale, iterations=iterations,
                                      tv=tv, on_iteration=tick)
            cpu = list(np.diff(marks))
            rec["peak_rss_bytes"] = peak_rss_bytes()  # of the solve: before the save
            take(0, planes, result.x)
            rec["peak_over_estimate"] = rec["peak_rss_bytes"] / rec["memory_estimate_bytes"]
        else:
            rec.update(_sharded(store_path, b, psf_scale, planes, sensor, iterations, tv,
                                workers, worker_memory, announce, cpu, take,
                                plan_slabs, streamed_memory_bytes, peak_rss_bytes))
            result = rec.pop("result")
    per_iter = float(np.median(result.history.seconds))
    rec.update({
        "seconds_per_iteration": per_iter,
        "seconds_per_iteration_all": list(result.history.seconds),
        "ratio_to_fft_floor": per_iter / rec["fft_floor_seconds"],
        "cpu_seconds_per_iteration": float(np.median(cpu)) if cpu else None,
        "cpu_ratio_to_fft_floor": (float(np.median(cpu)) / rec["fft_floor_cpu_seconds"]
                                   if cpu else None),
        "core_seconds_per_iteration_wall": per_iter * (rec["machine"]["cpu_count"] or 1),
        "bytes_moved_per_worker_per_iteration": result.params["bytes_moved_per_iteration"],
        "final_relative_residual": result.final_relative_residual,
        "objects_at_depth": objects_at_depth(
            energies, objects, resolution_planes=rec["axial_resolution"]["planes"]),
        "depths_mm": [depths[0], depths[-1]],
    })
    if saved is not None:
        saved.flush()
        del saved
    if ref is not None:
        rec["relative_difference_to"] = {"path": str(compare_with),
                                         "relative": float(np.sqrt(diff[0] / diff[1]))}
    return rec


def _sharded(store_path, b, psf_scale, planes, sensor, iterations, tv, workers,
             worker_memory, announce, cpu, take, plan_slabs, streamed_memory_bytes,
             peak_rss_bytes) -> dict:
    """The LocalCluster half of :func:`run_volume_scale`."""
    from ..processing.cluster_close import close_local_cluster
    from ..processing.volume_shards import local_cluster, sharded_fista3d

    client, cluster = local_cluster(workers, worker_memory)
    try:
        slab = max(z - a for a, z in plan_slabs(planes, workers))
        est = streamed_memory_bytes((sensor, sensor), slab)
        base = client.run(_warm_rss)
        estimate = {w: v + est["total"] for w, v in base.items()}
        announce(f"estimated peak memory per worker {max(estimate.values()) / 1e9:.2f} GB "
                 f"(worker now {max(base.values()) / 1e9:.2f} GB + arrays "
                 f"{est['total'] / 1e9:.2f} GB of a {slab}-plane slab)")

        def cpu_now():
            return sum(client.run(time.process_time).values()) + time.process_time()

        marks = [cpu_now()]

        def tick(k):
            marks.append(cpu_now())
            announce(f"iteration {k + 1}: {marks[-1] - marks[-2]:.0f} CPU s")

        result = sharded_fista3d(client, store_path, b, psf_scale=psf_scale,
                                 iterations=iterations, tv=tv, on_iteration=tick, on_slab=take)
        cpu.extend(np.diff(marks))
        peaks = client.run(peak_rss_bytes)
    finally:
        close_local_cluster(client, cluster)
    worst = max(peaks, key=lambda w: peaks[w] / estimate[w])
    return {"result": result, "worker_memory_limit": worker_memory,
            "memory_estimate_bytes_per_worker": estimate, "peak_rss_bytes_per_worker": peaks,
            "peak_over_estimate": peaks[worst] / estimate[worst],
            "loop_peak_rss_bytes": peak_rss_bytes(),
            "slab_planes": result.params["slab_planes"],
            "seconds_setup": result.params["seconds_setup"]}


def _pair_cpu_seconds(shape, repeats: int = 5) -> float:
    """Median CPU seconds (all threads) of one float32 rfft2 + irfft2 pair at ``shape``:
    the floor in CPU time, which the machine's load does not stretch."""
    from recon.fft import irfftn, rfftn

    x = np.random.default_rng(0).random(tuple(shape), dtype=np.float32)
    irfftn(rfftn(x), tuple(shape))
    times = []
    for _ in range(repeats):
        t = time.process_time()
        irfftn(rfftn(x), tuple(shape))
        times.append(time.process_time() - t)
    return float(np.median(times))


def _warm_rss() -> int:
    """A worker's resident set after the slab kernels are compiled, bytes."""
    from recon.volume.memory_plan import current_rss_bytes
    from recon.volume.slab import warm_up

    warm_up()
    return current_rss_bytes()


def volume_scale_table(r: dict) -> str:
    """The figures of :func:`run_volume_scale` as lines of text."""
    gb = 1e9
    where = ("this process" if not r["workers"] else
             f"LocalCluster of {r['workers']} workers ({r['worker_memory_limit']} each)")
    peak = (r["peak_rss_bytes"] if not r["workers"]
            else max(r["peak_rss_bytes_per_worker"].values()))
    est = (r["memory_estimate_bytes"] if not r["workers"]
           else max(r["memory_estimate_bytes_per_worker"].values()))
    depth = r["objects_at_depth"]
    kinds = ", ".join(f"{k} {v[0]}/{v[1]}" for k, v in depth["by_kind"].items())
    lines = [
        f"{r['planes']} planes of {r['sensor'][0]}x{r['sensor'][1]} (padded "
        f"{r['padded_shape'][0]}x{r['padded_shape'][1]}), {r['iterations']} iterations, "
        f"{where}; load average at start {r['machine'].get('load_average_start')}",
        f"peak RSS {peak / gb:.2f} GB vs estimate {est / gb:.2f} GB "
        f"({100 * (r['peak_over_estimate'] - 1):+.1f} %{' worst worker' if r['workers'] else ''})",
        f"seconds per iteration {r['seconds_per_iteration']:.1f} = "
        f"{r['ratio_to_fft_floor']:.2f}x the streamed FFT floor "
        f"({r['fft_floor_seconds']:.1f} s: {r['fft_floor_transforms']})",
        f"CPU seconds per iteration {r['cpu_seconds_per_iteration']:.1f} (measured) = "
        f"{r['cpu_ratio_to_fft_floor']:.2f}x the floor's CPU seconds "
        f"({r['fft_floor_cpu_seconds']:.1f}); wall x cores "
        f"{r['core_seconds_per_iteration_wall']:.1f}",
        "bytes moved per worker per iteration: "
        + ", ".join(f"{m / 1e6:.1f} MB" for m in r["bytes_moved_per_worker_per_iteration"]),
        f"objects at their depth (+-{depth['tolerance_planes']} plane): {depth['found']} of "
        f"{depth['total']} ({kinds}; a bead's light {r['bead_light']:g} pixels' worth)",
    ]
    if "found_within_resolution" in depth:
        ax = r["axial_resolution"]
        per = ax["planes"]
        lines.append(
            f"objects within one axial resolution of their depth (one resolution = "
            f"{min(per):.1f}-{max(per):.1f} planes: the 1/z step at inner product "
            f"{ax['threshold']:g}, Sec. 6.4, measured on planes "
            f"{', '.join(str(m['plane']) for m in ax['measured'])}): "
            f"{depth['found_within_resolution']} of {depth['total']} ("
            + ", ".join(f"{k} {v[0]}/{v[1]}"
                        for k, v in depth["by_kind_within_resolution"].items()) + ")")
    if "relative_difference_to" in r:
        lines.append(f"relative difference to {r['relative_difference_to']['path']}: "
                     f"{r['relative_difference_to']['relative']:.2e}")
    return "\n".join(lines)
