"""What every child process shares (``diffuserlab.processes``): how its error crosses
to the parent. The bench, live and batch processes use the one function; none borrows
it from another's module (the import contract ``child-processes-share-diffuserlab``)."""

from __future__ import annotations

import pickle
import threading

from diffuserlab.errors import DiffuserLabError, InputError
from diffuserlab.processes import ChildProcessFailure, portable_error


class _Unpicklable(Exception):
    """Not the project's, and it holds a lock: pickling it fails."""

    def __init__(self, message):
        super().__init__(message)
        self.held = threading.Lock()


class _UnpicklableInput(InputError):
    def __init__(self, path, reason):
        super().__init__(f"{path}: {reason}")
        self.held = threading.Lock()


def _raised(exc):
    try:
        raise exc
    except BaseException as caught:  # noqa: BLE001
        return caught


def test_an_error_that_survives_pickling_stays_itself_with_the_childs_traceback():
    sent = portable_error(_raised(KeyError("a bug")), "the bench process")
    assert type(sent) is KeyError and sent.args == ("a bug",)
    assert sent.__notes__[0].startswith("in the bench process:\n")
    assert "KeyError" in sent.__notes__[0]
    pickle.loads(pickle.dumps(sent))


def test_an_error_that_cannot_be_pickled_keeps_its_message_and_nearest_kind():
    sent = portable_error(_raised(_Unpicklable("camera gone")), "the live process")
    assert type(sent) is ChildProcessFailure and str(sent) == "camera gone"
    assert isinstance(sent, DiffuserLabError) and isinstance(sent, RuntimeError)
    assert "_Unpicklable" in sent.__notes__[0]
    sent = portable_error(_raised(_UnpicklableInput("run.zarr", "damaged")), "x")
    assert type(sent) is InputError and str(sent) == "run.zarr: damaged"
    pickle.loads(pickle.dumps(sent))


def test_a_process_names_its_own_fallback():
    class Mine(ChildProcessFailure):
        pass

    sent = portable_error(_raised(_Unpicklable("")), "the batch process", Mine)
    assert type(sent) is Mine and str(sent) == "_Unpicklable"
