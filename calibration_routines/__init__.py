"""Calibration plans the bench operator runs (layer 4): dark/flat, PSF sweeps, ...

May import ``instrument`` and ``recon`` (see docs/architecture.md). The names below are
imported on first use (PEP 562), so that the ``calibrate`` and ``align`` commands'
parsers (:mod:`calibration_routines.cli`) load neither scipy nor the plans.
:func:`register_plans` imports every plan module, which registers every plan
(:func:`instrument.acquisition.plan.register_plan`), so a stored run can be resumed from its
recorded plan name.
"""

from typing import TYPE_CHECKING

from diffuserlab.lazy import lazy_attributes

__all__ = ["AngularResponsePlan", "DarkFlatPlan", "PsfBlindPlan", "PsfGridPlan", "PsfSweepPlan",
           "SlmLutPlan", "apply_lut", "calibrate_microscope", "load_lut", "microscope_depths",
           "microscope_grid_plans", "probe_inverse_depth_step", "register_plans",
           "sweep_depths"]

_LAZY = {"AngularResponsePlan": ".angular_response", "DarkFlatPlan": ".dark_flat",
         "calibrate_microscope": ".microscope", "microscope_depths": ".microscope",
         "microscope_grid_plans": ".microscope", "PsfBlindPlan": ".psf_blind",
         "PsfGridPlan": ".psf_grid", "PsfSweepPlan": ".psf_sweep",
         "probe_inverse_depth_step": ".psf_sweep", "sweep_depths": ".psf_sweep",
         "SlmLutPlan": ".slm_lut", "apply_lut": ".slm_lut_io", "load_lut": ".slm_lut_io"}

#: The modules that define (and so register) the plans.
PLAN_MODULES = (".angular_response", ".dark_flat", ".psf_blind", ".psf_grid", ".psf_sweep",
                ".slm_lut")

if TYPE_CHECKING:  # pragma: no cover
    from .angular_response import AngularResponsePlan
    from .dark_flat import DarkFlatPlan
    from .microscope import calibrate_microscope, microscope_depths, microscope_grid_plans
    from .psf_blind import PsfBlindPlan
    from .psf_grid import PsfGridPlan
    from .psf_sweep import PsfSweepPlan, probe_inverse_depth_step, sweep_depths
    from .slm_lut import SlmLutPlan
    from .slm_lut_io import apply_lut, load_lut


def register_plans() -> None:
    """Import every plan module, registering its plan for
    :func:`instrument.acquisition.plan.plan_from_record` (what resuming a stored run needs)."""
    import importlib

    for module in PLAN_MODULES:
        importlib.import_module(module, __name__)


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, globals(), __all__)
