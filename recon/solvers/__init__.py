"""Solvers for the lensless inverse problem: Wiener preview, GD, FISTA, ADMM.

Each takes a forward-model operator and a measurement and returns a
:class:`~recon.solvers.common.SolveResult` (estimate + history).
"""

from .admm import admm
from .common import History, SolveResult
from .gradient import fista, gradient_descent
from .wiener import wiener

METHODS = ("wiener", "gd", "fista", "admm")

__all__ = ["METHODS", "History", "SolveResult", "admm", "fista", "gradient_descent", "wiener"]
