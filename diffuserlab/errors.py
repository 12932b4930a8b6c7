"""The project's error contract.

Every exception DiffuserLab raises on purpose derives from :class:`DiffuserLabError`;
a problem with what the user gave (a file, a value, an option, an output path that
exists) is an :class:`InputError`, which every command reports as one line naming
the problem and the fix, with exit status 2. Anything else that escapes a command is
a bug (a traceback, exit status 1), never disguised as bad input.

Hierarchy (the layers' own types derive from these)::

    DiffuserLabError
    +-- InputError (also ValueError)          exit 2: the message names the fix
    |   +-- recon.errors.ReconInputError      data or parameters of a reconstruction
    |   +-- instrument: BenchConfigError, PlanError, RunStoreError, OutputError
    +-- recon.errors.DivergenceError          a solver diverged (also RuntimeError)
    +-- drivers.errors.DeviceError            a device failed or refused (see there)
    +-- instrument: BenchOpenError, RegistryError, LiveReconstructionError, ...
"""

from __future__ import annotations

__all__ = ["DiffuserLabError", "InputError"]


class DiffuserLabError(Exception):
    """Root of every exception DiffuserLab raises on purpose.

    Catch it to tell the project's own, described failures from bugs.
    """


class InputError(DiffuserLabError, ValueError):
    """Input the user can fix: a file, a value, an option or an output path.

    The message names the problem and the fix; the command line prints it as one
    line and exits with status 2. Also a :class:`ValueError`, so code that validates
    arguments the standard way catches it.
    """
