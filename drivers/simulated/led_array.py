"""Simulated LED array (grid geometry, named colours) on simulated time."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.errors import DeviceValueError
from drivers.led_array import LedArray, grid_positions
from drivers.simulated._common import SimulatedMixin
from drivers.simulated.clock import SimClock
from drivers.simulated.faults import DeviceFaults

__all__ = ["DEFAULT_COLOURS", "SimulatedLedArray"]

#: Colour channels of the default array: name -> wavelength in nm (None: white).
DEFAULT_COLOURS: dict[str, float | None] = {
    "red": 630.0, "green": 515.0, "blue": 460.0, "white": None,
}


class SimulatedLedArray(SimulatedMixin, LedArray):
    """A rectangular LED grid centred on the optical axis.

    LED ``i * cols + j`` sits in grid row ``i`` (row 0 at the top, largest y) and
    column ``j`` (column 0 at the left, smallest x): ``x = (j - (cols - 1) / 2) *
    pitch_mm``, ``y = ((rows - 1) / 2 - i) * pitch_mm``. Each command takes
    ``command_latency_s`` of simulated time.

    Parameters
    ----------
    device_id : str
        Name of the array.
    shape : (int, int)
        LED grid rows and columns.
    pitch_mm, distance_mm : float
        LED pitch and distance to the sample plane, in mm.
    colours : Mapping[str, float | None], optional
        Colour channels (name -> wavelength nm); default :data:`DEFAULT_COLOURS`.
    na_illum : float
        Initial illumination NA of the patterns.
    command_latency_s : float
        Simulated time per command.
    seed : int
        Seeds the faults.
    clock : SimClock, optional
        Shared simulated time.
    """

    def __init__(
        self, device_id: str, *, shape: tuple[int, int] = (32, 32), pitch_mm: float = 4.0,
        distance_mm: float = 50.0, colours: Mapping[str, float | None] | None = None,
        na_illum: float = 0.25, command_latency_s: float = 1e-3, seed: int = 0,
        clock: SimClock | None = None,
    ) -> None:
        super().__init__(device_id)
        self._sim_setup(clock, DeviceFaults(self, seed))
        rows, cols = self._int_pair("shape", shape, high=1024)
        self._pitch = self._float("pitch_mm", pitch_mm, low=0.0, low_open=True)
        self._distance = self._float("distance_mm", distance_mm, low=0.0, low_open=True)
        self._positions = grid_positions(rows, cols, self._pitch)
        self._colours = dict(DEFAULT_COLOURS if colours is None else colours)
        if not self._colours or not all(isinstance(c, str) for c in self._colours):
            raise self._error(DeviceValueError, f"colours={colours!r} is invalid",
                              "pass {name: wavelength_nm or None}")
        self._na0 = self._float("na_illum", na_illum, low=0.0, low_open=True, high=1.0)
        self._latency = self._float("command_latency_s", command_latency_s, low=0.0)
        self._hw: dict[str, Any] = {}
        self.emitting: dict[int, tuple[str, float]] = {}

    def _do_open(self, timeout_s: float) -> None:
        self.faults._try_connect()
        colour = "white" if "white" in self._colours else next(iter(self._colours))
        self._hw = {"na_illum": self._na0, "colour": colour, "brightness": 1.0}
        self.emitting = {}

    def _do_close(self) -> None:
        self.emitting = {}

    def _do_get_info(self) -> dict[str, Any]:
        return {
            "positions_mm": self._positions.copy(), "pitch_mm": self._pitch,
            "distance_mm": self._distance, "colours": dict(self._colours),
        }

    def _do_show(self, state: dict[int, tuple[str, float]], timeout_s: float) -> None:
        self._raise_fault_timeout("LED command", timeout_s)
        self.clock.advance(self._latency)
        self.emitting = dict(state)
