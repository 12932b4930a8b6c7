"""Simulated DMD pattern sequencer on simulated time."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.dmd import Dmd, PatternEntry
from drivers.simulated._common import SimulatedMixin
from drivers.simulated.clock import SimClock
from drivers.simulated.faults import DeviceFaults

__all__ = ["SimulatedDmd"]

#: LED colours of the simulated projector (a LightCrafter 4500's), nm.
DMD_COLOURS: dict[str, float] = {"red": 624.0, "green": 520.0, "blue": 455.0}


class SimulatedDmd(SimulatedMixin, Dmd):
    """A DMD that plays a sequence on a :class:`SimClock`.

    :attr:`pattern_index` is the entry shown at the current simulated time while
    running (``period_s`` per entry; a sequence loaded without ``repeat`` stops
    after its last entry). Loading a sequence costs ``load_s`` of simulated time.

    Parameters
    ----------
    device_id : str
        Name of the DMD.
    resolution : (int, int)
        Mirror array ``(rows, cols)``; default the LightCrafter 4500's 1140 x 912
        (diamond pixels: 912 columns of 1140 rows).
    colours : Mapping[str, float], optional
        LED colours (name -> nm); default red, green, blue.
    max_entries, max_image : int
        Longest sequence; largest flash image index.
    load_s : float
        Simulated time to load a sequence.
    seed : int
        Seeds the faults.
    clock : SimClock, optional
        Shared simulated time.
    """

    def __init__(self, device_id: str, *, resolution: tuple[int, int] = (1140, 912),
                 colours: Mapping[str, float] | None = None, max_entries: int = 128,
                 max_image: int = 63, load_s: float = 0.01, seed: int = 0,
                 clock: SimClock | None = None) -> None:
        super().__init__(device_id)
        self._sim_setup(clock, DeviceFaults(self, seed))
        self._res = self._int_pair("resolution", resolution, high=8192)
        self._colours = dict(DMD_COLOURS if colours is None else colours)
        self._max_entries = self._int("max_entries", max_entries, low=1, high=4096)
        self._max_image = self._int("max_image", max_image, low=0, high=4096)
        self._load_s = self._float("load_s", load_s, low=0.0)
        self._hw: dict[str, Any] = {}
        self._t_start: float | None = None
        self._loaded: tuple[tuple[PatternEntry, ...], bool] = ((), True)

    def _do_open(self, timeout_s: float) -> None:
        self.faults._try_connect()
        self._hw = {"exposure_s": 0.01, "period_s": 0.01,
                    "led_currents": dict.fromkeys(self._colours, 0.4)}
        self._t_start = None

    def _do_close(self) -> None:
        self._t_start = None

    def _do_get_info(self) -> dict[str, Any]:
        return {"resolution": self._res, "colours": dict(self._colours),
                "max_entries": self._max_entries, "max_image": self._max_image,
                "sources": ("flash", "video")}

    def _do_load(self, entries, repeat, source, timeout_s) -> None:
        self._raise_fault_timeout("DMD sequence load", timeout_s)
        self._t_start = None
        self.clock.advance(self._load_s)
        self._loaded = (entries, repeat)

    def _do_start(self, timeout_s: float) -> None:
        self._raise_fault_timeout("DMD start", timeout_s)
        self._t_start = self.clock.now_s

    def _do_stop(self, timeout_s: float) -> None:
        self._raise_fault_timeout("DMD stop", timeout_s)
        self._t_start = None

    def _do_running(self) -> bool:
        self.faults._check_connected()
        return self.pattern_index is not None

    @property
    def pattern_index(self) -> int | None:
        """Index of the entry on the mirrors now, None when stopped."""
        if self._t_start is None or not self._loaded[0]:
            return None
        k = int((self.clock.now_s - self._t_start) // self._hw["period_s"])
        n = len(self._loaded[0])
        if not self._loaded[1] and k >= n:
            return None
        return k % n
