"""Errors of the SLM-mask alignment (:mod:`calibration_routines.mask_alignment`).

Their own module so that every step (:mod:`.procedure`, :mod:`.focus`) raises them
without importing the other.
"""

from __future__ import annotations

from instrument.acquisition.plan import PlanError

__all__ = ["AlignmentFailed", "MaskNotFound"]


class AlignmentFailed(PlanError):
    """The alignment cannot continue (the message says why and what to do)."""


class MaskNotFound(AlignmentFailed):
    """No spot over the whole coarse search range."""
