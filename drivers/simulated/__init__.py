"""Simulated drivers for every device kind, on a shared simulated clock.

They implement the same interfaces as the hardware drivers and pass the same
conformance tests. Time is a :class:`SimClock` advanced by operations (a move, an
exposure, a settle), so tests never sleep; on ``SimClock(realtime=True)`` the clock
follows the wall clock and a streaming simulated camera delivers its frames from a
grab thread at its frame rate (video, live views). Every device has ``faults`` for
seeded fault injection (timeouts, disconnection, dropped frames, stuck axes).
"""

from drivers.simulated.camera import SimulatedCamera
from drivers.simulated.clock import SimClock
from drivers.simulated.dmd import SimulatedDmd
from drivers.simulated.faults import CameraFaults, DeviceFaults, StageFaults
from drivers.simulated.led_array import DEFAULT_COLOURS, SimulatedLedArray
from drivers.simulated.slm import SimulatedSlm
from drivers.simulated.stage import SimulatedStage

__all__ = [
    "DEFAULT_COLOURS",
    "CameraFaults",
    "DeviceFaults",
    "SimClock",
    "SimulatedCamera",
    "SimulatedDmd",
    "SimulatedLedArray",
    "SimulatedSlm",
    "SimulatedStage",
    "StageFaults",
]
