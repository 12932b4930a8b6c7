"""Fixtures of the GUI tests: Qt on the offscreen platform, a window on the virtual bench.

The window's session is the built-in simulated bench streaming in real time, with no
moving scene (rendering one ahead takes ~20 s; the tests move the stage instead). It is
shared by the tests of a module (opening the bench and numba's first compilations take
seconds); each test leaves it connected, with no job running.
"""

from __future__ import annotations

import gc
import os

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


@pytest.fixture(autouse=True)
def _qt_garbage_dies_on_the_gui_thread():
    """After each test, collect the garbage it left, here on the GUI thread.

    A Qt widget's wrapper left to the garbage collector may be collected on any thread
    that happens to start a collection (zarr's event loop, a worker); PySide6 then
    queues the C++ deletion for the main thread, and such a deletion crashed a later
    test's process (segfault in ``Shiboken::BindingManager::runDeletionInMainThread``),
    which under pytest-xdist's ``--dist loadfile`` hung the whole run. (Widgets given
    ``deleteLater`` are left to the event loop, as in the window: deleting them here
    would run their pending jobs' callbacks on deleted widgets.)
    """
    yield
    gc.collect()


@pytest.fixture(scope="module")
def window(qapp, tmp_path_factory):
    """A connected :class:`gui.app.MainWindow` on the virtual bench (no scene)."""
    os.environ["DIFFUSERLAB_GUI_SETTINGS"] = str(tmp_path_factory.mktemp("qt") / "gui.ini")
    from gui.app import MainWindow
    from gui.session import BENCH_JOBS, Session
    from soak.device_jobs import JOBS

    BENCH_JOBS.update(JOBS)

    w = MainWindow(Session(None, simulate=True, scene="none"))
    w.show()
    w.session.connect_bench()
    wait_for(qapp, lambda: w.session.connected, 120.0, "the bench to open")
    # moves of tens of mm at the stage's default 5 mm/s would take seconds of wall time
    for stage in ("source_stage", "mask_stage"):
        axes = w.session.devices[stage].axes
        w.session.service.apply_settings(stage, {"velocity": dict.fromkeys(axes, 50.0)})
    yield w
    w.shutdown()
    w.deleteLater()
    qapp.processEvents()


#: The tests' timeouts are what an idle machine needs, with a margin; they guard against
#: a hang and are stretched by this factor (at most :data:`HANG_S`): the window's jobs
#: run at nice 10 (:data:`gui.workers.BACKGROUND_NICE`), so a machine busy at nice 0
#: gives them about a tenth of their idle share (CFS weights 110 against 1024), and the
#: README's command beside two busy loops ran a 4 s batch past 120 s.
HANG_FACTOR = 10.0
#: The longest a test waits for anything, s.
HANG_S = 600.0


def hang_guard(timeout_s: float) -> float:
    """The wait that guards a step an idle machine does within ``timeout_s``, s."""
    return max(timeout_s, min(timeout_s * HANG_FACTOR, HANG_S))


def wait_for(qapp, condition, timeout_s: float, what: str) -> None:
    """Process Qt events until ``condition()`` holds (fails naming ``what``) or
    :func:`hang_guard` of ``timeout_s`` has passed: no test waits for a timeout, so a
    longer wait costs only when something hangs."""
    from gui.workers import wait_until

    wait_until(qapp, condition, hang_guard(timeout_s), what)


@pytest.fixture
def wait(qapp):
    """``wait(condition, timeout_s, what)`` processing Qt events meanwhile."""
    return lambda condition, timeout_s=30.0, what="the GUI": wait_for(qapp, condition,
                                                                      timeout_s, what)


@pytest.fixture(scope="module")
def psf_file(window, tmp_path_factory):
    """The window's bench's on-axis PSF at 40 mm as its camera would record it (with
    the dark offset), a ``.npy`` path for the Live panel's PSF field."""
    import numpy as np

    from soak.device_jobs import twin_psf

    h, dark = twin_psf(window.session, (0.0, 0.0, 40.0))
    path = tmp_path_factory.mktemp("live-psf") / "psf.npy"
    np.save(path, (h / h.max() * 4000.0 + dark).astype(np.float32))
    return str(path)


@pytest.fixture
def record_panel(qapp, tmp_path):
    """A :class:`gui.panels.record.RecordPanel` on an unconnected simulated session,
    with settings of its own."""
    os.environ["DIFFUSERLAB_GUI_SETTINGS"] = str(tmp_path / "gui.ini")
    from gui.panels.record import RecordPanel
    from gui.session import Session

    panel = RecordPanel(Session(None, simulate=True, scene="none"))
    yield panel
    panel.close()
    panel.deleteLater()
