"""Live reconstruction: what warm-starting ADMM from the previous frame buys.

A moving scene (a natural image panning across the field of view at a fixed speed,
like a sample on a moving stage) is rendered frame by frame with
:func:`recon.simulate.simulate_measurement` (fine grid, shot and read noise: no
inverse crime) and reconstructed with :class:`recon.live.LiveReconstructor` on the
coarse grid. For each ADMM budget of k = 1..K iterations per frame, two runs over the
same frames: cold (every frame from zero) and warm (each frame from the previous
frame's ADMM state). PSNR is against each frame's own truth
(:func:`recon.metrics.psnr`, gain fitted), on the sensor field of view.

:func:`run_live_benchmark` (``diffuserlab benchmark live``) measures the throughput and
latency of the live worker (:class:`instrument.acquisition.live.LiveReconstruction`) on the
real-time simulated camera's stream, and calls :func:`warm_vs_cold` for its PSNR part.
"""

from __future__ import annotations

import time

import numpy as np

from drivers.camera import FrameRing
from recon.live import LiveReconstructor
from recon.metrics import psnr
from recon.options import LiveOptions, ReconOptions
from recon.preprocess import box_bin
from recon.scenes import load_scene
from recon.simulate import Simulation, simulate_measurement
from recon.validate import as_int

from ..acquisition.live import LiveReconstruction
from . import load_sample

#: Longest wait, s, past the run's length for the worker's first frame (a hang guard).
FIRST_FRAME_TIMEOUT_S = 60.0

__all__ = ["live_benchmark_table", "moving_scene", "run_live_benchmark", "warm_vs_cold",
           "warm_vs_cold_table"]


def moving_scene(psf_fine: np.ndarray, frames: int, *, shift_px: int = 2,
                 scene: str = "camera", photons: float = 5000.0, read_noise_e: float = 2.0,
                 seed: int = 0) -> list[Simulation]:
    """Frames of a scene panning sideways, rendered at twice the reconstruction grid.

    Parameters
    ----------
    psf_fine : ndarray, (2 R, 2 C), float
        PSF on the fine (rendering) grid; the reconstruction uses it box-binned by 2.
    frames : int
        Number of frames (>= 1).
    shift_px : int
        Pan per frame in fine pixels (>= 0); 2 is one reconstruction pixel.
    scene : str
        A :data:`recon.scenes.SCENES` name, loaded wide enough for the whole pan.
    photons, read_noise_e : float
        Peak photo-electrons and read noise (:func:`simulate_measurement`).
    seed : int
        Seed of frame 0's noise; frame i uses ``seed + i``.

    Returns
    -------
    list of Simulation
        ``sim.b`` float32 (R, C) in electrons, ``sim.truth`` float32 on the coarse
        padded grid.

    Raises
    ------
    ReconInputError
        Bad counts or noise parameters, or a PSF simulate_measurement refuses.
    """
    frames = as_int(frames, "frames", 1)
    shift_px = as_int(shift_px, "shift_px", 0)
    rows, cols = np.shape(psf_fine)
    wide = load_scene(scene, (rows, cols + shift_px * (frames - 1)))
    return [simulate_measurement(psf_fine, wide[:, i * shift_px:i * shift_px + cols],
                                 bin_factor=2, photons=photons, read_noise_e=read_noise_e,
                                 seed=seed + i)
            for i in range(frames)]


def warm_vs_cold(psf_fine: np.ndarray, sims: list[Simulation], max_iterations: int = 5, *,
                 tv: float | None = None) -> dict:
    """PSNR per iteration budget of cold- and warm-started ADMM on a frame sequence.

    Parameters
    ----------
    psf_fine : ndarray, (2 R, 2 C)
        The rendering PSF of ``sims`` (see :func:`moving_scene`).
    sims : list of Simulation
        At least 2 frames.
    max_iterations : int
        K: budgets 1..K iterations per frame.
    tv : float, optional
        TV weight (default that of :class:`recon.live.LiveReconstructor`).

    Returns
    -------
    dict
        ``iterations`` [1..K]; ``cold_db`` and ``warm_db``: per budget, the PSNR (dB) of
        every frame; ``cold_mean_db`` / ``warm_mean_db``: per budget, the mean over
        frames 2..N (frame 1 is cold in both runs); ``gain_db`` their difference;
        ``frames``; ``shape`` (R, C).

    Raises
    ------
    ReconInputError
        Fewer than 2 frames or an invalid budget.
    """
    from recon.errors import ReconInputError

    if len(sims) < 2:
        raise ReconInputError(f"warm start needs at least 2 frames, got {len(sims)}")
    max_iterations = as_int(max_iterations, "max_iterations", 1)
    psf = box_bin(np.asarray(psf_fine, np.float32), 2)
    out = {"iterations": list(range(1, max_iterations + 1)), "cold_db": [], "warm_db": [],
           "frames": len(sims), "shape": list(psf.shape)}
    for k in out["iterations"]:
        for key, warm in (("cold_db", False), ("warm_db", True)):
            live = LiveReconstructor(psf, ReconOptions.from_defaults(dark="none"), tv=tv)
            scores = []
            for sim in sims:
                res = live.admm(sim.b, iterations=k, warm_start=warm)
                scores.append(psnr(res.estimate[live.operator.crop],
                                   sim.truth[live.operator.crop]))
            out[key].append(scores)
    out["cold_mean_db"] = [float(np.mean(s[1:])) for s in out["cold_db"]]
    out["warm_mean_db"] = [float(np.mean(s[1:])) for s in out["warm_db"]]
    out["gain_db"] = [w - c for w, c in zip(out["warm_mean_db"], out["cold_mean_db"],
                                            strict=True)]
    return out


def warm_vs_cold_table(result: dict) -> str:
    """Text table of :func:`warm_vs_cold`: mean PSNR over frames 2..N per budget."""
    lines = [f"ADMM warm vs cold start, {result['frames']} frames "
             f"{result['shape'][0]}x{result['shape'][1]}, mean PSNR over frames 2..N",
             "iters/frame  cold dB  warm dB  gain dB"]
    for k, c, w, g in zip(result["iterations"], result["cold_mean_db"],
                          result["warm_mean_db"], result["gain_db"], strict=True):
        lines.append(f"{k:>11}  {c:7.2f}  {w:7.2f}  {g:+7.2f}")
    return "\n".join(lines)


def run_live_benchmark(seconds: float = 5.0, fps: float = 30.0,
                       sensor_shape: tuple[int, int] = (300, 400),
                       admm_iterations: int = 5, psnr_frames: int = 8,
                       threads: int | None = None) -> dict:
    """Live throughput, latency and drops on the real-time simulated camera, and
    the PSNR warm start buys (``diffuserlab benchmark live``).

    A :class:`~instrument.devices.virtual_bench.VirtualBench` with ``realtime=True`` and a
    ``sensor_shape`` sensor streams a prerendered bead-flow scene at ``fps`` into a
    ring; :meth:`LiveReconstruction.start() <instrument.acquisition.live.LiveReconstruction.start>`
    with ``ring=`` feeds the worker. The PSF is
    the bench's ray-traced on-axis PSF at the scene depth, as the camera would record it
    (scaled to 4000 DN above the dark offset); frames and PSF have the camera's dark
    offset subtracted. One run per mode (Wiener preview; warm ADMM with
    ``admm_iterations``) of ``seconds`` each, longer where the worker
    has not yet received a frame (see :func:`_stream_for`). The PSNR part is
    :func:`warm_vs_cold` on the real DiffuserCam PSF (moving
    natural scene, ``psnr_frames`` frames, 300 x 400).

    Parameters
    ----------
    seconds : float
        Duration of each streaming run, s.
    fps : float
        Camera frame rate, Hz (the simulated camera allows up to 30).
    sensor_shape : (rows, cols)
        Simulated sensor.
    admm_iterations : int
        K of the ADMM run and of the PSNR table.
    psnr_frames : int
        Frames of the warm/cold PSNR comparison (>= 2).
    threads : int, optional
        Thread cap of the live worker (:class:`~instrument.acquisition.live.LiveReconstruction`);
        None: all cores.

    Returns
    -------
    dict
        ``runs``: per mode the worker's ``stats()`` at the end, ``latency`` (whole-run
        summary, with the compute time that bounds the worker's rate), ``ring`` counters
        and ``camera_fps``; ``psnr``: the warm/cold table.
    """
    from instrument.config import default_bench
    from instrument.devices.video_scenes import BeadFlowScene
    from instrument.devices.virtual_bench import VirtualBench

    cfg = default_bench()
    geo = cfg.geometry.model_copy(update={"sensor_shape_px": tuple(sensor_shape)})
    result: dict = {"sensor_shape": list(sensor_shape), "camera_fps_set": fps, "runs": {},
                    "threads": threads}
    with VirtualBench(cfg.model_copy(update={"geometry": geo}), seed=1, realtime=True,
                      render_cache_size=8) as vb:
        vb.led_array.all_off()
        scene = BeadFlowScene(seed=2, time_step_s=0.5)  # 8 states of the 4 s period
        vb.set_scene(scene)
        vb.prerender()
        cam = vb.camera
        cam.apply_settings({"exposure_s": 0.005, "frame_rate_hz": fps})
        h = vb.psf((0.0, 0.0, scene.z_mm))
        psf = h / h.max() * 4000.0 + cam.dark_offset_dn
        for mode in ("wiener", f"admm:{admm_iterations}"):
            method, _, k = mode.partition(":")
            live = LiveReconstruction(
                LiveReconstructor(psf, ReconOptions.from_defaults(dark=cam.dark_offset_dn),
                                  regularization=1e-2),
                LiveOptions.from_defaults(method=method, iterations=int(k or 1)),
                window_s=seconds, threads=threads)
            ring = FrameRing(64)
            cam.start_stream(ring)
            live.start(ring=ring)
            t0 = time.monotonic()
            _stream_for(live, seconds)
            cam.stop_stream()
            elapsed = time.monotonic() - t0
            live.stop()  # waits for its frame (a hang guard)
            counters = ring.counters()
            result["runs"][mode] = {"stats": live.stats(), "latency": live.latency_summary(),
                                    "ring": counters,
                                    "camera_fps": counters["acquired"] / elapsed}
    fine = load_sample(2).psf
    result["psnr"] = warm_vs_cold(fine, moving_scene(fine, psnr_frames, shift_px=4),
                                  admm_iterations)
    result["text"] = live_benchmark_table(result) + "\n" + warm_vs_cold_table(result["psnr"])
    return result


def _stream_for(live: LiveReconstruction, seconds: float, poll_s: float = 0.05) -> None:
    """Let the stream run ``seconds`` and until the worker has received a frame.

    A short run on a loaded machine can end before the camera thread's first frame
    reaches the worker; a run with no frame measures nothing. The wait for the first
    frame is bounded by :data:`FIRST_FRAME_TIMEOUT_S` (a hang guard, not a figure).
    """
    deadline = time.monotonic() + seconds + FIRST_FRAME_TIMEOUT_S
    time.sleep(seconds)
    while live.stats()["received"] == 0 and time.monotonic() < deadline:
        time.sleep(poll_s)


def live_benchmark_table(result: dict) -> str:
    """Text table of the streaming part of :func:`run_live_benchmark`."""
    rows, cols = result["sensor_shape"]
    lines = [f"live reconstruction on the real-time simulated camera, {rows}x{cols}, camera "
             f"set to {result['camera_fps_set']:g} fps, worker threads "
             f"{result.get('threads') or 'all'}",
             "mode      camera fps  live fps  received  recon'd  skipped  errors  "
             "latency med ms  p95 ms  ring dropped  capacity fps"]
    for mode, r in result["runs"].items():
        s, lat = r["stats"], r["latency"]
        med = "-" if lat["median_s"] is None else f"{1e3 * lat['median_s']:.1f}"
        p95 = "-" if lat["p95_s"] is None else f"{1e3 * lat['p95_s']:.1f}"
        cap = "-" if lat["compute_median_s"] is None else f"{1 / lat['compute_median_s']:.1f}"
        lines.append(f"{mode:<8}  {r['camera_fps']:10.1f}  {s['fps']:8.1f}  "
                     f"{s['received']:8d}  {s['reconstructed']:7d}  {s['skipped']:7d}  "
                     f"{s['errors']:6d}  {med:>14}  {p95:>6}  {r['ring']['dropped']:12d}  "
                     f"{cap:>12}")
    return "\n".join(lines)
