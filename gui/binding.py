"""Is the installed Qt binding safe to run the GUI? (reference leaks of None and bools)

Two leaks were found in released PySide6 versions on Python 3.11:

PySide6 6.12.0 on Python 3.11 releases one reference to ``None`` on every Qt call
that returns nothing (2000 ``QLabel.setText`` calls move ``sys.getrefcount(None)`` by
-2000) and one to ``True``/``False`` on every ``Signal(bool).emit``. A streaming GUI
makes hundreds of such calls a second, so the count reaches zero within minutes and
the interpreter aborts (``Fatal Python error: none_dealloc``). Python 3.12 made
``None``, ``True`` and ``False`` immortal, which hides the bug there. The ``gui``
extra excludes the leaking versions (pyproject.toml); :func:`check_binding` refuses
to start the GUI on one that slipped through, and ``tests/gui/test_binding.py`` runs
:func:`reference_drift` against the installed binding.

Only PySide6 is imported here (no pyqtgraph, nothing of ours), so the check runs in
any interpreter that has the binding, e.g. a throwaway environment holding the
version under suspicion.

PySide6 6.10 and 6.11 (6.9.3 does not) keep one reference to ``None`` for every signal
connection still in place when its QObject is destroyed. pyqtgraph connects signals
in its items and makes and drops items all the time (a colormap change replaces 256
gradient ticks; a streaming view, an ROI or a profile plot do it every second): the
operator's day drifted by thousands of references a minute. The count only grows, so
the interpreter does not abort, but the drift hides any other leak; the ``gui`` extra
excludes those versions and :func:`reference_drift` measures it (``"destroyed"``).
"""

from __future__ import annotations

import gc
import sys

from diffuserlab.errors import DiffuserLabError

__all__ = ["BindingLeakError", "LEAK_LIMIT", "check_binding", "reference_drift"]

#: Largest change of a reference count over the calls :func:`reference_drift` makes
#: that is not a leak (the interpreter's own bookkeeping moves it by a few).
LEAK_LIMIT = 50


class BindingLeakError(DiffuserLabError, RuntimeError):
    """The installed Qt binding releases references it does not own."""


def reference_drift(calls: int = 2000, *, emit_bools: bool = True) -> dict[str, int]:
    """Change of ``sys.getrefcount`` of ``None`` and ``True`` over ``calls`` Qt calls, and
    of ``None`` over ``calls`` QObjects destroyed with a signal connected.

    Parameters
    ----------
    calls : int
        ``QLabel.setText`` calls (each returns None), and as many
        ``Signal(bool).emit(True)`` calls with ``emit_bools``.
    emit_bools : bool
        Also emit ``True``. On a leaking binding this can abort the interpreter
        (``bool_dealloc``) when ``True``'s count reaches zero: run it in a
        subprocess (the test does).

    Returns
    -------
    dict
        ``{"none": drift, "true": drift, "destroyed": drift, "calls": calls,
        "binding": version, "python": version}``; drifts are ``after - before`` (0 or
        a few on a sound binding, about ``-calls`` (none, true) or ``+calls``
        (destroyed) on a leaking one, always 0 where the objects are immortal).
    """
    import PySide6
    from PySide6.QtCore import QObject, Signal
    from PySide6.QtWidgets import QApplication, QLabel

    app = QApplication.instance() or QApplication(["binding-check"])

    class _Emitter(QObject):
        flag = Signal(bool)

        def handler(self) -> None:
            pass

    def connected_and_dropped() -> None:
        emitter = _Emitter()
        emitter.flag.connect(emitter.handler)  # still connected when it is destroyed

    label = QLabel()
    emitter = _Emitter()
    received: list[bool] = []
    emitter.flag.connect(received.append)
    none0 = sys.getrefcount(None)
    for _ in range(calls):
        label.setText("x")
    none1 = sys.getrefcount(None)
    true0 = sys.getrefcount(True)
    if emit_bools:
        for _ in range(calls):
            emitter.flag.emit(True)
    true1 = sys.getrefcount(True) - len(received)  # the list holds one per emit
    del received[:]
    connected_and_dropped()
    gc.collect()
    dropped0 = sys.getrefcount(None)
    for _ in range(calls):
        connected_and_dropped()
    gc.collect()
    dropped1 = sys.getrefcount(None)
    label.deleteLater()
    app.processEvents()
    return {"none": none1 - none0, "true": true1 - true0, "destroyed": dropped1 - dropped0,
            "calls": int(calls), "binding": PySide6.__version__,
            "python": sys.version.split()[0]}


def check_binding(calls: int = 400) -> None:
    """Refuse a Qt binding that leaks references to None (seconds of GUI use would end
    in ``Fatal Python error: none_dealloc``).

    Measures ``setText`` only (no bool emits, which could abort at once); costs a few
    milliseconds.

    Raises
    ------
    BindingLeakError
        The drift exceeds :data:`LEAK_LIMIT`; the message names the installed version
        and the fix.
    """
    drift = reference_drift(calls, emit_bools=False)
    if abs(drift["none"]) > LEAK_LIMIT:
        raise BindingLeakError(
            f"the installed PySide6 {drift['binding']} loses a reference to None on every "
            f"Qt call ({drift['none']:+d} over {calls} calls on Python {drift['python']}): "
            "the GUI would abort within minutes with 'Fatal Python error: none_dealloc'. "
            "Install the versions the gui extra allows: pip install -e '.[gui]' (or pip "
            "install 'PySide6-Essentials<6.10')")


if __name__ == "__main__":  # python -m gui.binding: print the drifts (the test runs this)
    import json

    print(json.dumps(reference_drift(int(sys.argv[1]) if len(sys.argv) > 1 else 2000)))
