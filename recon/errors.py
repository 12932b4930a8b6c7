"""Exceptions raised by the reconstruction layer.

Every message names the problem and the fix, so the CLI can print it as a
one-line reason and exit with status 2.
"""

from __future__ import annotations

from diffuserlab.errors import DiffuserLabError, InputError


class ReconInputError(InputError):
    """Input data or parameters that cannot be reconstructed as given.

    Raised for unreadable files, shape mismatches, NaN/inf values, an all-zero or
    negative-only PSF, and invalid solver parameters. The message says what is
    wrong and how to fix it. An :class:`diffuserlab.errors.InputError` (and so a
    ValueError): the command line reports it with exit status 2.
    """


class DivergenceError(DiffuserLabError, RuntimeError):
    """An iterative solver diverged (objective rising without bound, or NaN/inf).

    Parameters
    ----------
    message : str
        What happened and what to try instead.
    history : dict, optional
        The solver history up to the failing iteration.
    last_good : numpy.ndarray, optional
        The last finite estimate before divergence, so nothing computed is lost.
    """

    def __init__(self, message: str, history: dict | None = None, last_good=None):
        super().__init__(message)
        self.history = history
        self.last_good = last_good
