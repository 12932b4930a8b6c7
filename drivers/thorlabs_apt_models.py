"""Thorlabs APT controllers and stages: which scaling a controller model uses, and the
counts per unit of the stages it drives.

The controller is identified by the model string of MGMSG_HW_GET_INFO (bytes 4-11),
not by its serial number: serial prefixes 40 and 70 cover both BSC20x racks and the
legacy BSC101/BSC103 racks, whose steppers have another microstep count and no
53.68 velocity scaling (pylablib's ``KinesisMotor`` decides from the model string
too). A KDC101/TDC001 also reports the stage it was set up for (bytes 76-77 of
HW_GET_INFO), which names the stage when the bench file does not.

Sources: Thorlabs APT host-controller protocol (2025 issue) for the DC servo and
stepper scaling; the stage constants are Thorlabs' manuals as tabulated in pylablib
(``devices/Thorlabs/kinesis.py``, ``_get_step_scale``), except the Z8 actuators, for
which the 2025 protocol document's 34554.96 counts/mm is used (older documents and
pylablib: 34304; calibrate it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = [
    "COUNTS_PER_UNIT",
    "KDC_STAGE_IDS",
    "LEGACY_MODELS",
    "POSITION_TOLERANCE_COUNTS",
    "STAGES",
    "Stage",
    "profile_of_model",
    "velocity_units",
]

#: DC servo velocity time unit (s): velocity = counts/s x T x 65536, acceleration x T².
T_DC = 2048 / 6e6

#: Profile of each supported controller model (model strings as HW_GET_INFO reports).
_MODEL_PROFILES: tuple[tuple[str, str], ...] = (
    (r"KDC101|TDC001", "kdc101"),
    (r"KST101|KST201|TST101", "kst101"),
    (r"BSC20\d", "bsc20x"),
)
#: Models refused: another stepper scaling that no test here has checked.
LEGACY_MODELS = r"BSC00\d|BSC10\d|TST001|SSC20\d"

#: Default counts per mm when neither counts_per_unit nor a stage is known: Z8 actuator
#: (2025 document), ZST actuator, DRV013 (1 mm per turn). Calibrate on the bench.
COUNTS_PER_UNIT: dict[str, float] = {"kdc101": 34554.96, "kst101": 2008645.63,
                                     "bsc20x": 409600.0}
#: Default tolerance of a move's end position, counts: a DC servo settles within a few
#: tens of encoder counts of its target (20 counts = 0.6 um with a Z8, well inside its
#: 1.5 um repeatability); a stepper ends on the commanded microstep.
POSITION_TOLERANCE_COUNTS: dict[str, int] = {"kdc101": 20, "kst101": 2, "bsc20x": 2}


@dataclass(frozen=True)
class Stage:
    """A Thorlabs stage: the profiles that drive it, its unit and counts per unit."""

    profiles: tuple[str, ...]
    unit: str
    counts_per_unit: float


_DC, _STEP = ("kdc101",), ("kst101", "bsc20x")
#: Known stages by name (upper case).
STAGES: dict[str, Stage] = {
    **{name: Stage(_DC, "mm", 34554.96) for name in
       ("Z806", "Z812", "Z825", "MTS25-Z8", "MTS50-Z8")},
    **{name: Stage(_DC, "mm", 24600.0) for name in ("Z606", "Z612", "Z625")},
    "PRM1-Z8": Stage(_DC, "deg", 1919.6418578623391),
    "PRM1TZ8": Stage(_DC, "deg", 1919.6418578623391),
    "ZST": Stage(_STEP, "mm", 2008645.63),
    "ZFS": Stage(_STEP, "mm", 2184533.33),
    "DRV001": Stage(_STEP, "mm", 819200.0),
    **{name: Stage(_STEP, "mm", 409600.0) for name in
       ("DRV013", "DRV014", "NRT100", "NRT150", "LTS150", "LTS300")},
    **{name: Stage(_STEP, "mm", 327680.0) for name in ("DRV113", "DRV114")},
    "FW103": Stage(_STEP, "deg", 409600 / 360),
    "NR360": Stage(_STEP, "deg", 409600 / (360 / 66)),
}
#: Stage ids a KDC101/TDC001 reports in HW_GET_INFO bytes 76-77 (those in STAGES).
KDC_STAGE_IDS: dict[int, str] = {6: "PRM1-Z8", 7: "MTS25-Z8", 8: "MTS50-Z8", 9: "Z825",
                                 10: "Z812", 11: "Z806"}


def profile_of_model(model: str) -> str | None:
    """The profile of a controller ``model`` string; None for an unknown model.

    Raises
    ------
    ValueError
        A legacy model whose scaling this driver does not support (BSC10x, BSC00x,
        TST001).
    """
    model = model.strip().upper()
    if re.match(LEGACY_MODELS, model):
        raise ValueError(model)
    for pattern, profile in _MODEL_PROFILES:
        if re.match(pattern, model):
            return profile
    return None


def velocity_units(profile: str, counts_per_unit: float, velocity: float,
                   accel: float) -> tuple[int, int]:
    """(velocity, acceleration) in a controller's units for unit/s and unit/s².

    DC servo (kdc101): counts/s x T x 65536 and counts/s² x T² x 65536 with T = 2048 /
    6e6 s; steppers (kst101, bsc20x): microsteps/s x 53.68 and microsteps/s² / 90.9.
    """
    if profile == "kdc101":
        return round(counts_per_unit * T_DC * 65536 * velocity), max(
            1, round(counts_per_unit * T_DC * T_DC * 65536 * accel))
    return round(counts_per_unit * velocity * 53.68), max(1, round(counts_per_unit * accel
                                                                    / 90.9))
