"""The text of docs/drivers/settings.md, from the settings declared by each device kind.

``python -m instrument.writer.docpage`` rewrites the page (the drivers write no files);
``--check`` exits 1 when the page differs from the declarations
(``tests/drivers/test_settings.py`` checks it).
"""

from __future__ import annotations

from pathlib import Path

from drivers.aravis_camera import AravisCamera
from drivers.arduino_led import ArduinoLedArray
from drivers.camera import Camera
from drivers.dlp_lightcrafter import LightCrafter4500
from drivers.dmd import Dmd
from drivers.illuminate import IlluminateLedArray
from drivers.led_array import LedArray
from drivers.settings import settings_markdown
from drivers.simulated import (
    SimulatedCamera,
    SimulatedDmd,
    SimulatedLedArray,
    SimulatedSlm,
    SimulatedStage,
)
from drivers.slm import Slm
from drivers.slm_window import FullscreenSlm
from drivers.stage import Stage
from drivers.template import TemplateStage
from drivers.thorlabs_apt import ThorlabsAptStage
from drivers.v4l2_camera import V4l2Camera
from drivers.zaber_ascii import ZaberAsciiStage

__all__ = ["DEFAULT_PAGE", "DRIVERS", "KINDS", "page"]

#: The device kinds, in the order of the page.
KINDS = {"camera": Camera, "stage": Stage, "led_array": LedArray, "slm": Slm, "dmd": Dmd}
#: The drivers of this package (a driver that changes its kind's table gets a section).
DRIVERS = (AravisCamera, ArduinoLedArray, FullscreenSlm, IlluminateLedArray, LightCrafter4500,
           SimulatedCamera, SimulatedDmd, SimulatedLedArray, SimulatedSlm, SimulatedStage,
           TemplateStage, ThorlabsAptStage, V4l2Camera, ZaberAsciiStage)
#: The page in a source checkout.
DEFAULT_PAGE = Path(__file__).resolve().parents[1] / "docs" / "drivers" / "settings.md"


def page() -> str:
    """The page's text, generated from the declarations of :data:`KINDS`."""
    return settings_markdown(KINDS, DRIVERS)

