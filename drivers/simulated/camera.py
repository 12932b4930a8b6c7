"""Simulated camera with a physical sensor model (EMVA 1288 style)."""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.camera import PIXEL_FORMATS, Camera, Frame, FrameRing
from drivers.errors import DeviceValueError
from drivers.simulated._common import SimulatedMixin
from drivers.simulated.clock import SimClock
from drivers.simulated.faults import CameraFaults

__all__ = ["SimulatedCamera"]

Irradiance = Callable[["SimulatedCamera"], np.ndarray]


class SimulatedCamera(SimulatedMixin, Camera):
    """A camera whose frames come from a sensor model on simulated time.

    Sensor model per frame, for an exposure ``t`` and gain ``g`` dB:

    1. signal electrons ``~ Poisson(t * (qe * E + dark_current + hot))`` with
       ``E = irradiance(camera)`` and ``hot`` the extra dark current of hot pixels;
    2. clipped at ``full_well_e`` (counted as saturated), plus Gaussian read noise
       ``read_noise_e``;
    3. ``DN = round(dark_offset_dn + K * electrons)`` with conversion gain
       ``K = (2**adc_bits - 1) / full_well_e * 10**(g / 20)`` DN per electron, clipped
       to ``[0, 2**adc_bits - 1]`` (full scale counted as saturated);
    4. ROI crop, block-average binning (rounded), and conversion to the pixel format
       (shifting the ``adc_bits`` data to 8/12/16 bits).

    So a flat irradiance gives mean ``offset + K*mu_e`` and variance
    ``K**2 * (mu_e + read_noise_e**2) + 1/12`` DN^2 (unbinned, away from clipping).
    The ROI is cut before the noise is drawn, which is statistically the same.

    Parameters
    ----------
    device_id : str
        Name of the camera.
    sensor_shape : (int, int)
        Full sensor ``(rows, cols)``.
    pixel_pitch_um : float
        Pixel pitch in micrometres.
    irradiance : callable or None
        ``f(camera) -> (rows, cols) float64`` photo-electrons per second per
        full-resolution pixel at ``quantum_efficiency = 1`` (the virtual bench supplies
        it); called once per frame at the frame's simulated time. None: dark frames.
        The callable must not advance the clock.
    quantum_efficiency : float
        Multiplies ``irradiance`` (keep 1.0 when the callable already includes the QE).
    full_well_e, read_noise_e, dark_current_e_per_s : float
        Full-well capacity (e-), read noise (e- rms), dark current (e-/s).
    dark_offset_dn : float
        Black level in ADC DN.
    hot_pixel_fraction : float
        Fraction of pixels that are hot; the map is fixed by ``seed``.
    hot_pixel_e_per_s : float
        Extra dark current of a hot pixel (e-/s).
    adc_bits : int
        ADC resolution (8..16).
    max_frame_rate_hz : float
        Readout limit: the frame period is ``max(exposure_s, 1 / max_frame_rate_hz)``.
    max_gain_db : float
        Largest allowed gain.
    prnu_fraction : float
        Photo-response non-uniformity: each pixel's gain is ``1 + prnu_fraction * g``
        with ``g`` standard normal, fixed by ``seed`` (what a flat field measures).
    seed : int
        Seeds the noise, the hot pixel map, the PRNU map and the faults.
    clock : SimClock, optional
        Shared simulated time (a private clock if None).
    """

    def __init__(
        self, device_id: str, *, sensor_shape: tuple[int, int] = (480, 640),
        pixel_pitch_um: float = 3.45, irradiance: Irradiance | None = None,
        quantum_efficiency: float = 1.0, full_well_e: float = 10_000.0,
        read_noise_e: float = 2.5, dark_current_e_per_s: float = 5.0,
        dark_offset_dn: float = 64.0, hot_pixel_fraction: float = 1e-4,
        hot_pixel_e_per_s: float = 2000.0, adc_bits: int = 12,
        max_frame_rate_hz: float = 30.0, max_gain_db: float = 24.0,
        prnu_fraction: float = 0.0, seed: int = 0, clock: SimClock | None = None,
    ) -> None:
        super().__init__(device_id)
        self._sim_setup(clock, CameraFaults(self, seed))
        # per-pixel maps are allocated here: a simulated sensor stays below 64 Mpx
        self._shape = self._int_pair("sensor_shape", sensor_shape, high=8192)
        self._pitch = self._float("pixel_pitch_um", pixel_pitch_um, low=0, low_open=True)
        if irradiance is not None and not callable(irradiance):
            raise self._error(DeviceValueError, "irradiance is not callable",
                              "pass f(camera) -> (rows, cols) array, or None")
        self.irradiance = irradiance
        self.quantum_efficiency = self._float("quantum_efficiency", quantum_efficiency,
                                              low=0.0, high=1.0)
        self.full_well_e = self._float("full_well_e", full_well_e, low=0, low_open=True)
        self.read_noise_e = self._float("read_noise_e", read_noise_e, low=0.0)
        self.dark_current_e_per_s = self._float("dark_current_e_per_s", dark_current_e_per_s,
                                                low=0.0)
        self.adc_bits = self._int("adc_bits", adc_bits, low=8, high=16)
        self.dark_offset_dn = self._float("dark_offset_dn", dark_offset_dn, low=0.0,
                                          high=2**self.adc_bits - 1)
        frac = self._float("hot_pixel_fraction", hot_pixel_fraction, low=0.0, high=1.0)
        self.hot_pixel_e_per_s = self._float("hot_pixel_e_per_s", hot_pixel_e_per_s, low=0.0)
        self._max_fps = self._float("max_frame_rate_hz", max_frame_rate_hz, low=0,
                                    low_open=True)
        self._max_gain = self._float("max_gain_db", max_gain_db, low=0.0)
        prnu = self._float("prnu_fraction", prnu_fraction, low=0.0, high=0.5)
        seed = self._int("seed", seed, low=0)
        self._seed = seed
        self._hot = np.random.default_rng([seed, 1]).random(self._shape) < frac
        self._prnu = np.clip(1.0 + prnu * np.random.default_rng([seed, 3]).standard_normal(
            self._shape), 0.0, None) if prnu > 0 else None
        self._rng = np.random.default_rng([seed, 2])
        self._hw: dict[str, Any] = {}
        self._index = 0
        self._stream_ring: FrameRing | None = None
        self._timer: int | None = None
        self._next_start = 0.0
        self._last_end = -math.inf
        self._triggers: collections.deque[float] = collections.deque()

    # ----------------------------------------------------------- simulation extras
    @property
    def hot_pixel_mask(self) -> np.ndarray:
        """Full-sensor boolean map of hot pixels (fixed by the seed)."""
        return self._hot.copy()

    @property
    def prnu_map(self) -> np.ndarray:
        """Full-sensor per-pixel gain (mean ~1; all ones without PRNU)."""
        return np.ones(self._shape) if self._prnu is None else self._prnu.copy()

    def reseed_noise(self, key: tuple[int, ...]) -> None:
        """Restart the noise stream from ``(seed, key)``: frames after this call are a
        function of the seed, the key and what the sensor sees (the virtual bench calls
        it before each plan point so a resumed run reproduces an uninterrupted one)."""
        self._rng = np.random.default_rng([self._seed, 2, *(int(k) for k in key)])

    @property
    def conversion_gain_dn_per_e(self) -> float:
        """ADC DN per electron at the current gain (before pixel-format shifting)."""
        self._require_open()
        return self._k()

    @property
    def frame_period_s(self) -> float:
        """Time between frames: ``max(exposure_s, 1 / max_frame_rate_hz)``."""
        self._require_open()
        return self._period()

    def _k(self) -> float:
        return (2**self.adc_bits - 1) / self.full_well_e * 10 ** (self._hw["gain"] / 20.0)

    def _period(self) -> float:
        return max(self._hw["exposure_s"], 1.0 / self._max_fps)

    def fire_hardware_trigger(self) -> None:
        """Simulate an external trigger pulse now (used in trigger_mode "hardware")."""
        self._require_open()
        if self._hw["trigger_mode"] == "hardware":
            self._triggers.append(self.clock.now_s)

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        self.faults._try_connect()
        self._hw = {
            "pixel_format": "mono12" if self.adc_bits <= 12 else "mono16",
            "roi": (0, 0, self._shape[1], self._shape[0]), "binning": 1,
            "exposure_s": 0.01, "gain": 0.0, "trigger_mode": "free_run",
        }
        self._index = 0
        self._triggers.clear()
        self._last_end = -math.inf

    def _do_close(self) -> None:
        self._unsubscribe()

    def _do_get_info(self) -> dict[str, Any]:
        return {
            "sensor_shape": self._shape, "pixel_pitch_um": self._pitch,
            "exposure_range_s": (1e-6, 60.0), "gain_range_db": (0.0, self._max_gain),
            "pixel_formats": list(PIXEL_FORMATS), "max_binning": 8,
        }

    def _do_get_settings(self) -> dict[str, Any]:
        return dict(self._hw)

    def _do_apply(self, name: str, value: Any) -> Any:
        self.faults._check_connected()
        self._hw[name] = value
        if name == "trigger_mode":
            self._triggers.clear()
        return None

    # ----------------------------------------------------------- acquisition hooks
    def _do_snap(self, timeout_s: float) -> Frame:
        self._raise_fault_timeout("snap", timeout_s)
        deadline = self.clock.now_s + timeout_s
        while True:
            if self._hw["trigger_mode"] == "hardware":
                if not self._triggers:
                    self.clock.advance(timeout_s)
                    raise self._timeout(
                        f"no hardware trigger within {timeout_s:g} s",
                        "check the trigger cable/source, or use trigger_mode 'software'",
                    )
                start = max(self._triggers.popleft(), self._last_end)
            else:
                start = max(self.clock.now_s, self._last_end)
            end = start + self._period()
            if end > deadline:
                self.clock.advance_to(max(deadline, self.clock.now_s))
                raise self._timeout(f"no frame within {timeout_s:g} s (frames lost)",
                                    "check the link; raise timeout_s")
            self.clock.advance_to(max(end, self.clock.now_s))
            frame = self._produce(start, end)
            if frame is not None:
                return frame

    def _do_start_stream(self, ring: FrameRing) -> None:
        self.faults._check_connected()
        self._stream_ring = ring
        self._triggers.clear()
        self._next_start = max(self.clock.now_s, self._last_end)
        self._timer = self.clock.subscribe(self._next_event, self._fire)
        ring._attach(self.device_id, self._pump)

    def _do_stop_stream(self) -> None:
        self._unsubscribe()

    def _do_trigger(self) -> None:
        self.faults._check_connected()
        self._triggers.append(self.clock.now_s)

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "time_s": self.clock.now_s, "frame_index": self._index}

    # ----------------------------------------------------------- stream timing
    def _next_times(self) -> tuple[float, float] | None:
        if not self.faults.connected:  # an unplugged camera delivers nothing
            return None
        if self._hw["trigger_mode"] == "free_run":
            start = self._next_start
        elif self._triggers:
            start = max(self._triggers[0], self._last_end)
        else:
            return None
        return start, start + self._period()

    def _next_event(self) -> float | None:
        times = self._next_times()
        return None if times is None else times[1]

    def _fire(self, now: float) -> None:
        start, end = self._next_times()
        if self._hw["trigger_mode"] == "free_run":
            self._next_start = end
        else:
            self._triggers.popleft()
        frame = self._produce(start, end)
        if frame is not None:
            self._stream_ring.put(frame)

    def _pump(self, budget_s: float) -> float:
        """Ring wait on simulated time: run the clock to the next frame or the budget."""
        if self._timer is not None and not self.faults.connected:
            with self._io():  # the camera is flagged as disconnected, the reader told
                self.faults._check_connected()
        now = self.clock.now_s
        nxt = self._next_event() if self._timer is not None else None
        if nxt is not None and nxt - now <= budget_s:
            self.clock.advance_to(max(nxt, now))
            return max(nxt - now, 0.0)
        self.clock.advance(budget_s)
        return budget_s

    def _unsubscribe(self) -> None:
        if self._timer is not None:
            self.clock.unsubscribe(self._timer)
            self._timer = None

    # ----------------------------------------------------------- sensor model
    def _produce(self, start: float, end: float) -> Frame | None:
        """Render the frame exposed from ``start``; None (counted) if dropped."""
        self._last_end = end
        index = self._index
        self._index += 1
        if self.faults._take_drop():
            self._count_dropped()
            if self._stream_ring is not None and self._timer is not None:
                self._stream_ring.mark_dropped()
            return None
        image, saturated = self._render()
        hw = self._hw
        return Frame(image=image, index=index, device_timestamp_s=start,
                     host_timestamp_s=time.time(), exposure_s=hw["exposure_s"],
                     gain=hw["gain"], saturated_pixels=saturated)

    def _render(self) -> tuple[np.ndarray, int]:
        hw = self._hw
        x, y, w, h = hw["roi"]
        win = (slice(y, y + h), slice(x, x + w))
        t = hw["exposure_s"]
        rate = self.dark_current_e_per_s + self.hot_pixel_e_per_s * self._hot[win]
        if self.irradiance is not None:
            e_flux = np.asarray(self.irradiance(self), dtype=np.float64)
            if e_flux.shape != self._shape or not np.all(np.isfinite(e_flux)) or (
                e_flux.min() < 0
            ):
                raise self._error(
                    DeviceValueError,
                    f"irradiance returned shape {e_flux.shape} (or negative/non-finite values)",
                    f"return finite values >= 0 of shape {self._shape} (e-/s per pixel)",
                )
            flux = self.quantum_efficiency * e_flux[win]
            rate = rate + (flux if self._prnu is None else flux * self._prnu[win])
        electrons = self._rng.poisson(rate * t).astype(np.float64)
        saturated = electrons >= self.full_well_e
        np.minimum(electrons, self.full_well_e, out=electrons)
        if self.read_noise_e > 0:
            electrons += self._rng.normal(0.0, self.read_noise_e, electrons.shape)
        full = 2**self.adc_bits - 1
        dn = np.rint(self.dark_offset_dn + self._k() * electrons)
        saturated |= dn >= full
        np.clip(dn, 0, full, out=dn)
        b = hw["binning"]
        if b > 1:
            dn = dn[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b).mean(axis=(1, 3))
            dn = np.rint(dn)
        shift = PIXEL_FORMATS[hw["pixel_format"]] - self.adc_bits
        dn = dn * 2.0**shift if shift >= 0 else np.floor(dn / 2.0**-shift)
        dtype = np.uint8 if hw["pixel_format"] == "mono8" else np.uint16
        return dn.astype(dtype), int(saturated.sum())
