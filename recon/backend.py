"""Array backends and devices: where a reconstruction runs (NumPy on the CPU, CuPy or
PyTorch on a CUDA GPU) and the checks before it does.

The numerics that matter for speed have two implementations behind one entry: the
NumPy one (numba kernels, :mod:`recon.solvers`, :mod:`recon.volume`) and a generic one
written against the Python array API standard (``xp_*`` modules: ``recon.xp_operators``,
``recon.solvers.xp_admm``, ``recon.solvers.xp_fista``,
``recon.volume.xp_admm3d``; through
``array-api-compat``), which runs on any conforming array: CuPy and PyTorch (CPU or
CUDA) arrays, or ``array-api-strict`` in the tests. The solvers dispatch on the type of
the measurement they are given: a ``numpy.ndarray`` takes the NumPy path unchanged,
anything else the generic path, on that array's device.

This module imports neither CuPy, PyTorch nor ``array_api_compat`` until a device
other than the CPU is asked for (``diffuserlab --help`` and a CPU reconstruction load
none of them).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, replace

import numpy as np

from .errors import ReconInputError
from .options import DEVICES, ReconOptions

__all__ = ["DEVICES", "NUMPY", "Backend", "GPU_INSTALL", "array_namespace", "check_memory",
           "device_of", "free_device_bytes", "is_numpy", "resolve_device", "to_device", "to_numpy",
           "torch_cpu", "total"]

#: How to install a GPU backend (the message of an unusable ``cuda`` request).
GPU_INSTALL = "pip install 'diffuserlab[gpu]'"


@dataclass(frozen=True)
class Backend:
    """One array library on one device.

    Attributes
    ----------
    name : str
        ``"numpy"``, ``"cupy"``, ``"torch"`` (or ``"array-api-strict"`` in tests).
    xp : module
        The array-API namespace (``array_api_compat``'s wrapper for CuPy and
        PyTorch); :mod:`numpy` for the NumPy path.
    device : object
        The library's device (``"cpu"``, a ``torch.device``, a CuPy device), or None.
    label : str
        Human-readable, e.g. ``"cuda:0 (torch)"``, for messages and benchmarks.
    note : str
        Why ``auto`` runs on the CPU although a GPU library is installed (it cannot
        be imported, or sees no device); empty otherwise.
    """

    name: str
    xp: object
    device: object
    label: str
    note: str = ""

    @property
    def is_numpy(self) -> bool:
        """True for the NumPy (numba) path."""
        return self.name == "numpy"


#: The CPU backend: NumPy arrays and the numba kernels (``device="cpu"``, and
#: ``"auto"`` without a usable GPU).
#:
#: :meta hide-value:
NUMPY = Backend("numpy", np, "cpu", "cpu (numpy)")


def is_numpy(a) -> bool:
    """Whether ``a`` takes the NumPy path (a ``numpy.ndarray``)."""
    return isinstance(a, np.ndarray)


def array_namespace(*arrays):
    """The array-API namespace of ``arrays`` (``array_api_compat.array_namespace``)."""
    import array_api_compat

    return array_api_compat.array_namespace(*arrays)


def _import(*names: str) -> tuple:
    """The modules ``names``; a library that is installed but fails to import (a CuPy
    built for another CUDA, a missing shared library) is a ReconInputError naming it.
    """
    import importlib

    modules = []
    for name in names:
        try:
            modules.append(importlib.import_module(name))
        except Exception as exc:  # ImportError, OSError, RuntimeError of a broken build
            lib = name.split(".")[-1]
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise ReconInputError(
                f"cuda requested but {lib} is installed and cannot be imported ({text}); "
                f"reinstall it for this machine's CUDA ({GPU_INSTALL}), remove it, or use "
                "--device cpu") from exc
    return tuple(modules)


def _cupy_backend():
    """CuPy on CUDA device 0, or None when CuPy is absent; raises when it is there
    but sees no device."""
    if importlib.util.find_spec("cupy") is None:
        return None
    cupy, xp = _import("cupy", "array_api_compat.cupy")
    try:
        count = cupy.cuda.runtime.getDeviceCount()
    except Exception as exc:  # CUDA driver or runtime missing: CuPy raises its own types
        raise ReconInputError(f"cuda requested but no CUDA device visible (CuPy: {exc}); "
                              "check the driver with nvidia-smi, or use --device cpu") from exc
    if count < 1:
        raise ReconInputError("cuda requested but no CUDA device visible (CuPy sees 0 "
                              "devices); check the driver with nvidia-smi, or use --device cpu")
    return Backend("cupy", xp, cupy.cuda.Device(0), "cuda:0 (cupy)")


def _torch_backend():
    """PyTorch on cuda:0, or None when PyTorch is absent or built without CUDA; raises
    when it is built with CUDA but sees no device."""
    if importlib.util.find_spec("torch") is None:
        return None
    (torch,) = _import("torch")
    if torch.version.cuda is None:
        return None
    if not torch.cuda.is_available():
        raise ReconInputError("cuda requested but no CUDA device visible (PyTorch "
                              f"{torch.__version__} sees none); check the driver with "
                              "nvidia-smi, or use --device cpu")
    _, xp = _import("torch", "array_api_compat.torch")

    return Backend("torch", xp, torch.device("cuda:0"), "cuda:0 (torch)")


def resolve_device(device: str = ReconOptions.defaults()["device"]) -> Backend:
    """The backend of a ``--device`` / ``device=`` value.

    Parameters
    ----------
    device : {"cpu", "cuda", "auto"}
        ``cpu``: NumPy (numba kernels). ``cuda``: CuPy on GPU 0 when installed, else
        PyTorch built with CUDA. ``auto``: ``cuda`` when usable, else ``cpu``.

    Returns
    -------
    Backend

    Raises
    ------
    ReconInputError
        An unknown name; ``cuda`` without CuPy or a CUDA PyTorch (names the install
        command), with one that fails to import (names it), or with them but no
        visible device. ``auto`` never raises for these: it returns the CPU backend
        with the reason in its ``note``.
    """
    name = str(device).strip().lower()
    if name not in DEVICES:
        raise ReconInputError(f"device {device!r} is not one of {', '.join(DEVICES)}")
    if name == "cpu":
        return NUMPY
    errors = []
    for probe in (_cupy_backend, _torch_backend):
        try:
            backend = probe()
        except ReconInputError as exc:
            errors.append(exc)
            continue
        if backend is not None:
            return backend
    if name == "auto":
        if errors:  # installed but unusable: the CPU, and why
            return replace(NUMPY, note="no usable GPU, running on the CPU: "
                           + str(errors[0]).removeprefix("cuda requested but "))
        return NUMPY
    if errors:
        raise errors[0]
    raise ReconInputError("cuda requested but CuPy/PyTorch with CUDA is not installed: "
                          f"{GPU_INSTALL}")


def torch_cpu() -> Backend | None:
    """PyTorch on the CPU through the generic path (benchmarks, tests), or None."""
    if importlib.util.find_spec("torch") is None:
        return None
    import array_api_compat.torch as xp
    import torch

    return Backend("torch", xp, torch.device("cpu"), "cpu (torch, generic path)")


def device_of(a):
    """The device of array ``a`` (``array_api_compat.device``)."""
    import array_api_compat

    return array_api_compat.device(a)


def total(xp, a) -> float:
    """``sum(a)`` as a Python float (one device-to-host transfer on a GPU)."""
    return float(xp.sum(a))


def to_device(a, backend: Backend):
    """``a`` (array-like) as an array of ``backend`` on its device (float dtypes kept)."""
    if backend.is_numpy:
        return to_numpy(a)
    return backend.xp.asarray(np.asarray(a) if is_numpy(a) else a, device=backend.device)


def to_numpy(a) -> np.ndarray:
    """A NumPy copy (or view) of any backend's array, moved to the host."""
    if is_numpy(a):
        return a
    import array_api_compat

    if array_api_compat.is_torch_array(a):
        return a.detach().cpu().numpy()
    if array_api_compat.is_cupy_array(a):
        return a.get()
    return np.from_dlpack(a)  # any other array-API array on the CPU (DLPack)


def free_device_bytes(backend: Backend) -> int | None:
    """Free memory of the backend's GPU in bytes, or None (CPU: not checked here)."""
    if backend.name == "cupy":
        import cupy

        with backend.device:
            free, _total = cupy.cuda.runtime.memGetInfo()
        # memory CuPy's pool holds but does not use is free for our arrays
        return int(free + cupy.get_default_memory_pool().free_bytes())
    if backend.name == "torch" and backend.device.type == "cuda":
        import torch

        free, _total = torch.cuda.mem_get_info(backend.device)
        return int(free + torch.cuda.memory_reserved(backend.device)
                   - torch.cuda.memory_allocated(backend.device))
    return None


def check_memory(needed_bytes: int, free_bytes: int | None, *, what: str,
                 where: str = "the GPU",
                 fix: str = "bin the data (--bin), use fewer depth planes") -> None:
    """Refuse a solve that does not fit before it starts.

    Parameters
    ----------
    needed_bytes : int
        Estimated peak of the solve's arrays on the device.
    free_bytes : int or None
        Free device memory (:func:`free_device_bytes`); None skips the check.
    what, where : str
        The solve and the device, for the message.
    fix : str
        What makes the problem smaller, for the message (before "free the GPU, or use
        --device cpu").

    Raises
    ------
    ReconInputError
        "<what> needs X GiB on <where>, Y GiB are free; ...".
    """
    if free_bytes is None or needed_bytes <= free_bytes:
        return
    gib = 2.0**30
    raise ReconInputError(
        f"{what} needs {needed_bytes / gib:.2f} GiB on {where}, {free_bytes / gib:.2f} GiB "
        f"are free; {fix}, free the GPU, or use the CPU (device cpu)")
