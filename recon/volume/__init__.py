"""3D DiffuserCam: volume reconstruction from one image (Kuo 2020, Ch. 4, App. A.1-A.3).

:class:`VolumeConvolutionOperator` is the forward model b = C sum_z h_z * v_z
(Eq. 4.4) with its adjoint; :func:`fista3d` solves the regularised inverse problem
(3D TV by Haar shifts, l1, non-negativity).
"""

from .admm import VolumeAdmmPlan, VolumeAdmmState, admm3d
from .api import DEFAULT_TV, reconstruct_stack
from .fista import fista3d, volume_tv
from .operator import (
    VolumeConvolutionOperator,
    bin_stack,
    estimate_memory_bytes,
    fft_floor_seconds,
    normalize_psf_stack,
)

__all__ = [
    "DEFAULT_TV",
    "VolumeConvolutionOperator",
    "VolumeAdmmPlan",
    "VolumeAdmmState",
    "admm3d",
    "bin_stack",
    "estimate_memory_bytes",
    "fista3d",
    "fft_floor_seconds",
    "normalize_psf_stack",
    "reconstruct_stack",
    "volume_tv",
]
