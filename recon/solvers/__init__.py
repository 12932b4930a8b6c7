"""Solvers for the lensless inverse problem: Wiener preview, GD, FISTA, ADMM.

Each takes a forward-model operator and a measurement and returns a
:class:`~recon.solvers.common.SolveResult` (estimate + history).

:data:`SOLVERS` is the one table of 2D solvers: :func:`recon.reconstruct`, the
``recon`` command's ``--method`` choices and the benchmarks read it, so a new
solver is one module here and one entry there (docs/architecture.md, "a solver").

One convention for every iterative solver, 2D, 3D and spatially varying
(:func:`fista`, :func:`gradient_descent`, :func:`admm`, :func:`recon.volume.fista3d`,
:func:`recon.volume.admm3d`, :func:`recon.spatial.spatial_admm`,
:func:`recon.spatial.fista_background`): keywords ``iterations`` (the most allowed,
default 100), ``tv`` and ``l1`` (absolute weights in the
scaled problem, default 0: a solver solves the problem it is given and adds no term
unless asked; choosing a weight is :func:`recon.reconstruct`'s job, ``"auto"`` by
default, with the tested fixed weights in :data:`recon.api.DEFAULT_TV` and
:data:`recon.volume.DEFAULT_TV`), ``stop`` where the solver stops early; and
``params`` holding ``iterations`` (the maximum) and ``iterations_used`` (how many ran).
"""

from collections.abc import Callable
from dataclasses import dataclass

from .admm import admm
from .common import History, SolveResult
from .gradient import fista, gradient_descent
from .penalty import AdmmPenalty
from .wiener import wiener


@dataclass(frozen=True)
class SolverSpec:
    """One solver as the API, the command line and the benchmarks see it.

    Attributes
    ----------
    solve : callable
        ``solve(op, b, *, iterations, tv, **options) -> SolveResult`` for an
        iterative solver; ``solve(op, b, **options)`` for a direct one.
    default_tv : float
        Default TV weight, absolute in the scaled problem (unit-sum PSF,
        measurement divided by its maximum); 0 for a solver without TV.
    iterative : bool
        Whether it takes ``iterations`` and ``tv`` (a direct solver such as Wiener
        takes neither and reports one iteration).
    summary : str
        One line for help texts.
    """

    solve: Callable[..., SolveResult]
    default_tv: float
    iterative: bool
    summary: str


#: The 2D solvers by method name. Default TV weights: chosen on simulated scenes with
#: the real PSF (``diffuserlab benchmark recon``: 3e-4 to 1e-3 score best there) and by
#: eye on the real hand (3e-4 keeps the fingers).
SOLVERS: dict[str, SolverSpec] = {
    "wiener": SolverSpec(wiener, 0.0, False, "Wiener / Tikhonov preview, one FFT pair"),
    "gd": SolverSpec(gradient_descent, 3e-4, True, "gradient descent with Nesterov momentum"),
    "fista": SolverSpec(fista, 3e-4, True, "FISTA with TV and non-negativity (Alg. 1)"),
    "admm": SolverSpec(admm, 3e-4, True,
                       "ADMM with crop, TV and non-negativity splits (Eq. 4.5 in 2D)"),
}

#: Method names, in :data:`SOLVERS` order.
METHODS = tuple(SOLVERS)

__all__ = ["METHODS", "SOLVERS", "AdmmPenalty", "History", "SolveResult", "SolverSpec", "admm",
           "fista", "gradient_descent", "wiener"]
