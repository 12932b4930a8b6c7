"""The emulated bench: the real drivers talking to protocol emulators, no hardware.

:class:`EmulatedBench` starts the serial emulators of :mod:`drivers.emulators` on
pseudo-terminals and keeps, in one directory, a link per device named like udev's
``/dev/serial/by-id`` entries (with the device's serial number), pointing at its
current pty. :data:`BENCH_TEMPLATE` is a bench file that names the *real* drivers
(``thorlabs-apt``, ``zaber-ascii``, ``illuminate``) with those links as their ports
(the Thorlabs controllers found by serial number in the directory, as on a bench),
the ``aravis`` camera driver on libaravis's in-process fake camera, and a simulated
SLM. ``examples/bench-emulated.toml`` is this
template for the default directory, and ``diffuserlab emulators start`` runs the
emulators (and can write the file for another directory).

The emulators run in real time scaled by ``time_scale`` (20: a 10 s move takes
0.5 s), so a calibration plan exercises the drivers' waits, events and polling.
"""

from __future__ import annotations

import os
import string
from pathlib import Path

from diffuserlab.errors import DiffuserLabError
from drivers.emulators import (
    AptEmulator,
    ArduinoLedEmulator,
    IlluminateEmulator,
    PtyEmulator,
    ZaberEmulator,
)

__all__ = ["BENCH_TEMPLATE", "DEFAULT_DIR", "EmulatedBench", "EmulatorsRunningError"]

#: Where the port links live unless told otherwise (the directory
#: examples/bench-emulated.toml names).
DEFAULT_DIR = Path("/tmp/diffuserlab-emulators")
#: USB serial numbers of the three emulated KDC101 controllers (x, y, z).
APT_SERIALS = {"x": "27000001", "y": "27000002", "z": "27000003"}
_APT_LINK = "usb-Thorlabs_Brushed_Motor_Controller_{serial}-if00-port0"
_ZABER_LINK = "usb-Zaber_Technologies_Inc._X-USBDC_ZB0001-if00-port0"
_ILLUMINATE_LINK = "usb-Teensyduino_USB_Serial_IL0042-if00"
_LEDMX_LINK = "usb-Arduino__www.arduino.cc__Uno_LX0001-if00"
_COUNTS_PER_MM = 34554.96  # Z8 actuator
_ZABER_MM = 0.047625e-3  # mm per microstep (X-LSM)
_ZABER_DEG = 0.000234375  # deg per microstep (X-RSW)

#: The emulated bench file; ``$dir`` is the link directory.
BENCH_TEMPLATE = string.Template('''\
# The emulated bench: the real drivers (thorlabs-apt, zaber-ascii, illuminate) talking
# to protocol emulators on pseudo-terminals instead of hardware, the aravis driver on
# libaravis's in-process fake camera ("Fake_1"), and a simulated SLM. Start the
# emulators first (they run until Ctrl-C):
#
#     diffuserlab emulators start
#     diffuserlab devices examples/bench-emulated.toml
#     diffuserlab calibrate psf-sweep examples/bench-emulated.toml --n-depths 3 --out sweep.zarr
#
# The ports are links in $dir that follow the emulators' ptys
# (named like /dev/serial/by-id entries); `diffuserlab emulators start --dir DIR
# --bench-out FILE` runs them elsewhere and writes this file for that directory.
# The emulators are a Python process on this computer: on a loaded machine a reply can
# come a second or more late, so the serial drivers wait up to 5 s for one here (a real
# controller answers within the drivers' default of 1-2 s).

name = "emulated"
description = "Real drivers on emulated hardware (APT, Zaber, illuminate, Aravis fake camera)."
branches = ["lensless", "holography"]

[geometry]
sensor_pixel_pitch_um = 13.0
sensor_shape_px = [512, 512]
diffuser_sensor_distance_mm = 8.9
aperture_mm = [2.67, 2.11]
diffuser_kind = "smooth"
wavelength_nm = 532.0

[calibration]
z_range_mm = [20.0, 60.0]
n_depths = 4
frames_per_point = 1
dark_frames = 4
exposure_bounds_s = [1e-05, 1.0]
settle_s = 0.05

[[devices]]
id = "camera"
kind = "camera"
driver = "aravis"

[devices.params]
camera_name = "Fake_1"
fake_interface = true
pixel_format = "mono8"
pixel_pitch_um = 13.0

[[devices]]
id = "source_stage"
kind = "stage"
driver = "thorlabs-apt"

[devices.params]
axes = ["x", "y", "z"]
serial_numbers = { x = "27000001", y = "27000002", z = "27000003" }
search_dirs = ["$dir"]
limits_mm = { x = [0, 25], y = [0, 25], z = [0, 100] }
counts_per_unit = 34554.96
speed_mm_s = 2.5
home_on_open = true
reply_timeout_s = 5.0

[[devices]]
id = "led_array"
kind = "led_array"
driver = "illuminate"

[devices.params]
port = "$dir/usb-Teensyduino_USB_Serial_IL0042-if00"
shape = [32, 32]
reply_timeout_s = 5.0

[[devices]]
id = "slm"
kind = "slm"
driver = "simulated-slm"

[devices.params]
resolution = [96, 120]
pixel_pitch_um = 8.0
wavelength_nm = 532.0

[[devices]]
id = "mask_stage"
kind = "stage"
driver = "zaber-ascii"

[devices.params]
axes = ["x", "y", "z", "tip", "tilt", "rotation"]
port = "$dir/usb-Zaber_Technologies_Inc._X-USBDC_ZB0001-if00-port0"
device_numbers = { x = 1, y = 2, z = 3, tip = 4, tilt = 5, rotation = 6 }
speed_mm_s = 2.0
speed_deg_s = 5.0
home_on_open = true
reply_timeout_s = 5.0
''')


class EmulatorsRunningError(DiffuserLabError, RuntimeError):
    """Emulators already serve the link directory (another ``emulators start``)."""


class EmulatedBench:
    """The emulators of the emulated bench, with their port links in ``directory``.

    Parameters
    ----------
    directory : str or Path
        Where the links are made (created if needed).
    time_scale : float
        Emulated seconds per real second.
    ledmx : bool
        Also start a LEDMX (DIY Arduino) array, 8 x 8 (not in the bench file).

    Attributes
    ----------
    emulators : dict[str, PtyEmulator]
        ``{name: emulator}`` once started: ``apt-x``, ``apt-y``, ``apt-z``, ``zaber``,
        ``illuminate`` (and ``ledmx``).
    """

    def __init__(self, directory: str | os.PathLike = DEFAULT_DIR, *, time_scale: float = 20.0,
                 ledmx: bool = False) -> None:
        self.directory = Path(directory).expanduser().absolute()
        self.time_scale = float(time_scale)
        self.ledmx = bool(ledmx)
        self.emulators: dict[str, PtyEmulator] = {}

    def _build(self) -> dict[str, PtyEmulator]:
        d, ts = self.directory, self.time_scale
        travel = {"x": 25.0, "y": 25.0, "z": 100.0}
        out: dict[str, PtyEmulator] = {
            f"apt-{axis}": AptEmulator(
                "kdc101", serial_number=int(sn), time_scale=ts, counts_per_unit=_COUNTS_PER_MM,
                travel_counts=(0, round(travel[axis] * _COUNTS_PER_MM)),
                link=d / _APT_LINK.format(serial=sn))
            for axis, sn in APT_SERIALS.items()
        }
        mm, deg = round(5.0 / _ZABER_MM), round(5.0 / _ZABER_DEG)
        rot = round(180.0 / _ZABER_DEG)
        chain = {i: {"axes": 1, "limit_min": -mm, "limit_max": mm} for i in (1, 2, 3)}
        chain.update({i: {"axes": 1, "limit_min": -deg, "limit_max": deg} for i in (4, 5)})
        chain[6] = {"axes": 1, "limit_min": -rot, "limit_max": rot}
        out["zaber"] = ZaberEmulator(chain, time_scale=ts, link=d / _ZABER_LINK)
        out["illuminate"] = IlluminateEmulator((32, 32), pitch_mm=4.0, distance_mm=50.0,
                                               time_scale=ts, link=d / _ILLUMINATE_LINK)
        if self.ledmx:
            out["ledmx"] = ArduinoLedEmulator((8, 8), time_scale=ts, link=d / _LEDMX_LINK)
        return out

    def start(self) -> EmulatedBench:
        """Start every emulator and make its link.

        Raises
        ------
        EmulatorsRunningError
            A link in the directory points at a live pty: emulators run there already.
        """
        self.directory.mkdir(parents=True, exist_ok=True)
        emulators = self._build()
        live = [e.link for e in emulators.values()
                if e.link is not None and e.link.is_symlink() and e.link.exists()]
        if live:
            raise EmulatorsRunningError(
                f"emulators already run in {self.directory} ({live[0].name} is live): stop "
                "them (Ctrl-C in their terminal) or use another --dir")
        try:
            for emu in emulators.values():
                emu.start()
        except BaseException:
            for emu in emulators.values():
                emu.stop()
            raise
        self.emulators = emulators
        return self

    def stop(self) -> None:
        """Stop every emulator and remove its link."""
        for emu in self.emulators.values():
            emu.stop()
        self.emulators = {}

    def __enter__(self) -> EmulatedBench:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def ports(self) -> dict[str, tuple[str, str]]:
        """``{name: (link, pty)}`` of the running emulators."""
        return {name: (emu.port, emu.tty or "") for name, emu in self.emulators.items()}

    def bench_text(self) -> str:
        """The emulated bench file for this directory."""
        return BENCH_TEMPLATE.substitute(dir=str(self.directory))
