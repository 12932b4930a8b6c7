"""Conformance suites every driver of a kind must pass (one module per kind).

Use one as a base class of a pytest test class that provides:

- a ``device`` fixture yielding an *opened* device (closed again afterwards);
- ``provoke_timeout(device)``: arrange for the next blocking call to time out
  (fault injection for simulated devices, an emulator delay for real drivers);
- optionally ``advance_time(device, seconds)``: let time pass (default: sleep,
  simulated devices advance their clock).

Example::

    class TestMyCamera(CameraConformance):
        @pytest.fixture
        def device(self):
            with MyCamera("cam0", port=...) as cam:
                yield cam

        def provoke_timeout(self, device):
            emulator.delay_next_reply(10.0)
"""

from .base import DeviceConformance
from .camera import CameraConformance
from .dmd import DmdConformance
from .led_array import LedArrayConformance, SerialLedArrayConformance
from .slm import SlmConformance
from .stage import StageConformance, unplug_mid_move

__all__ = [
    "CameraConformance",
    "DeviceConformance",
    "DmdConformance",
    "LedArrayConformance",
    "SerialLedArrayConformance",
    "SlmConformance",
    "StageConformance",
    "unplug_mid_move",
]
