"""Étendue-expanded holograms through a random scattering mask (Kuo 2020, Ch. 7, App. A.4).

Hologram *computation* (layer 1, numerics only). The physical bench model with
relay, camera mapping and laser drift is :mod:`recon.optics.holo_display`; this
package reuses its random binary mask so that both agree for the same seed.

Model (:class:`ScatteringDisplay`, Eq. 7.8, 7.15, 7.20-7.22): a phase-only SLM
pattern ``s`` (``N_y x N_x``, pitch ``Delta``) is box-upsampled by ``k`` onto the
mask grid, multiplied by the random binary 0/pi mask ``m`` (pitch
``Delta_m = Delta / k``; expansion ``q = k^2``, Eq. 7.10) and optionally by a
Fresnel defocus per image plane, and Fourier-transformed to the image plane;
the viewer sees ``I = |y|^2``. ``forward``/``adjoint`` are exact adjoints.

Modules
-------
scattering_display
    :class:`ScatteringDisplay` (operator; ``no_mask`` for the native étendue),
    :func:`random_binary_mask`, :func:`field_from_phase`.
etendue
    Étendue, FoV and eyebox calculator (Eq. 7.1-7.6, 7.10).
losses
    :class:`IntensityLoss` (L2 Eq. 7.16; frequency Eq. 7.17-7.18; spatial Eq. 7.19;
    summed over planes Eq. 7.23), :func:`butterworth_lowpass`,
    :func:`passband_count`, :func:`foveation_map`.
optimize
    :func:`optimize_hologram` (projected gradient with Nesterov acceleration and
    backtracking, Algorithm 1 / App. A.4; phase-only or complex SLM) and
    :func:`loss_and_gradient` (the Wirtinger gradient of Eq. A.7-A.9);
    :func:`no_mask_hologram` (the same optimiser on the bare SLM, for reference).
    ``device="cpu"|"cuda"|"auto"`` picks the NumPy path or the generic one.
iteration, xp_optimize, xp_display
    The optimiser's loop shared by both paths; the generic loss, gradient and display
    model on any array-API backend (PyTorch, CuPy; a GPU), imported only when used.
baselines
    :func:`one_step_hologram` (Eq. 7.11-7.13).
protocol, evaluation, evaluate
    The pre-registered Table 7.1 protocol, its runner and acceptance rules, and
    what ``diffuserlab holo evaluate`` writes (``evaluate.run_evaluation``).
benchmark
    Full-size speed benchmark (``diffuserlab holo benchmark``).

Speed (docs/protocols.md, "Hologram speed budget"): complex64/float32 throughout,
``scipy.fft`` with all workers and in-place complex FFTs, the upsampling and the
mask fused into one numba pass (no exponential or upsampled copy on the full grid),
buffers allocated once, the field at the momentum point obtained by linearity.
FFTs per iteration (complex equivalents): L2 2, frequency 3.5, spatial 5, times
the number of planes.
"""

from __future__ import annotations

from .baselines import one_step_hologram, random_phase_field
from .etendue import (
    etendue_mm2,
    expansion_factor,
    eyebox_for_fov,
    fov_eyebox,
    fov_for_eyebox,
    max_diffraction_angle_deg,
    pixels_for,
    slm_etendue_mm2,
)
from .hologram import HologramResult, project
from .losses import (
    IntensityLoss,
    butterworth_lowpass,
    cutoff_radius,
    foveation_map,
    lowpass,
    passband_count,
)
from .optimize import loss_and_gradient, no_mask_hologram, optimize_hologram
from .scattering_display import ScatteringDisplay, field_from_phase, random_binary_mask

__all__ = [
    "HologramResult",
    "IntensityLoss",
    "ScatteringDisplay",
    "butterworth_lowpass",
    "cutoff_radius",
    "etendue_mm2",
    "expansion_factor",
    "eyebox_for_fov",
    "field_from_phase",
    "fov_eyebox",
    "fov_for_eyebox",
    "foveation_map",
    "loss_and_gradient",
    "lowpass",
    "max_diffraction_angle_deg",
    "no_mask_hologram",
    "one_step_hologram",
    "optimize_hologram",
    "passband_count",
    "pixels_for",
    "project",
    "random_binary_mask",
    "random_phase_field",
    "slm_etendue_mm2",
]
