"""Spot measurements on the bench: show an SLM phase, capture, measure the spot.

The alignment metric (docs/protocols.md, "Mask alignment", steps 0-1) is the spot
efficiency ``eta = (E_W - n_W b) / E_total`` of a dark-subtracted frame
(:func:`recon.optics.holo_display.efficiency`): window energy above the local
background over the whole frame's energy, so laser drift and exposure cancel.
Each reading auto-exposes first (peak near half of full scale, never saturated,
exposure steps of x0.5-2, a bench-time budget), then averages frames.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from instrument.acquisition.exposure import ExposureError, average_frames, full_scale
from instrument.acquisition.plan import PlanError
from recon.optics.holo_display import efficiency

__all__ = ["SpotMeter", "SpotReading", "blazed_phase"]


@dataclass(frozen=True)
class SpotReading:
    """One spot measurement.

    Attributes
    ----------
    eta : float
        Spot efficiency (dimensionless; about 0, possibly negative, without a spot).
    peak_to_background : float
        Brightest window pixel above the ring background over the background's spread.
    centroid_px : (float, float)
        Background-subtracted intensity centroid ``(x, y)`` in the window (camera px).
    exposure_s : float
    peak_fraction : float
        Brightest pixel (dark removed) as a fraction of full scale.
    railed : bool
        The exposure sat at its upper bound below the target (dim frame).
    frames : int
        Frames captured for this reading (auto-exposure trials included).
    bench_time_s, host_time_s : float
        When the reading finished (bench clock; ``time.time()``).
    """

    eta: float
    peak_to_background: float
    centroid_px: tuple[float, float]
    exposure_s: float
    peak_fraction: float
    railed: bool
    frames: int
    bench_time_s: float
    host_time_s: float

    def as_dict(self) -> dict:
        """JSON-ready fields."""
        return asdict(self)


def blazed_phase(shape, u) -> np.ndarray:
    """Linear phase ramp that sends an SLM's light to far-field frequency ``u``.

    ``phi[r, c] = 2 pi (ux c / C + uy r / R)``: with the FFT convention of
    :mod:`recon.optics.holo_display` the field ``exp(i phi)`` focuses at ``u`` (in
    far-field samples, cycles per SLM aperture).

    Parameters
    ----------
    shape : (int, int)
        SLM ``(R, C)``.
    u : (float, float)
        ``(ux, uy)``.

    Returns
    -------
    numpy.ndarray
        float64 (R, C), radians.
    """
    rows, cols = shape
    r = np.arange(rows)[:, None] / rows
    c = np.arange(cols)[None, :] / cols
    return 2 * math.pi * (float(u[0]) * c + float(u[1]) * r)


class SpotMeter:
    """Show SLM phases and measure spots on the bench camera.

    Parameters
    ----------
    bench : instrument.devices.bench.Bench
        Open bench with a camera and an SLM.
    frames : int
        Frames averaged per reading (after auto-exposure; >= 1).
    window : int
        Odd metric window (camera px).
    target : float
        Auto-exposure target of the brightest pixel (fraction of full scale).
    tolerance : float
        Accepted deviation from ``target`` (eta is a ratio, so a loose tolerance only
        saves frames).
    exposure_bounds_s : (float, float)
    budget_s : float
        Bench-time budget of one reading's auto-exposure (timeout).
    timeout_s : float
        Per-frame and per-SLM-update timeout.
    on_reading : callable, optional
        Called with every :class:`SpotReading` (the record's capture log).
    check : callable, optional
        Called before every capture (abort/pause hook; may raise).

    Notes
    -----
    Call :meth:`measure_dark` once first: it asks the operator to cap the camera (the
    virtual bench does it itself), stores the dark level and the hot pixels (more
    than 8 read-noise sigma above the dark mean), which are replaced by the frame
    median in every later frame so a hot pixel never sets the exposure.
    """

    def __init__(self, bench, *, frames: int = 3, window: int = 5, target: float = 0.5,
                 tolerance: float = 0.1, exposure_bounds_s: tuple[float, float] = (1e-5, 1.0),
                 budget_s: float = 5.0,
                 timeout_s: float = 5.0, on_reading: Callable | None = None,
                 check: Callable | None = None):
        if frames < 1:
            raise PlanError(f"frames per reading must be >= 1, got {frames}")
        if window < 1 or window % 2 == 0:
            raise PlanError(f"the metric window must be odd and >= 1, got {window}")
        if not 0.05 <= target <= 0.9:
            raise PlanError(f"auto-exposure target {target} must be in [0.05, 0.9]")
        self.bench = bench
        if not 0 < tolerance < target:
            raise PlanError(f"auto-exposure tolerance {tolerance} must be in (0, target)")
        self.frames, self.window, self.target = int(frames), int(window), float(target)
        self.tolerance = float(tolerance)
        self.exposure_bounds_s = (float(exposure_bounds_s[0]), float(exposure_bounds_s[1]))
        self.budget_s, self.timeout_s = float(budget_s), float(timeout_s)
        self.on_reading, self.check = on_reading, check
        self.dark_dn: float | None = None
        self.hot: np.ndarray | None = None
        self.captures = 0

    @property
    def camera(self):
        return self.bench.camera

    def measure_dark(self, n: int = 8) -> float:
        """Dark level (DN) and hot-pixel map from ``n`` capped frames at the current exposure."""
        self.bench.prompt("cap_camera", "cap the camera (dark frames for the spot metric)")
        try:
            dark, _ = average_frames(self.camera, n, self.timeout_s)
        finally:
            self.bench.prompt("uncap_camera", "uncap the camera")
        med = float(np.median(dark))
        spread = 1.4826 * float(np.median(np.abs(dark - med))) * math.sqrt(n) + 1.0
        self.hot = dark > med + 8 * spread
        self.dark_dn = med
        self.captures += n
        return med

    def show(self, phase: np.ndarray) -> int:
        """Display ``phase`` (rad) through the SLM's LUT; returns the pattern id (settled)."""
        return self.bench.slm.show_phase(phase, timeout_s=self.timeout_s)

    def _clean(self, img: np.ndarray) -> np.ndarray:
        out = img.astype(np.float64) - self.dark_dn
        if self.hot is not None and self.hot.any() and self.hot.shape == out.shape:
            out[self.hot] = float(np.median(out))
        return out

    def frame(self) -> tuple[np.ndarray, float, float, bool, int]:
        """Auto-exposed, averaged, dark-subtracted frame of what is displayed.

        Returns
        -------
        image : numpy.ndarray
            float64 (rows, cols), DN per second of exposure.
        exposure_s, peak_fraction : float
        railed : bool
            Upper exposure bound reached below the target.
        frames : int
            Frames taken.

        Raises
        ------
        instrument.acquisition.exposure.ExposureError
            Saturated at the shortest exposure (too bright: lower the laser power or add
            an ND filter), or the budget ran out.
        """
        if self.dark_dn is None:
            raise PlanError("measure_dark() must run before the first spot reading")
        cam = self.camera
        full = full_scale(cam) - self.dark_dn
        hi = self.exposure_bounds_s[1]
        start = self.bench.now_s()
        n = 0
        while True:
            img, exposure, peak, tries = self._expose(full, start)
            n += tries
            if self.frames == 1:
                break
            mean, meta = average_frames(cam, self.frames, self.timeout_s)
            n += self.frames
            if not any(m["saturated_pixels"] for m in meta):
                img = self._clean(mean)
                break
            # a frame of the average saturated (noise or drift): search again
        railed = peak < self.target - self.tolerance and exposure >= hi
        self.captures += n
        return img / exposure, exposure, peak, railed, n

    def _expose(self, full: float, start: float) -> tuple[np.ndarray, float, float, int]:
        """Single frames until the peak is within ``tolerance`` of the target (or the
        upper bound is reached below it): the last frame, its exposure and peak, and
        the frames taken."""
        cam = self.camera
        lo, hi = self.exposure_bounds_s
        n = 0
        while True:
            if self.check is not None:
                self.check()
            exposure = cam.exposure_s
            fr = cam.snap(timeout_s=self.timeout_s)
            n += 1
            img = self._clean(fr.image)
            peak = float(img.max()) / full
            if fr.saturated_pixels:
                if exposure <= lo * 1.0001:
                    raise ExposureError(cam.device_id, "spot saturates at the shortest exposure "
                                        f"{lo:g} s", "lower the laser power or add an ND filter")
                new = max(exposure * 0.5, lo)
            elif abs(peak - self.target) <= self.tolerance or (peak < self.target
                                                                and exposure >= hi):
                return img, exposure, peak, n
            else:
                new = min(max(exposure * min(2.0, max(0.5, self.target / max(peak, 1e-6))), lo),
                          hi)
            if self.bench.now_s() - start > self.budget_s:
                raise ExposureError(cam.device_id, f"no stable exposure within {self.budget_s} s",
                                    "check for flicker or laser instability")
            cam.exposure_s = new

    def read(self, phase: np.ndarray | None, spot_px) -> SpotReading:
        """Show ``phase`` (None: keep the current pattern) and measure the spot at ``spot_px``.

        Parameters
        ----------
        phase : numpy.ndarray or None
            float (R, C) SLM phase in radians.
        spot_px : (float, float)
            Expected spot position ``(x, y)`` on the camera.

        Returns
        -------
        SpotReading
        """
        if phase is not None:
            self.show(phase)
        img, exposure, peak, railed, n = self.frame()
        eta = efficiency(img, spot_px, self.window)
        pbr, centroid = _window_stats(img, spot_px, self.window)
        reading = SpotReading(float(eta), pbr, centroid, float(exposure), float(peak),
                              bool(railed), n, float(self.bench.now_s()), time.time())
        if self.on_reading is not None:
            self.on_reading(reading)
        return reading

    def brightest(self, exclude_px=None, exclude_radius: float = 4.0) -> tuple[float, float]:
        """Centroid ``(x, y)`` of the brightest spot of an auto-exposed frame.

        Pixels within ``exclude_radius`` of ``exclude_px`` (e.g. the zero order) are
        ignored when looking for the maximum.
        """
        img, *_ = self.frame()
        work = img.copy()
        if exclude_px is not None:
            yy, xx = np.indices(work.shape)
            work[(xx - exclude_px[0]) ** 2 + (yy - exclude_px[1]) ** 2
                 <= exclude_radius**2] = -np.inf
        r, c = np.unravel_index(int(np.argmax(work)), work.shape)
        return _window_stats(img, (c, r), self.window)[1]


def _window_stats(img: np.ndarray, spot_px, window: int) -> tuple[float, tuple[float, float]]:
    """Peak-to-background ratio and background-subtracted centroid in a window."""
    rows, cols = img.shape
    cx, cy = int(round(spot_px[0])), int(round(spot_px[1]))
    h = window // 2
    r0, r1 = max(cy - h, 0), min(cy + h + 1, rows)
    c0, c1 = max(cx - h, 0), min(cx + h + 1, cols)
    o0, o1 = max(cy - 2 * h - 1, 0), min(cy + 2 * h + 2, rows)
    p0, p1 = max(cx - 2 * h - 1, 0), min(cx + 2 * h + 2, cols)
    inner = img[r0:r1, c0:c1]
    ring_mask = np.ones((o1 - o0, p1 - p0), bool)
    ring_mask[r0 - o0:r1 - o0, c0 - p0:c1 - p0] = False
    ring = img[o0:o1, p0:p1][ring_mask]
    bg = float(np.mean(ring)) if ring.size else 0.0
    spread = float(np.std(ring)) if ring.size > 1 else 0.0
    pbr = (float(inner.max()) - bg) / max(spread, 1e-12)
    w = np.clip(inner - bg, 0.0, None)
    if w.sum() > 0:
        yy, xx = np.mgrid[r0:r1, c0:c1]
        centroid = (float((w * xx).sum() / w.sum()), float((w * yy).sum() / w.sum()))
    else:
        centroid = (float(cx), float(cy))
    return float(pbr), centroid
