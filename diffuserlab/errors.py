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

__all__ = ["DiffuserLabError", "InputError", "kept_error"]


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


def kept_error(exc: BaseException) -> BaseException:
    """``exc`` made safe to keep after its handler (a worker thread's error stored for
    another thread to report): its traceback, and those of the exceptions it chains
    (``__cause__``, ``__context__``), are dropped.

    A traceback holds the frames it passed through, their local variables and so,
    most often, the object that stores the exception: a reference cycle that only the
    garbage collector frees, and never once the object was frozen
    (``gui.workers.settle_heap``). In the operator's day a stopped live
    reconstruction kept its solver's arrays (38 MiB at a 19-minute day's end) that way.
    The type and the message stay; log the traceback before, where it is wanted.

    Parameters
    ----------
    exc : BaseException
        The exception caught.

    Returns
    -------
    BaseException
        The same object, without tracebacks.
    """
    seen: set[int] = set()
    todo = [exc]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        e.__traceback__ = None
        todo += [e.__cause__, e.__context__]
    return exc
