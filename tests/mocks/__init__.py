"""Protocol emulators of real devices, for the driver tests.

They live in the installed package :mod:`drivers.emulators` (so that the
``diffuserlab emulators start`` command can run them without the tests) and are
re-exported here: serial devices on a pseudo-terminal (Thorlabs APT, Zaber ASCII,
illuminate, the Arduino LED protocol) and the LightCrafter 4500's HID reports.
"""

from drivers.emulators import *  # noqa: F403
from drivers.emulators import __all__  # noqa: F401
