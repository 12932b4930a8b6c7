"""Spatially varying models (Kuo 2020, Ch. 5) and the microscope's solver (Sec. 6.2).

- :mod:`recon.spatial.grid` -- registered PSF grids (Eq. 5.2), their bilinear
  weights (Eq. 5.3) and PSF grids synthesised at new depths.
- :mod:`recon.spatial.operator` -- the local convolution model (Eq. 5.4-5.5) and
  the low-rank PCA model (Eq. 5.6-5.7) as forward-model operators with adjoints,
  2D and 3D.
- :mod:`recon.spatial.choice` -- which model a grid needs (convolution, PCA with
  the smallest k, local) from predicted model errors and, optionally, measured
  reconstruction PSNR.
- :mod:`recon.spatial.blind` -- compressive calibration by blind deconvolution
  (Sec. 5.4, Eq. 5.11-5.13).
- :mod:`recon.spatial.resolution` -- two-point resolution across the field
  (Sec. 6.4, Fig. 6.4a).
- :mod:`recon.spatial.admm` -- ADMM for these models, its x-update linearized and
  preconditioned by the convolution that bounds the model.
- :mod:`recon.spatial.background` -- FISTA jointly over the object and a smooth
  background restricted to the lowest DCT coefficients (Eq. 6.2).
- :mod:`recon.spatial.brightness` -- the field's relative brightness from a grid
  (the two-part model's brightness term, Eq. 5.1), the correction of a
  reconstruction made with the on-axis PSF, and the caustic factor (each PSF over
  its brightness) that a far scene's spatially varying model interpolates.
"""

from .admm import SpatialAdmmPlan, spatial_admm
from .background import dct_basis, fista_background, lowpass_background
from .blind import BlindCalibration, blind_calibration
from .brightness import brightness_map, caustic_grid, correct_brightness, node_brightness
from .choice import MODELS, ModelChoice, build_operator, choose_model, predicted_errors
from .grid import PsfGrid, register_psfs, scale_psf, synthesize_grid
from .operator import (
    SpatialConvolutionOperator,
    local_convolution_operator,
    pca_components,
    pca_operator,
    spatial_memory_bytes,
)
from .resolution import ray_traced_pair, two_point_resolution

__all__ = [
    "BlindCalibration",
    "blind_calibration",
    "brightness_map",
    "caustic_grid",
    "correct_brightness",
    "node_brightness",
    "MODELS",
    "ModelChoice",
    "build_operator",
    "choose_model",
    "predicted_errors",
    "PsfGrid",
    "SpatialAdmmPlan",
    "SpatialConvolutionOperator",
    "dct_basis",
    "fista_background",
    "local_convolution_operator",
    "lowpass_background",
    "pca_components",
    "pca_operator",
    "ray_traced_pair",
    "register_psfs",
    "scale_psf",
    "spatial_admm",
    "spatial_memory_bytes",
    "synthesize_grid",
    "two_point_resolution",
]
