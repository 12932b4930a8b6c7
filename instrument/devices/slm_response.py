"""The physical gray -> phase response of the virtual bench's SLM (unknown to the software).

What a liquid-crystal SLM really does with a gray level is a property of the panel,
its drive electronics and the wavelength; the software only *believes* a LUT
(:attr:`drivers.slm.Slm.lut_rad`, linear until calibrated). The virtual bench renders
the holography branch through :class:`SlmPhaseResponse` (the truth), so the SLM
phase-LUT calibration has something real to measure.

Wavelength scaling (docs/hardware.md, "Phase SLMs"): the retardance of the liquid
crystal is a path difference, so the phase at wavelength ``lambda`` is
``phi(g) = (lambda_design / lambda) * phi_design(g)`` (first order; LC dispersion is
neglected).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SlmPhaseResponse"]


@dataclass(frozen=True)
class SlmPhaseResponse:
    """A monotone gray -> phase response, tabulated at a design wavelength.

    Attributes
    ----------
    design_phase_rad : tuple of 256 float
        Phase delay (rad) of gray levels 0..255 at ``design_wavelength_nm``,
        non-decreasing.
    design_wavelength_nm : float or None
        Wavelength (nm) the table holds for; the phase scales as
        ``design_wavelength_nm / wavelength_nm``. None: the same at every wavelength
        (no scaling).

    Raises
    ------
    ValueError
        Not 256 finite non-decreasing phases, or a non-positive wavelength.
    """

    design_phase_rad: tuple
    design_wavelength_nm: float | None = 532.0

    def __post_init__(self):
        table = np.asarray(self.design_phase_rad, dtype=np.float64)
        if table.shape != (256,) or not np.all(np.isfinite(table)) or np.any(np.diff(table) < 0):
            raise ValueError("design_phase_rad must be 256 finite, non-decreasing phases (rad); "
                             "build one with SlmPhaseResponse.nonlinear() or .linear()")
        object.__setattr__(self, "design_phase_rad", tuple(table.tolist()))
        wl = self.design_wavelength_nm
        if wl is not None and not (math.isfinite(wl) and wl > 0):
            raise ValueError(f"design_wavelength_nm={wl!r}: give a wavelength in nm > 0, or None")

    @classmethod
    def nonlinear(cls, max_phase_rad: float = 2.1 * math.pi, gamma: float = 1.6,
                  linear_fraction: float = 0.3,
                  design_wavelength_nm: float = 532.0) -> SlmPhaseResponse:
        """An uncalibrated LCoS-like response with a gamma bend (the virtual bench default).

        ``phi(g) = max_phase_rad * ((1 - a) x^gamma + a x)``, ``x = g / 255``,
        ``a = linear_fraction``: smooth, strictly increasing (slope ``a max/255`` at
        gray 0), 0 at gray 0 and ``max_phase_rad`` at gray 255 at the design wavelength.
        With the defaults it reaches 2.1 pi at 532 nm and differs from the software's
        uncalibrated ``2 pi g / 256`` by -0.65 to +0.34 rad (0.45 rad RMS over the
        levels; 0.85 rad RMS at 633 nm, where it reaches 1.76 pi).

        Raises
        ------
        ValueError
            ``max_phase_rad <= 0``, ``gamma <= 0`` or ``linear_fraction`` outside [0, 1].
        """
        if not max_phase_rad > 0 or not gamma > 0 or not 0 <= linear_fraction <= 1:
            raise ValueError(f"max_phase_rad={max_phase_rad!r} and gamma={gamma!r} must be > 0 "
                             f"and linear_fraction={linear_fraction!r} in [0, 1]")
        x = np.arange(256) / 255.0
        a = float(linear_fraction)
        return cls(tuple(max_phase_rad * ((1.0 - a) * x**gamma + a * x)), design_wavelength_nm)

    @classmethod
    def linear(cls) -> SlmPhaseResponse:
        """``2 pi g / 256`` at every wavelength: the response the software assumes
        uncalibrated (:func:`drivers.slm.linear_lut`); for tests that need the old ideal
        SLM."""
        return cls(tuple(2.0 * math.pi * np.arange(256) / 256.0), None)

    def lut_rad(self, wavelength_nm: float) -> np.ndarray:
        """The response at ``wavelength_nm``.

        Returns
        -------
        numpy.ndarray
            float64 (256,), radians: ``design_phase_rad * design_wavelength_nm /
            wavelength_nm`` (unscaled without a design wavelength).

        Raises
        ------
        ValueError
            ``wavelength_nm`` not a positive number.
        """
        if not (math.isfinite(wavelength_nm) and wavelength_nm > 0):
            raise ValueError(f"wavelength_nm={wavelength_nm!r}: give the laser wavelength in "
                             "nm > 0")
        table = np.asarray(self.design_phase_rad, dtype=np.float64)
        if self.design_wavelength_nm is None:
            return table
        return table * (self.design_wavelength_nm / float(wavelength_nm))
