"""Simulated phase SLM on simulated time."""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.simulated._common import SimulatedMixin
from drivers.simulated.clock import SimClock
from drivers.simulated.faults import DeviceFaults
from drivers.slm import Slm, linear_lut

__all__ = ["SimulatedSlm"]


class SimulatedSlm(SimulatedMixin, Slm):
    """A phase SLM panel: an image reaches the panel one refresh period after the
    call, then :attr:`settle_s` of simulated time passes.

    Parameters
    ----------
    device_id : str
        Name of the SLM.
    resolution : (int, int)
        Panel ``(rows, cols)``.
    pixel_pitch_um, wavelength_nm : float
        Pixel pitch (um) and LUT wavelength (nm).
    lut_rad : array_like, optional
        Initial LUT (256 phases, rad); default linear 0..2 pi (:func:`drivers.slm.linear_lut`).
    settle_s : float
        Initial settle time in seconds.
    refresh_hz : float
        Panel refresh rate.
    seed : int
        Seeds the faults.
    clock : SimClock, optional
        Shared simulated time.
    """

    def __init__(
        self, device_id: str, *, resolution: tuple[int, int] = (96, 120),
        pixel_pitch_um: float = 8.0, wavelength_nm: float = 633.0, lut_rad: Any = None,
        settle_s: float = 0.01, refresh_hz: float = 60.0, seed: int = 0,
        clock: SimClock | None = None,
    ) -> None:
        super().__init__(device_id)
        self._sim_setup(clock, DeviceFaults(self, seed))
        self._res = self._int_pair("resolution", resolution, high=8192)
        self._pitch = self._float("pixel_pitch_um", pixel_pitch_um, low=0.0, low_open=True)
        self._wl = self._float("wavelength_nm", wavelength_nm, low=0.0, low_open=True)
        self._lut0 = self._validate_setting(
            "lut_rad", linear_lut() if lut_rad is None else lut_rad, {})
        self._settle0 = self._validate_setting("settle_s", settle_s, {})
        self._frame_s = 1.0 / self._float("refresh_hz", refresh_hz, low=0.0, low_open=True)
        self._hw: dict[str, Any] = {}
        self.panel = np.zeros(self._res, dtype=np.uint8)

    def _do_open(self, timeout_s: float) -> None:
        self.faults._try_connect()
        self._hw = {"lut_rad": self._lut0, "settle_s": self._settle0}
        self.panel = np.zeros(self._res, dtype=np.uint8)

    def _do_close(self) -> None:
        pass

    def _do_get_info(self) -> dict[str, Any]:
        return {"resolution": self._res, "pixel_pitch_um": self._pitch,
                "wavelength_nm": self._wl}

    def _do_show(self, gray: np.ndarray, timeout_s: float) -> None:
        self._raise_fault_timeout("SLM display", timeout_s)
        self.clock.advance(self._frame_s)
        self.panel = gray.copy()
