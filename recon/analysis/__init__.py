"""Analysis of calibration measurements (layer 1, numerics only).

Plain numpy/scipy functions used by the calibration routines, following G. Kuo,
*Exploiting Randomness in Computational Cameras and Displays* (PhD dissertation,
UC Berkeley, 2020):

- :mod:`recon.analysis.psf` -- DCT background removal (Sec. 6.2/6.4), normalised
  inner product and correlation (Eq. 3.11), registration by cross-correlation
  (Sec. 5.2) and the energy of a PSF near the sensor edge.
- :mod:`recon.analysis.sampling` -- depth grids uniform and in 1/z (Eq. 4.7,
  Eq. 5.10), depth sensitivity of a PSF under scaling (Sec. 3.2) and the lateral
  calibration spacing set by the sensor fall-off (Sec. 5.3, Eq. 5.9).
- :mod:`recon.analysis.angular` -- Gaussian fit of the pixel angular response
  (Fig. 5.3a) and the angular field of view (Eq. 3.12 / Eq. 4.6).
- :mod:`recon.analysis.resolution` -- autocorrelation and its 70 % half width
  (Sec. 3.2), the inner-product predictor for shifts and scales (Sec. 6.4),
  object-space resolution (m = d/z), hyperfocal distance and depth of field.
- :mod:`recon.analysis.similarity` -- PSF similarity across a stack (App. A.2,
  Fig. A.3).
- :mod:`recon.analysis.conditioning` -- local condition number of neighbouring
  point sources, laterally and across depth planes (Sec. 4.4, Fig. 4.5).
- :mod:`recon.analysis.distinguishability` -- two-point and 16-point
  distinguishability by reconstruction with the 20 % dip criterion (Sec. 4.4).
- :mod:`recon.analysis.grid` -- reconstruction-grid recommendation (Nyquist planes
  in 1/z and lateral binning, only over the depths a scene spans).
- :mod:`recon.analysis.activity` -- ΔF/F of a fluorescence video against a per-pixel
  percentile baseline (Fig. 6.5b).
- :mod:`recon.analysis.psf_from_scenes` -- the PSF per colour channel from known
  scenes and their measurements (non-negative least squares), with held-out residuals.
- :mod:`recon.analysis.reports` -- the numbers of ``diffuserlab analyze`` for a
  whole PSF stack (stack preparation, resolution per depth, lateral and axial
  conditioning, distinguishability, field of view per depth).

Bad input raises :class:`recon.errors.ReconInputError` naming the problem and the fix.
"""

from .activity import delta_f_over_f
from .angular import FalloffFit, fit_gaussian_falloff, fov_half_angle_deg
from .conditioning import (
    axial_layout,
    condition_vs_k,
    condition_vs_k_axial,
    local_condition_number,
    point_source_columns,
    stack_source_columns,
)
from .distinguishability import (
    TwoPointResult,
    dip_between,
    distinguishability_limit,
    points_resolved,
)
from .grid import GridRecommendation, recommend_grid
from .psf import (
    border_energy_fraction,
    inner_product,
    normalized_correlation,
    register_shift,
    remove_background_dct,
)
from .reports import (
    axial_condition,
    distinguishability,
    energy_kept,
    field_of_view,
    lateral_condition,
    prepare_stack,
    resolution_per_depth,
    support_width_px,
)
from .resolution import (
    LateralResolution,
    autocorrelation,
    axial_inner_product_scale,
    depth_of_field_mm,
    hyperfocal_distance_mm,
    lateral_inner_product_resolution_px,
    lateral_resolution_deg,
    lateral_resolution_object_mm,
    lateral_resolution_px,
)
from .sampling import (
    axial_step_eq510_per_mm,
    depth_sensitivity,
    inverse_depth_step_per_mm,
    inverse_depths,
    lateral_calibration_spacing_mm,
    scale_at_threshold,
    uniform_depths,
)
from .similarity import cross_correlation, inner_products_with, stack_similarity

__all__ = [
    "delta_f_over_f",
    "FalloffFit",
    "axial_step_eq510_per_mm",
    "border_energy_fraction",
    "depth_sensitivity",
    "fit_gaussian_falloff",
    "fov_half_angle_deg",
    "inner_product",
    "inverse_depth_step_per_mm",
    "inverse_depths",
    "lateral_calibration_spacing_mm",
    "normalized_correlation",
    "register_shift",
    "remove_background_dct",
    "scale_at_threshold",
    "uniform_depths",
    "GridRecommendation",
    "LateralResolution",
    "autocorrelation",
    "axial_inner_product_scale",
    "axial_layout",
    "condition_vs_k",
    "condition_vs_k_axial",
    "cross_correlation",
    "depth_of_field_mm",
    "hyperfocal_distance_mm",
    "inner_products_with",
    "lateral_inner_product_resolution_px",
    "lateral_resolution_deg",
    "lateral_resolution_object_mm",
    "lateral_resolution_px",
    "local_condition_number",
    "point_source_columns",
    "recommend_grid",
    "stack_source_columns",
    "stack_similarity",
    "TwoPointResult",
    "dip_between",
    "distinguishability_limit",
    "points_resolved",
    "axial_condition",
    "distinguishability",
    "energy_kept",
    "field_of_view",
    "lateral_condition",
    "prepare_stack",
    "resolution_per_depth",
    "support_width_px",
]
