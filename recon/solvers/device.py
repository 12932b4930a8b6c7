"""Running a NumPy-path solve on another device: move the measurement there, check the
device's memory first, bring the estimate back.

:func:`device_solvers` is the 2D solver table (:data:`recon.solvers.SOLVERS`) with every
solver wrapped so (Wiener, GD, FISTA and ADMM all have a generic path);
:func:`recon.reconstruct` and :func:`recon.auto.solve_channel` use it for
``device="cuda"``.
"""

from __future__ import annotations

import inspect
import time
from dataclasses import replace

import numpy as np

from ..backend import Backend, check_memory, free_device_bytes, to_device, to_numpy

__all__ = ["GENERIC_2D", "check_device_memory", "device_metrics", "device_solvers",
           "fft_pair_seconds_on", "solve_on"]

#: The 2D methods with an array-API path (any other would run on the CPU).
GENERIC_2D = ("wiener", "gd", "fista", "admm")


def check_device_memory(backend: Backend, needed_bytes: int, what: str) -> None:
    """:func:`recon.backend.check_memory` against ``backend``'s free memory.

    Raises
    ------
    ReconInputError
        "<what> needs X GiB on <device>, Y GiB are free; ...".
    """
    check_memory(needed_bytes, free_device_bytes(backend), what=what, where=backend.label)


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
    check_device_memory(backend, needed_bytes, what)
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
    from .xp_wiener import memory_bytes as wiener_bytes

    solvers = SOLVERS if solvers is None else solvers
    if backend.is_numpy:
        return solvers

    def wrapped(name, spec):
        needs = wiener_bytes if name == "wiener" else memory_bytes  # FISTA / GD need less

        def run(op, b, **kwargs):
            return solve_on(backend, spec.solve, op, b, needed_bytes=needs(
                op.padded_shape), what=f"2D {name} at {op.sensor_shape[0]} x "
                f"{op.sensor_shape[1]}", **kwargs)

        run.__signature__ = inspect.signature(spec.solve)
        return replace(spec, solve=run)

    return {name: wrapped(name, spec) if name in GENERIC_2D else spec
            for name, spec in solvers.items()}



def fft_pair_seconds_on(backend: Backend, shape: tuple[int, int],
                        repeats: int | None = None, n_z: int = 0) -> float:
    """:func:`recon.fft.fft_pair_seconds` on ``backend``'s device: the median seconds of
    one float32 rfft2 + irfft2 pair at ``shape`` (with ``n_z``: a batched pair on
    ``n_z`` planes and one on a single plane, the ``n_z + 1`` pairs of a 3D
    iteration), each waited for (one element read back), after one warm-up (plans,
    kernels). The unit of a time budget (:func:`recon.auto.choice.choose_method`) and
    of the metrics' ratio to the FFT floor on that device.

    Parameters
    ----------
    backend : Backend
        A device; NumPy (2D only) gives :func:`recon.fft.fft_pair_seconds`.
    shape : (P0, P1)
        Padded shape.
    repeats : int, optional
        Timed repeats (default: 15 on the NumPy path, as
        :func:`recon.fft.fft_pair_seconds`; 7 on a device).
    n_z : int
        Planes of a volume (0: one 2D pair).

    Returns
    -------
    float
        Seconds per pair (per ``n_z + 1`` pairs with ``n_z``).
    """
    if backend.is_numpy:
        from ..fft import fft_pair_seconds

        return fft_pair_seconds(shape) if repeats is None else fft_pair_seconds(shape, repeats)
    xp = backend.xp
    repeats = 7 if repeats is None else repeats
    rng = np.random.default_rng(0)
    bufs = [to_device(rng.random((n, *shape) if n > 1 else shape, dtype=np.float32), backend)
            for n in ((n_z, 1) if n_z else (1,))]
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        for buf in bufs:
            out = xp.fft.irfftn(xp.fft.rfftn(buf, axes=(-2, -1)), s=shape, axes=(-2, -1))
            float(out[(0,) * out.ndim])  # wait for the device
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


def device_metrics(record, backend: Backend, n_z: int = 0):
    """A metrics record (:func:`recon.planar.image_metrics`,
    :func:`recon.volume.api.volume_metrics`) whose FFT floor, when not given, is
    measured on ``backend``'s device (:func:`fft_pair_seconds_on`): the ratio to the
    floor of the device the solve ran on.

    Returns
    -------
    callable
        ``record(rec, floor_s=None) -> dict``.
    """
    def metrics(rec, floor_s: float | None = None) -> dict:
        if floor_s is None:
            floor_s = fft_pair_seconds_on(backend, rec.operator.padded_shape, n_z=n_z)
        return record(rec, floor_s)

    return metrics
