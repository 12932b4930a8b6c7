"""Calibration plans the bench operator runs (layer 4): dark/flat, PSF sweeps, ...

May import ``instrument`` and ``recon`` (see docs/architecture.md). Importing the package
registers every plan (:func:`instrument.plan.register_plan`), so a stored run can be
resumed from its recorded plan name.
"""

from .angular_response import AngularResponsePlan
from .dark_flat import DarkFlatPlan
from .microscope import calibrate_microscope, microscope_depths, microscope_grid_plans
from .psf_blind import PsfBlindPlan
from .psf_grid import PsfGridPlan
from .psf_sweep import PsfSweepPlan, probe_inverse_depth_step, sweep_depths
from .slm_lut import SlmLutPlan
from .slm_lut_io import apply_lut, load_lut

__all__ = ["AngularResponsePlan", "DarkFlatPlan", "PsfBlindPlan", "PsfGridPlan", "PsfSweepPlan",
           "SlmLutPlan", "apply_lut", "calibrate_microscope", "load_lut", "microscope_depths",
           "microscope_grid_plans", "probe_inverse_depth_step", "sweep_depths"]
