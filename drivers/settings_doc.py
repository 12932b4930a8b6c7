"""Write docs/drivers/settings.md from the settings declared by each device kind.

``python -m drivers.settings_doc`` rewrites the page; ``--check`` exits 1 when the
page differs from the declarations (``tests/drivers/test_settings.py`` checks it).
"""

from __future__ import annotations

import argparse
import sys
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

__all__ = ["DEFAULT_PAGE", "DRIVERS", "KINDS", "main", "page"]

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


def main(argv: list[str] | None = None) -> int:
    """Write (or with ``--check`` compare) the settings page; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m drivers.settings_doc",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--page", type=Path, default=DEFAULT_PAGE, help="the Markdown file")
    parser.add_argument("--check", action="store_true",
                        help="compare instead of writing; exit 1 when it differs")
    args = parser.parse_args(argv)
    text = page()
    if args.check:
        current = args.page.read_text(encoding="utf-8") if args.page.exists() else ""
        if current != text:
            print(f"{args.page} is out of date: run python -m drivers.settings_doc",
                  file=sys.stderr)
            return 1
        return 0
    args.page.write_text(text, encoding="utf-8")
    print(f"wrote {args.page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
