"""Which planes of a PSF stack a volume reconstruction needs (``recon3d --planes auto``).

A sweep calibrated finer than the camera resolves in depth costs planes (FFTs, memory)
that add nothing: :func:`recon.analysis.recommend_grid` (Sec. 4.4, Eq. 4.7) gives the
planes that Nyquist-sample the measured axial resolution over the scene's depths, and
:func:`select_planes` keeps the calibrated PSF nearest each of them. This thins a sweep
by the camera's resolution, never by where the light is: the automatic 3D weight
(:func:`recon.auto.volume.auto_volume`) keeps every plane it is given and reports those
that show no signal.
"""

from __future__ import annotations

import numpy as np

__all__ = ["select_planes"]


def select_planes(stack: np.ndarray, depths_mm, raw: np.ndarray, *, pitch_um: float | None,
                  d_mm: float | None, bin_factor: int, dark="auto",
                  scene_depth_range_mm=None) -> tuple[np.ndarray, dict]:
    """Indices of the calibrated planes nearest the recommended reconstruction planes.

    Parameters
    ----------
    stack : ndarray, (n_z, rows, cols)
        The PSF stack as loaded (any order of depths).
    depths_mm : sequence of float, (n_z,)
    raw : ndarray, (rows, cols)
        The measurement (prepared alike, for the dark level).
    pitch_um : float
        Sensor pixel pitch, um, unbinned.
    d_mm : float
        Diffuser-to-sensor distance, mm.
    bin_factor : int
        Lateral binning of the reconstruction (the PSFs are compared binned).
    dark : "auto", "none" or float
        As :func:`recon.volume.api.prepare_volume_problem`.
    scene_depth_range_mm : (float, float), optional
        Depths the scene occupies; planes outside are not kept.

    Returns
    -------
    indices : ndarray of int
        Ascending indices into ``stack`` (each once).
    record : dict
        JSON-ready: the recommendation (:meth:`recon.analysis.GridRecommendation.to_dict`),
        the kept depths and how many planes were dropped.

    Raises
    ------
    recon.errors.ReconInputError
        No pitch or diffuser distance (naming the options), or the errors of
        :func:`recon.analysis.recommend_grid` (e.g. a PSF whose similarity never
        falls to the threshold).
    """
    from recon.analysis import recommend_grid
    from recon.errors import ReconInputError
    from recon.volume.api import prepare_volume_problem

    if pitch_um is None or d_mm is None:
        raise ReconInputError("--planes auto needs the sensor pixel pitch (--pitch-um) and "
                              "the diffuser-to-sensor distance (--d-mm) to find the planes "
                              "the camera resolves; give both, or --planes all")
    z = np.asarray(depths_mm, np.float64)
    prepared, _, _ = prepare_volume_problem(np.asarray(stack, np.float32),
                                            np.asarray(raw, np.float32), dark, bin_factor)
    rec = recommend_grid(prepared, z, pitch_mm=float(pitch_um) * 1e-3 * bin_factor,
                         d_mm=float(d_mm), scene_depth_range_mm=scene_depth_range_mm)
    keep = np.unique(np.asarray(rec.psf_indices, int))  # indices into the caller's stack
    record = {"recommendation": rec.to_dict(), "kept_depths_mm": [float(v) for v in z[keep]],
              "calibrated_planes": int(len(z)), "kept_planes": int(len(keep)),
              "reason": (f"{len(keep)} of {len(z)} calibrated planes: the nearest to the "
                         f"{len(rec.depths_mm)} planes that Nyquist-sample the measured axial "
                         f"resolution ({rec.inverse_depth_step_per_mm:.3g} 1/mm apart in "
                         f"1/z) over {rec.span_mm[0]:g}-{rec.span_mm[1]:g} mm")}
    return keep, record
