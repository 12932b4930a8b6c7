"""Live reconstruction: what warm-starting ADMM from the previous frame buys.

A moving scene (a natural image panning across the field of view at a fixed speed,
like a sample on a moving stage) is rendered frame by frame with
:func:`recon.simulate.simulate_measurement` (fine grid, shot and read noise: no
inverse crime) and reconstructed with :class:`recon.live.LiveReconstructor` on the
coarse grid. For each ADMM budget of k = 1..K iterations per frame, two runs over the
same frames: cold (every frame from zero) and warm (each frame from the previous
frame's ADMM state). PSNR is against each frame's own truth
(:func:`recon.metrics.psnr`, gain fitted), on the sensor field of view.

The throughput and latency of the live worker on a camera stream are measured at the
instrument level (:func:`instrument.live.run_live_benchmark`), which calls this for
its PSNR part.
"""

from __future__ import annotations

import numpy as np

from ..live import LiveReconstructor
from ..metrics import psnr
from ..preprocess import box_bin
from ..scenes import load_scene
from ..simulate import Simulation, simulate_measurement
from ..validate import as_int

__all__ = ["moving_scene", "warm_vs_cold", "warm_vs_cold_table"]


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
    from ..errors import ReconInputError

    if len(sims) < 2:
        raise ReconInputError(f"warm start needs at least 2 frames, got {len(sims)}")
    max_iterations = as_int(max_iterations, "max_iterations", 1)
    psf = box_bin(np.asarray(psf_fine, np.float32), 2)
    out = {"iterations": list(range(1, max_iterations + 1)), "cold_db": [], "warm_db": [],
           "frames": len(sims), "shape": list(psf.shape)}
    for k in out["iterations"]:
        for key, warm in (("cold_db", False), ("warm_db", True)):
            live = LiveReconstructor(psf, dark="none", tv=tv)
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
