"""Protocol emulators of the hardware the drivers speak to, for tests and for running
the whole application without hardware (``diffuserlab emulators start``).

Serial devices run on a pseudo-terminal (:class:`PtyEmulator`), so a driver goes
through the real pyserial path; the DMD's USB HID reports go through a fake hidapi
module. Each emulator is written from the protocol notes (wire format, replies,
errors, timing), not from another project's code, and offers fault injection:
dropped replies, errors, stalls, limit switches and unplug / re-plug.
"""

from drivers.emulators._motion import Motion
from drivers.emulators._pty import PtyEmulator
from drivers.emulators.arduino_led import ArduinoLedEmulator
from drivers.emulators.dlpc350 import Dlpc350Emulator, FakeHid, FakeUsb
from drivers.emulators.illuminate import IlluminateEmulator
from drivers.emulators.template_stage import TemplateStageEmulator
from drivers.emulators.thorlabs_apt import AptEmulator
from drivers.emulators.zaber import ZaberEmulator

__all__ = [
    "AptEmulator", "ArduinoLedEmulator", "Dlpc350Emulator", "FakeHid", "FakeUsb",
    "IlluminateEmulator", "Motion", "PtyEmulator", "TemplateStageEmulator", "ZaberEmulator",
]
