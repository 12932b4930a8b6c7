"""Dark frames and flat field at the current exposure; hot-pixel and pixel-gain maps.

Two points:

0. ``dark``: the camera capped, LEDs off, at the exposure the plan was built with
   (:meth:`DarkFlatPlan.for_bench` takes the camera's current one), ``n_frames``
   frames.
1. ``flat``: camera uncapped, diffuser and pinhole removed, so the bare sensor sees
   the lit LED array directly (a smooth, nearly uniform illumination: each LED is a
   distant point source, and the array is much wider than the sensor);
   auto-exposure (:data:`FLAT_EXPOSURE`), ``n_frames`` flat frames, LEDs off,
   ``n_frames`` dark frames at the flat's exposure (``flat_dark``).

The teardown uncaps the camera, installs the pinhole and the diffuser again and sets
the camera back to the dark's exposure (the operator's, when built with
:meth:`~DarkFlatPlan.for_bench`). The runner puts back what the run changed on every
exit path (:meth:`instrument.acquisition.plan.Plan.teardown`): a run that fails or is aborted
after the dark point has the camera uncapped; one that ends in the flat point has the
pinhole and diffuser put back.

Products (:meth:`DarkFlatPlan.reduce`), all ``(rows, cols)``:

* ``dark_mean`` (float32, DN): mean dark frame, the black level plus dark current
  at this exposure;
* ``dark_std`` (float32, DN): per-pixel temporal standard deviation of the dark
  frames (``ddof=1``): read noise, dark-current shot noise and quantisation;
* ``hot_pixel_map`` (uint8, 1 = hot): ``dark_mean > median + k * s`` with the
  robust sigma ``s = max(1.4826 * MAD, 1 / sqrt(12 n))`` (MAD the median absolute
  deviation of ``dark_mean`` from its median over the sensor; the floor is the
  quantisation noise of a mean of ``n`` integer frames, so a noise-free sensor has
  no "hot" pixels) and ``k = hot_sigma_k`` (default 8); a map *at this exposure*
  (hot pixels are dark current: longer exposures show more of them);
* ``flat_field`` (float32, 1): ``F / mean(F)`` with ``F = mean(flat) -
  mean(flat_dark)``;
* ``pixel_gain`` (float32, 1): ``flat_field / gaussian_filter(flat_field,
  smooth_sigma_px)``: the flat field divided by its smooth component
  (illumination, vignetting, angular fall-off), leaving the per-pixel gain, i.e.
  the photo-response non-uniformity (PRNU) map.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter

from instrument.acquisition.plan import (
    AutoExposure,
    Capture,
    Expose,
    Light,
    Plan,
    PlanError,
    PlanPoint,
    Prompt,
    register_plan,
)

__all__ = ["FLAT_EXPOSURE", "MAD_TO_SIGMA", "DarkFlatPlan", "hot_pixels"]

#: Auto-exposure of the flat: brightest pixels at 60-80 % of full scale (a smooth
#: field: well exposed, so its shot noise is low, but far from saturation).
FLAT_EXPOSURE = AutoExposure(target=0.7, tolerance=0.1, required=False)

#: The flat's mean signal above its darks must exceed this many times their temporal
#: noise (the median per-pixel std of the flat's dark frames, at least the 8-bit
#: quantisation floor 1/sqrt(12) DN): below it the flat received no light worth the
#: name and its pixel-gain map would be noise (libaravis's fake camera, whose ramp
#: pattern the LEDs do not change, gave a flat 0.002 DN above its darks, with a noise
#: of 0.71 DN, and a PRNU of 28 000).
FLAT_MIN_SNR = 5.0

#: MAD of a normal distribution times this is its standard deviation.
MAD_TO_SIGMA = 1.4826


def hot_pixels(dark_mean: np.ndarray, k: float, n_frames: int) -> tuple[np.ndarray, float, float]:
    """Robust hot-pixel rule on a mean dark frame.

    Parameters
    ----------
    dark_mean : ndarray, (rows, cols)
        Mean of ``n_frames`` dark frames, DN.
    k : float
        Threshold in robust sigmas above the median.
    n_frames : int
        Frames averaged (sets the quantisation floor of the robust sigma).

    Returns
    -------
    hot : ndarray of bool, (rows, cols)
        ``dark_mean > median + k * s``, ``s = max(1.4826 MAD, 1 / sqrt(12 n_frames))``.
    threshold_dn : float
        ``median + k * s``, DN.
    sigma_dn : float
        ``s``, DN.
    """
    values = np.asarray(dark_mean, np.float64)
    median = float(np.median(values))
    mad = float(np.median(np.abs(values - median)))
    sigma = max(MAD_TO_SIGMA * mad, 1.0 / math.sqrt(12.0 * max(int(n_frames), 1)))
    threshold = median + float(k) * sigma
    return values > threshold, threshold, sigma


def _stack(store, point: int, tag: str) -> tuple[np.ndarray, float, dict]:
    frames, coords = store.point_frames(point, tag)
    exposures = {c["exposure_s"] for c in coords}
    if len(exposures) != 1:
        raise PlanError(f"point {point}: the {tag!r} frames have exposures "
                        f"{sorted(exposures)}; they must share one (rerun the point)")
    info = {"gain": coords[0]["gain"],
            "saturated_pixels": max(c["saturated_pixels"] for c in coords)}
    return frames.astype(np.float64), exposures.pop(), info


@register_plan
class DarkFlatPlan(Plan):
    """Dark frames, flat field, hot-pixel map and PRNU map (module docstring).

    Parameters
    ----------
    exposure_s : float
        Exposure of the dark frames, s (:meth:`for_bench`: the camera's current one).
    n_frames : int
        Frames per series (dark, flat, flat dark), >= 2 (a temporal std needs two).
    flat_brightness : float
        LED brightness of the flat, in (0, 1].
    hot_sigma_k : float
        Hot-pixel threshold in robust sigmas above the median dark (default 8).
    smooth_sigma_px : float
        Gaussian sigma, pixels, of the smooth component divided out of the flat
        field to leave the pixel gain (default 8).

    Raises
    ------
    PlanError
        A parameter out of range.
    """

    name = "dark-flat"

    def __init__(self, *, exposure_s: float, n_frames: int = 32, flat_brightness: float = 1.0,
                 hot_sigma_k: float = 8.0, smooth_sigma_px: float = 8.0) -> None:
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise PlanError(f"exposure_s={exposure_s!r}: give the dark exposure in seconds > 0")
        if int(n_frames) != n_frames or n_frames < 2:
            raise PlanError(f"n_frames={n_frames!r}: need at least 2 frames per series (the "
                            "temporal noise needs two); raise calibration.dark_frames")
        if not 0 < flat_brightness <= 1:
            raise PlanError(f"flat_brightness={flat_brightness!r}: use a value in (0, 1]")
        if not hot_sigma_k > 0:
            raise PlanError(f"hot_sigma_k={hot_sigma_k!r}: use a positive number of sigmas")
        if not smooth_sigma_px > 0:
            raise PlanError(f"smooth_sigma_px={smooth_sigma_px!r}: use a positive width")
        super().__init__(exposure_s=float(exposure_s), n_frames=int(n_frames),
                         flat_brightness=float(flat_brightness),
                         hot_sigma_k=float(hot_sigma_k), smooth_sigma_px=float(smooth_sigma_px))

    @classmethod
    def for_bench(cls, bench, **params) -> DarkFlatPlan:
        """The plan at the camera's current exposure with the bench config's
        ``calibration.dark_frames`` frames per series, unless ``params`` say otherwise
        (``frames`` is accepted for ``n_frames``, as ``diffuserlab calibrate dark
        --frames`` passes it)."""
        if "frames" in params:
            frames = params.pop("frames")
            if params.setdefault("n_frames", frames) != frames:
                raise PlanError("give n_frames or frames, not both")
        params.setdefault("exposure_s", float(bench.camera.exposure_s))
        if bench.config is not None:
            params.setdefault("n_frames", bench.config.calibration.dark_frames)
        return cls(**params)

    def points(self) -> list[PlanPoint]:
        n = self.params["n_frames"]
        return [PlanPoint({"kind": "dark", "exposure_s": self.params["exposure_s"]},
                          ("dark",) * n),
                PlanPoint({"kind": "flat"}, ("flat",) * n + ("flat_dark",) * n)]

    def steps(self, index, point):
        p = self.params
        n = p["n_frames"]
        if point.coords["kind"] == "dark":
            yield Prompt("cap_camera", "Cap the camera: no light may reach the sensor")
            yield Light(())
            yield Expose(exposure_s=p["exposure_s"])
            yield Capture(n, "dark")
            return
        yield Prompt("uncap_camera", "Uncap the camera")
        yield Prompt("remove_diffuser", "Remove the diffuser and its aperture: the bare "
                     "sensor must see the LED array")
        yield Prompt("remove_pinhole", "Remove the pinhole: the bare sensor must see the "
                     "whole lit LED array")
        yield Light("all", p["flat_brightness"])
        yield Expose(auto=FLAT_EXPOSURE)
        yield Capture(n, "flat")
        yield Light(())
        yield Capture(n, "flat_dark")

    def teardown(self):
        yield Prompt("uncap_camera", "Uncap the camera")
        yield Prompt("install_pinhole", "Install the pinhole again")
        yield Prompt("install_diffuser", "Install the diffuser and its aperture again")
        yield Expose(exposure_s=self.params["exposure_s"])

    def reduce(self, store) -> dict:
        """Write ``dark_mean``, ``dark_std``, ``hot_pixel_map``, ``flat_field`` and
        ``pixel_gain`` (module docstring) and return the summary.

        Returns
        -------
        dict
            ``exposure_s`` (dark), ``flat_exposure_s``, ``dark_level_dn`` (median of
            ``dark_mean``), ``read_noise_dn`` (median of ``dark_std``),
            ``n_hot_pixels``, ``hot_pixel_fraction``, ``hot_threshold_dn``,
            ``hot_sigma_dn``, ``prnu_rms`` (std of ``pixel_gain`` over the pixels
            that are not hot; it includes the shot noise of the mean flat),
            ``prnu_noise_rms`` (that noise, from the flat's temporal variance) and
            ``prnu_rms_corrected`` (``sqrt(prnu_rms^2 - prnu_noise_rms^2)``), the
            flat's mean level and peak fraction, and saturated pixels seen.

        Raises
        ------
        PlanError
            A series mixes exposures, or the flat received no light (its mean above
            its darks not over ``FLAT_MIN_SNR`` times their temporal noise).
        """
        p = self.params
        n = p["n_frames"]
        dark, exposure, dark_info = _stack(store, 0, "dark")
        dark_mean = dark.mean(axis=0)
        dark_std = dark.std(axis=0, ddof=1)
        del dark
        hot, threshold, robust_sigma = hot_pixels(dark_mean, p["hot_sigma_k"], n)

        flat, flat_exposure, flat_info = _stack(store, 1, "flat")
        flat_dark, fd_exposure, _ = _stack(store, 1, "flat_dark")
        if fd_exposure != flat_exposure:
            raise PlanError(f"the flat ({flat_exposure} s) and its darks ({fd_exposure} s) "
                            "have different exposures; rerun the flat point")
        signal = flat.mean(axis=0) - flat_dark.mean(axis=0)
        dark_var = flat_dark.var(axis=0, ddof=1)
        noise_var = (flat.var(axis=0, ddof=1) + dark_var) / n
        del flat, flat_dark
        level = float(signal.mean())
        noise = max(float(np.median(np.sqrt(dark_var))), 1.0 / math.sqrt(12.0))
        if not level > FLAT_MIN_SNR * noise:
            raise PlanError(f"the flat received no light: its mean is {level:.3g} DN above "
                            f"its dark frames, under {FLAT_MIN_SNR:g} times their noise "
                            f"({noise:.3g} DN); check that the LEDs light, the camera is "
                            "uncapped and the pinhole and diffuser are out")
        flat_field = signal / level
        smooth = gaussian_filter(flat_field, p["smooth_sigma_px"], mode="nearest")
        pixel_gain = flat_field / np.where(smooth > 0, smooth, np.inf)
        good = ~hot & (smooth > 0)
        prnu_rms = float(np.std(pixel_gain[good]))
        rel_noise = noise_var[good] / np.maximum(signal[good], 1e-12) ** 2
        prnu_noise = float(np.sqrt(np.mean(rel_noise)))
        corrected = math.sqrt(max(prnu_rms**2 - prnu_noise**2, 0.0))

        full = float(store.attrs.get("camera", {}).get("full_scale_dn", 2**16 - 1))
        common = {"dark_exposure_s": exposure, "n_frames": n}
        store.write_product("dark_mean", dark_mean.astype(np.float32), units="DN",
                            processing="mean of the dark frames (camera capped, LEDs off)",
                            **common)
        store.write_product("dark_std", dark_std.astype(np.float32), units="DN",
                            processing="per-pixel temporal std of the dark frames (ddof=1)",
                            **common)
        store.write_product("hot_pixel_map", hot.astype(np.uint8), units="1 = hot",
                            rule=f"dark_mean > median + {p['hot_sigma_k']:g} * max(1.4826 "
                                 "MAD, 1/sqrt(12 n)) at this exposure",
                            threshold_dn=threshold, robust_sigma_dn=robust_sigma, **common)
        store.write_product("flat_field", flat_field.astype(np.float32), units="1",
                            processing="(mean(flat) - mean(flat_dark)) / its mean",
                            flat_exposure_s=flat_exposure, flat_mean_dn=level, **common)
        store.write_product("pixel_gain", pixel_gain.astype(np.float32), units="1",
                            processing=f"flat_field / gaussian_filter(flat_field, "
                                       f"{p['smooth_sigma_px']:g} px): the PRNU map",
                            flat_exposure_s=flat_exposure, **common)
        return {"exposure_s": exposure, "flat_exposure_s": flat_exposure,
                "gain_db": dark_info["gain"],
                "dark_level_dn": float(np.median(dark_mean)),
                "read_noise_dn": float(np.median(dark_std)),
                "n_hot_pixels": int(hot.sum()), "hot_pixel_fraction": float(hot.mean()),
                "hot_threshold_dn": threshold, "hot_sigma_dn": robust_sigma,
                "hot_sigma_k": p["hot_sigma_k"],
                "prnu_rms": prnu_rms, "prnu_noise_rms": prnu_noise,
                "prnu_rms_corrected": corrected,
                "flat_mean_dn": level,
                "flat_peak_fraction": float(np.percentile(signal, 99.99)) / full,
                "flat_smooth_range": [float(smooth.min()), float(smooth.max())],
                "saturated_pixels": {"dark": dark_info["saturated_pixels"],
                                     "flat": flat_info["saturated_pixels"]}}
