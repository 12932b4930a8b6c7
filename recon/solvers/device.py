"""Running a NumPy-path solve on another device: move the measurement there, check the
device's memory first, bring the estimate back.

:func:`device_solvers` is the 2D solver table (:data:`recon.solvers.SOLVERS`) with each
generic solver wrapped so; :func:`recon.reconstruct` and :func:`recon.auto.solve_channel`
use it for ``device="cuda"``. Wiener (one FFT pair) stays on the CPU.
"""

from __future__ import annotations

import inspect
from dataclasses import replace

from ..backend import Backend, check_memory, free_device_bytes, to_device, to_numpy

__all__ = ["GENERIC_2D", "device_solvers", "solve_on"]

#: The 2D methods with an array-API path (the others run on the CPU).
GENERIC_2D = ("gd", "fista", "admm")


def solve_on(backend: Backend, solve, op, b, *, needed_bytes: int, what: str, **kwargs):
    """``solve(op, b_on_device, **kwargs)`` with ``x`` returned as a NumPy array.

    Parameters
    ----------
    backend : Backend
        Where to run (not NumPy).
    solve : callable
        A solver of the NumPy path that dispatches on its measurement's type.
    op : operator
    b : ndarray
        The measurement on the host.
    needed_bytes : int
        Estimated device memory of the solve (checked before anything is moved).
    what : str
        The solve, for the memory message.

    Returns
    -------
    SolveResult
        With ``x`` on the host.

    Raises
    ------
    ReconInputError
        The solve does not fit in the device's free memory (says how much it needs).
    """
    check_memory(needed_bytes, free_device_bytes(backend), what=what, where=backend.label)
    result = solve(op, to_device(b, backend), **kwargs)
    result.x = to_numpy(result.x)
    result.params["device"] = backend.label
    return result


def device_solvers(backend: Backend, solvers=None) -> dict:
    """The 2D solver table with the generic solvers run on ``backend``.

    Parameters
    ----------
    backend : Backend
    solvers : dict, optional
        Default :data:`recon.solvers.SOLVERS`.

    Returns
    -------
    dict
        Same keys and :class:`~recon.solvers.SolverSpec` values; those of
        :data:`GENERIC_2D` solve on ``backend`` (NumPy backend: the table unchanged).
    """
    from . import SOLVERS
    from .xp_admm import memory_bytes

    solvers = SOLVERS if solvers is None else solvers
    if backend.is_numpy:
        return solvers

    def wrapped(name, spec):
        def run(op, b, **kwargs):
            return solve_on(backend, spec.solve, op, b, needed_bytes=memory_bytes(
                op.padded_shape), what=f"2D {name} at {op.sensor_shape[0]} x "
                f"{op.sensor_shape[1]}", **kwargs)

        run.__signature__ = inspect.signature(spec.solve)
        return replace(spec, solve=run)

    return {name: wrapped(name, spec) if name in GENERIC_2D else spec
            for name, spec in solvers.items()}

