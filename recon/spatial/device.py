"""Running the PSF grid's solvers on another device: the memory check with the bytes
a spatially varying model needs, the measurement moved there, the results brought back.

:func:`solve_grid_on` runs one solve (:func:`recon.spatial.fista_background` or
:func:`recon.spatial.spatial_admm`, which dispatch on their measurement's type);
:func:`device_grid_solvers` is :data:`recon.spatial.api.GRID_SOLVERS` with ADMM so
wrapped, for :func:`recon.auto.solve_channel` (whose automatic weight path runs on the
CPU). :func:`recon.spatial.api.reconstruct_psf_grid` uses both for ``device="cuda"``.
"""

from __future__ import annotations

import inspect
from dataclasses import replace

from ..backend import Backend, to_numpy
from ..solvers.device import solve_on
from .xp_operator import device_memory_bytes

__all__ = ["ADMM_PLANES", "BACKGROUND_PLANES", "device_grid_solvers", "solve_grid_on"]

#: Padded float32 planes the generic ADMM holds besides the operator: x, M x, five
#: q's, four stored duals, the split pass's and the x-update's temporaries
#: (:func:`recon.solvers.xp_admm.memory_bytes` counts 24 and 6 half-spectra).
ADMM_PLANES = 30
#: Object-sized float32 arrays the generic joint FISTA holds besides the operator (per
#: object plane): the joint x, y and y_next, the gradient, the prox's temporaries and
#: a snapshot.
BACKGROUND_PLANES = 10


def solve_grid_on(backend: Backend, solve, op, b, *, planes: int, method: str, **kwargs):
    """``solve(op, b_on_device, **kwargs)`` after the device's memory check; ``x`` and
    the background returned as NumPy arrays.

    Parameters
    ----------
    backend : Backend
        Not NumPy.
    solve : callable
        :func:`recon.spatial.fista_background` or :func:`recon.spatial.spatial_admm`.
    op : SpatialConvolutionOperator
    b : ndarray, float32, ``op.shape_out``
        The scaled measurement on the host.
    planes : int
        Object-sized arrays the solver holds (per object plane).
    method : str
        The solver, for the memory message.
    **kwargs
        The solver's.

    Returns
    -------
    SolveResult
        ``x``, ``params["background"]`` and ``params["background_dct"]`` (when there)
        on the host; ``params["device"]`` the backend's label.

    Raises
    ------
    ReconInputError
        The solve does not fit in the device's free memory ("... needs X GiB on
        <device>, Y GiB are free ..."), or the solver's own errors.
    """
    rows, cols = op.sensor_shape
    depth = f"{op.n_z} planes of " if op.volume else ""
    result = solve_on(backend, solve, op, b,
                      needed_bytes=device_memory_bytes(op, planes=planes * op.n_z),
                      what=f"{method} of the {getattr(op, 'model', 'spatially varying')} "
                           f"model ({op.n_kernels} kernels) on {depth}{rows} x {cols}",
                      **kwargs)
    for key in ("background", "background_dct"):
        if key in result.params:
            result.params[key] = to_numpy(result.params[key])
    return result


def device_grid_solvers(backend: Backend, solvers: dict) -> dict:
    """The grid's solver table with ADMM run on ``backend``.

    Parameters
    ----------
    backend : Backend
    solvers : dict
        :data:`recon.spatial.api.GRID_SOLVERS`.

    Returns
    -------
    dict
        Same keys; ``"admm"`` solves on ``backend`` through :func:`solve_grid_on`, the
        others as given (on the CPU). NumPy backend: ``solvers`` unchanged.
    """
    if backend.is_numpy:
        return solvers
    spec = solvers["admm"]

    def run(op, b, **kwargs):
        return solve_grid_on(backend, spec.solve, op, b, planes=ADMM_PLANES, method="ADMM",
                             **kwargs)

    run.__signature__ = inspect.signature(spec.solve)
    return {**solvers, "admm": replace(spec, solve=run)}
