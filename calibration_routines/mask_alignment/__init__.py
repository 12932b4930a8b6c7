"""SLM-mask alignment with spot feedback (Kuo 2020 Sec. 7.4; docs/protocols.md).

:class:`MaskAligner` runs the procedure on a bench (SLM, camera, 6-axis mask stage)
and writes an alignment record (:class:`AlignmentRecord`, read back with
:func:`load_alignment`) whose corrected mask later holograms use;
``diffuserlab align mask BENCH.toml [--simulate]`` is its command line.
"""

from .config import AlignmentConfig
from .errors import AlignmentFailed, MaskNotFound
from .fitting import best_subpixel_offset, fit_similarity, fit_triangle
from .procedure import MaskAligner
from .record import AlignmentRecord, corrected_mask, load_alignment, section_bounds
from .spotmeter import SpotMeter, SpotReading, blazed_phase

__all__ = ["AlignmentConfig", "AlignmentFailed", "AlignmentRecord", "MaskAligner",
           "MaskNotFound", "SpotMeter", "SpotReading", "blazed_phase", "corrected_mask",
           "best_subpixel_offset", "fit_similarity", "fit_triangle", "load_alignment",
           "section_bounds"]
