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

Bad input raises :class:`recon.errors.ReconInputError` naming the problem and the fix.
"""

from .angular import FalloffFit, fit_gaussian_falloff, fov_half_angle_deg
from .psf import (
    border_energy_fraction,
    inner_product,
    normalized_correlation,
    register_shift,
    remove_background_dct,
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

__all__ = [
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
]
