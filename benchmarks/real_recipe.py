"""The scene calibration's recipe as a column of the real-data benchmark.

A camera calibrated from known scenes (``calibrate psf-from-scenes``) reconstructs,
by default, with the recipe fitted on its own calibration pairs
(:mod:`recon.analysis.early_stop`: PSF threshold, FISTA iteration count, TV denoising
weight). In the leave-one-out benchmark (:mod:`benchmarks.real_data`) pair ``k`` is
the scene, the other pairs are the calibration: the recipe for pair ``k`` is fitted
on them alone, each reconstructed with a PSF estimated from the rest of them
(:func:`recon.analysis.early_stop.fit_held_out`: strictly nested, pair ``k`` touches
neither the PSF nor any of the three numbers). The fit is timed apart from the
reconstruction (a one-off of the calibration, not of each image).

:func:`family_oracle` scores the scored pair itself at every setting of the recipe's
grid: the best fixed setting of the recipe's family on each pair, which sees the
truth (the bound the fitted recipe is compared with).
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.real_priors import gain_fit, score

__all__ = ["calibrate_recipe", "family_oracle", "solve_recipe"]


def calibrate_recipe(k: int, scenes, measurements, psf, log=print) -> dict:
    """The recipe for pair ``k``, fitted on the other pairs only.

    Parameters
    ----------
    k : int
        The scored pair.
    scenes, measurements : list of ndarray, (H, W, 3) float32
        Every pair (the measurements dark-subtracted).
    psf : ndarray, (H, W, 3) float32
        Pair ``k``'s PSF, estimated from the other pairs (the one the recipe is for).
    log : callable

    Returns
    -------
    dict
        ``{"recipe": EarlyStop}``: the keywords of :func:`solve_recipe`.
    """
    from recon.analysis.early_stop import fit_held_out

    t0 = time.perf_counter()
    recipe = fit_held_out(scenes, measurements, k, psf=psf)
    seconds = time.perf_counter() - t0
    field = ("none fitted" if recipe.field_gain_db is None else
             f"{'kept' if recipe.field_response is not None else 'not kept'}, "
             f"{recipe.field_gain_db:+.2f} dB held out")
    log(f"recipe for pair {k}: PSF threshold {recipe.psf_threshold:g}, {recipe.iterations} "
        f"iterations, denoising {recipe.denoise_weight:g}, field response {field} (fitted "
        f"in {seconds:.0f} s)")
    return {"recipe": recipe}


def solve_recipe(psf, raw, weight, iterations, recipe=None):
    """:func:`recon.analysis.early_stop.reconstruct_early_stopped` with ``recipe``:
    what ``recon --psf RUN`` runs for a scene-calibrated run (``weight`` and
    ``iterations`` are the recipe's own, the arguments unused).

    Returns
    -------
    ndarray, (H, W, 3) float32
    """
    from recon.analysis.early_stop import reconstruct_early_stopped

    return np.asarray(reconstruct_early_stopped(psf, raw, recipe, dark="none").image)


def family_oracle(psf, raw, truth, recipe) -> dict:
    """PSNR and SSIM of the scored pair at every setting of ``recipe``'s grid, each
    with the recipe's field response (if it has one) as its reconstruction applies it.

    Parameters
    ----------
    psf, raw, truth : ndarray, (H, W, 3) float32
        The pair's PSF (estimated without it), measurement and lensed truth.
    recipe : recon.early_stop.EarlyStop
        Its grids (thresholds, counts, weights) are scored.

    Returns
    -------
    dict
        ``best``: the setting with the highest PSNR (``psf_threshold``,
        ``iterations``, ``denoise_weight``, ``psnr_db``, ``ssim``); ``fitted``: the
        recipe's own setting scored the same way (``psnr_db``, ``ssim``).
    """
    from recon.analysis.early_stop import solve_checkpoints
    from recon.early_stop import clean_psf, denoise_tv
    from recon.field_response import apply_field_response

    best, fitted = None, None
    for t in recipe.thresholds:
        images = solve_checkpoints(clean_psf(psf, t), raw, recipe.candidates)
        for n in recipe.candidates:
            for w in recipe.weights:
                image = apply_field_response(denoise_tv(images[n], w), recipe.field_response)
                psnr, ssim = score(gain_fit(image, truth), truth)
                row = {"psf_threshold": t, "iterations": n, "denoise_weight": w,
                       "psnr_db": psnr, "ssim": ssim}
                if best is None or psnr > best["psnr_db"]:
                    best = row
                if (t, n, w) == (recipe.psf_threshold, recipe.iterations,
                                 recipe.denoise_weight):
                    fitted = row
    return {"best": best, "fitted": fitted}
