"""Simulated camera with a physical sensor model (EMVA 1288 style)."""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.camera import PIXEL_FORMATS, Camera, Frame, FrameRing
from drivers.errors import DeviceDisconnectedError, DeviceValueError
from drivers.simulated._common import SimulatedMixin
from drivers.simulated.clock import SimClock
from drivers.simulated.faults import CameraFaults

__all__ = ["SimulatedCamera"]

Irradiance = Callable[["SimulatedCamera"], np.ndarray]

#: Standard normal quantiles at (k + 0.5) / 65536: a 16-bit random index into this
#: table is a standard normal draw (tails cut at +-4.32 sigma) at a quarter of the
#: cost of numpy's generator (see SimulatedCamera, "Speed").
_NORMAL_TABLE_SIZE = 65536
#: Derived per-pixel maps kept for the last few distinct irradiance arrays.
_MAP_CACHE_SIZE = 8


def _normal_table() -> np.ndarray:
    from scipy.special import ndtri

    q = (np.arange(_NORMAL_TABLE_SIZE) + 0.5) / _NORMAL_TABLE_SIZE
    return ndtri(q).astype(np.float32)


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

    Timing: free run delivers a frame every ``frame_period_s = max(1 / frame_rate_hz,
    exposure_s)`` (``frame_rate_hz`` at most ``max_frame_rate_hz``, the readout
    limit): an exposure longer than the requested period lowers the rate. The
    irradiance callable sees the scene at :attr:`frame_time_s`, the middle of the
    exposure (no motion blur within an exposure).

    Streaming on a :class:`SimClock`: on the default clock nothing runs by itself;
    a reader waiting on the ring (or any device operation that advances the clock)
    moves time on frame by frame, so tests never sleep. On a real-time clock
    (``SimClock(realtime=True)``) a grab thread paces the clock on the wall clock
    and puts each frame into the ring when it is due, whether or not anyone reads:
    a slow reader loses the oldest frames, counted by the ring as ``skipped``.

    Speed: the per-pixel mean electrons (irradiance x QE x PRNU + dark current and
    hot pixels, times the exposure) are computed once per distinct irradiance
    array and kept for the last 8 (keyed by the array object, the ROI and the
    exposure; only read-only arrays, see below), so each frame only draws fresh
    noise. By default the noise is exact (Poisson shot noise, numpy normal read
    noise: ~100-190 ms per 1200 x 1600 frame on 2 cores). With a finite
    ``gaussian_shot_noise_above_e`` (real-time streaming of large frames; the
    real-time virtual bench sets 100), pixels expecting at least that many
    electrons get Gaussian shot noise ``N(mu, mu)`` (the Poisson's skew
    ``1 / sqrt(mu)`` is dropped), the others exact Poisson draws (by inverse
    transform below 1 electron), and every Gaussian draw (shot and read noise) is
    a 16-bit random index into a table of normal quantiles (tails cut at 4.32
    sigma): ~15-30 ms per 1200 x 1600 frame. To be cached, the irradiance callable
    returns a read-only array (``a.flags.writeable = False``, as the virtual bench
    does): the same read-only object means "unchanged"; a writable array is taken
    as new on every frame.

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
        Readout limit: the upper bound of ``frame_rate_hz`` (also its value on open).
    max_gain_db : float
        Largest allowed gain.
    prnu_fraction : float
        Photo-response non-uniformity: each pixel's gain is ``1 + prnu_fraction * g``
        with ``g`` standard normal, fixed by ``seed`` (what a flat field measures).
    gaussian_shot_noise_above_e : float
        Mean electrons from which shot noise is drawn as a Gaussian, >= 10 (see
        "Speed"); default ``math.inf``: exact Poisson everywhere.
    seed : int
        Seeds the noise, the hot pixel map, the PRNU map and the faults.
    clock : SimClock, optional
        Shared simulated time (a private clock if None).
    """

    _normal: np.ndarray | None = None

    def __init__(
        self, device_id: str, *, sensor_shape: tuple[int, int] = (480, 640),
        pixel_pitch_um: float = 3.45, irradiance: Irradiance | None = None,
        quantum_efficiency: float = 1.0, full_well_e: float = 10_000.0,
        read_noise_e: float = 2.5, dark_current_e_per_s: float = 5.0,
        dark_offset_dn: float = 64.0, hot_pixel_fraction: float = 1e-4,
        hot_pixel_e_per_s: float = 2000.0, adc_bits: int = 12,
        max_frame_rate_hz: float = 30.0, max_gain_db: float = 24.0,
        prnu_fraction: float = 0.0, gaussian_shot_noise_above_e: float = math.inf,
        seed: int = 0, clock: SimClock | None = None,
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
        g = gaussian_shot_noise_above_e
        if not (isinstance(g, int | float) and not isinstance(g, bool) and g >= 10):
            raise self._error(DeviceValueError, f"gaussian_shot_noise_above_e={g!r}",
                              "use a number >= 10 (electrons), or math.inf for exact Poisson")
        self.gaussian_shot_noise_above_e = float(g)
        if math.isfinite(g) and SimulatedCamera._normal is None:  # not on the first frame
            SimulatedCamera._normal = _normal_table()
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
        self._frame_time: float | None = None
        self._maps: collections.OrderedDict[tuple, tuple] = collections.OrderedDict()
        self._grab: tuple[threading.Thread, threading.Event] | None = None

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
        """Time between free-run frames: ``max(1 / frame_rate_hz, exposure_s)``."""
        self._require_open()
        return self._period()

    @property
    def frame_time_s(self) -> float:
        """Simulated time the scene is sampled at: while a frame is rendered, the
        middle of its exposure; otherwise the clock's time (what a time-dependent
        irradiance callable reads)."""
        return self.clock.now_s if self._frame_time is None else self._frame_time

    def _k(self) -> float:
        return (2**self.adc_bits - 1) / self.full_well_e * 10 ** (self._hw["gain"] / 20.0)

    def _period(self) -> float:
        rate = min(self._hw["frame_rate_hz"], self._max_fps)
        return max(self._hw["exposure_s"], 1.0 / rate)

    def _do_resulting_frame_rate_hz(self) -> float:
        return 1.0 / self._period()

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
            "exposure_s": 0.01, "frame_rate_hz": self._max_fps, "gain": 0.0,
            "trigger_mode": "free_run",
        }
        self._index = 0
        self._triggers.clear()
        self._last_end = -math.inf

    def _do_close(self) -> None:
        self._unsubscribe()
        self._maps.clear()

    def _do_get_info(self) -> dict[str, Any]:
        return {
            "sensor_shape": self._shape, "pixel_pitch_um": self._pitch,
            "exposure_range_s": (1e-6, 60.0), "frame_rate_range_hz": (1e-3, self._max_fps),
            "gain_range_db": (0.0, self._max_gain),
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
        if not self.clock.realtime:
            ring._attach(self.device_id, self._pump)
            return
        self.clock.resync()  # frames from now on, not catching up an idle gap
        stop = threading.Event()
        thread = threading.Thread(target=self._grab_loop, args=(ring, stop), daemon=True,
                                  name=f"{self.device_id}-grab")
        self._grab = (thread, stop)
        thread.start()

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
        with self._stream_ring.producing():  # rendering takes CPU time, not a dead camera
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
        if self._grab is not None:
            thread, stop = self._grab
            stop.set()
            if thread is not threading.current_thread():
                thread.join(timeout=5.0 + self._hw.get("exposure_s", 0.0))
            self._grab = None
        if self._timer is not None:
            self.clock.unsubscribe(self._timer)
            self._timer = None

    def _grab_loop(self, ring: FrameRing, stop: threading.Event) -> None:
        """Real-time clock: wait on the wall clock for each frame, then run the clock
        to it (the timer renders the frame and puts it into the ring)."""
        try:
            while not stop.is_set():
                if not self.faults.connected:
                    ring.fail(self._error(DeviceDisconnectedError,
                                          "the camera was unplugged while streaming",
                                          "call reconnect() and start the stream again"))
                    return
                nxt = self._next_event()
                if nxt is None:  # waiting for a trigger
                    stop.wait(0.002)
                    continue
                if stop.wait(self.clock.wall_time_until(nxt)):
                    return
                self.clock.run_until(nxt)
        except Exception as exc:  # noqa: BLE001 -- handed to the reader, not lost
            self._log.error("%s: grab thread failed: %s", self.device_id, exc)
            ring.fail(exc)

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
        hw = self._hw
        self._frame_time = start + 0.5 * hw["exposure_s"]
        try:
            image, saturated = self._render()
        finally:
            self._frame_time = None
        return Frame(image=image, index=index, device_timestamp_s=start,
                     host_timestamp_s=time.time(), exposure_s=hw["exposure_s"],
                     gain=hw["gain"], saturated_pixels=saturated)

    def _mean_electrons(self) -> dict[str, np.ndarray]:
        """Per-pixel maps of the ROI for the current irradiance and exposure: ``mean``
        electrons (float64) for exact noise; with Gaussian shot noise instead
        ``mean32`` and ``sqrt32`` (float32), the flat indices ``low`` of the pixels
        that get exact Poisson noise and their means ``low_mean``. Cached per
        read-only irradiance array (see "Speed")."""
        hw = self._hw
        x, y, w, h = hw["roi"]
        t = hw["exposure_s"]
        e_flux = None if self.irradiance is None else self.irradiance(self)
        cacheable = e_flux is None or (isinstance(e_flux, np.ndarray)
                                       and not e_flux.flags.writeable)
        key = (id(e_flux), hw["roi"], t, self.quantum_efficiency, self.dark_current_e_per_s,
               self.hot_pixel_e_per_s, self.gaussian_shot_noise_above_e)
        hit = self._maps.get(key) if cacheable else None
        if hit is not None and hit[0] is e_flux:
            self._maps.move_to_end(key)
            return hit[1]
        win = (slice(y, y + h), slice(x, x + w))
        rate = self.dark_current_e_per_s + self.hot_pixel_e_per_s * self._hot[win]
        if e_flux is not None:
            flux = np.asarray(e_flux, dtype=np.float64)
            if flux.shape != self._shape or not np.all(np.isfinite(flux)) or flux.min() < 0:
                raise self._error(
                    DeviceValueError,
                    f"irradiance returned shape {flux.shape} (or negative/non-finite values)",
                    f"return finite values >= 0 of shape {self._shape} (e-/s per pixel)",
                )
            flux = self.quantum_efficiency * flux[win]
            rate = rate + (flux if self._prnu is None else flux * self._prnu[win])
        mean = rate * t
        if math.isfinite(self.gaussian_shot_noise_above_e):
            flat = mean.reshape(-1)
            tiny = np.flatnonzero(flat < 1.0)
            low = np.flatnonzero((flat >= 1.0) & (flat < self.gaussian_shot_noise_above_e))
            mean32 = mean.astype(np.float32)
            maps = {"mean32": mean32, "sqrt32": np.sqrt(mean32), "low": low,
                    "low_mean": flat[low], "tiny": tiny, "tiny_p0": np.exp(-flat[tiny]),
                    "tiny_mean": flat[tiny]}
        else:
            maps = {"mean": mean}
        if cacheable:
            self._maps[key] = (e_flux, maps)
            while len(self._maps) > _MAP_CACHE_SIZE:
                self._maps.popitem(last=False)
        return maps

    def _standard_normal(self, shape: tuple[int, ...]) -> np.ndarray:
        """Standard normal float32 draws from the quantile table (tails cut at 4.32)."""
        if SimulatedCamera._normal is None:
            SimulatedCamera._normal = _normal_table()
        idx = self._rng.integers(0, _NORMAL_TABLE_SIZE, shape, dtype=np.uint16)
        return SimulatedCamera._normal.take(idx)

    def _electrons(self, maps: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Signal electrons of one frame with shot noise, clipped at full well, plus
        read noise; and the map of pixels that reached full well."""
        fw = self.full_well_e
        if "low" not in maps:  # exact Poisson and numpy normals (the reference model)
            electrons = self._rng.poisson(maps["mean"]).astype(np.float64)
            saturated = electrons >= fw
            np.minimum(electrons, fw, out=electrons)
            if self.read_noise_e > 0:
                electrons += self._rng.normal(0.0, self.read_noise_e, electrons.shape)
            return electrons, saturated
        shape = maps["mean32"].shape
        electrons = self._standard_normal(shape)
        electrons *= maps["sqrt32"]
        electrons += maps["mean32"]
        if maps["low"].size:
            electrons.reshape(-1)[maps["low"]] = self._rng.poisson(maps["low_mean"])
        if maps["tiny"].size:
            electrons.reshape(-1)[maps["tiny"]] = self._poisson_below_one(
                maps["tiny_mean"], maps["tiny_p0"])
        saturated = electrons >= fw
        np.minimum(electrons, np.float32(fw), out=electrons)
        if self.read_noise_e > 0:
            noise = self._standard_normal(shape)
            noise *= np.float32(self.read_noise_e)
            electrons += noise
        return electrons, saturated

    def _poisson_below_one(self, mean: np.ndarray, p0: np.ndarray) -> np.ndarray:
        """Exact Poisson draws for means < 1 by inverse transform: one uniform per
        pixel, most resolved at 0 (``p0 = exp(-mean)``), the rest in a few steps;
        several times faster than numpy's Poisson for dim pixels."""
        u = self._rng.random(mean.size)
        out = np.zeros(mean.size, np.float32)
        idx = np.flatnonzero(u > p0)
        u, lam, p = u[idx], mean[idx], p0[idx]
        cdf = p.copy()
        for k in range(1, 40):  # P(X >= 40 | mean < 1) < 1e-47
            if not idx.size:
                break
            out[idx] += 1
            p = p * lam / k
            cdf += p
            more = u > cdf
            idx, u, lam, p, cdf = idx[more], u[more], lam[more], p[more], cdf[more]
        return out

    def _render(self) -> tuple[np.ndarray, int]:
        hw = self._hw
        electrons, saturated = self._electrons(self._mean_electrons())
        h, w = electrons.shape
        full = 2**self.adc_bits - 1
        dn = electrons
        dn *= dn.dtype.type(self._k())
        dn += dn.dtype.type(self.dark_offset_dn)
        np.rint(dn, out=dn)
        saturated |= dn >= full
        np.clip(dn, 0, full, out=dn)
        b = hw["binning"]
        if b > 1:
            dn = dn[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b).mean(
                axis=(1, 3), dtype=np.float64)
            dn = np.rint(dn)
        shift = PIXEL_FORMATS[hw["pixel_format"]] - self.adc_bits
        if shift > 0:
            dn *= dn.dtype.type(2.0**shift)
        elif shift < 0:
            dn = np.floor(dn / 2.0**-shift)
        dtype = np.uint8 if hw["pixel_format"] == "mono8" else np.uint16
        return dn.astype(dtype), int(np.count_nonzero(saturated))
