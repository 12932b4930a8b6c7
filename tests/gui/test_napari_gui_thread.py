"""napari's Reconstruct widget, issue 67: what runs on napari's GUI thread when a
solve's result arrives. Checked by structure, not by timing (the machine's load must
not decide a test): the result crosses the pipe from the solver's process without its
array (no large unpickling under napari's interpreter lock), and the GUI thread's
handling computes no contrast limits and guesses no multiscale on the result."""

from __future__ import annotations

import threading

import numpy as np
import pytest

napari = pytest.importorskip("napari")

#: Bytes a result may take on the pipe: its layer keywords, not its array.
_SMALL = 16 * 1024


def _problem(n: int):
    from scipy.signal import fftconvolve

    rng = np.random.default_rng(3)
    psf = np.zeros((n, n), np.float32)
    psf[rng.integers(4, n - 4, 20), rng.integers(4, n - 4, 20)] = 1.0
    scene = np.zeros((n, n), np.float32)
    scene[n // 3:n // 2, n // 4:n // 3] = 1.0
    return psf, (fftconvolve(scene, psf, mode="same") * 500 + 20).astype(np.float32)


def test_a_result_reaches_the_gui_thread_ready_to_add(tmp_path, qapp, wait, monkeypatch):
    """A 128 x 128 result (64 KiB): every message received from the solver's process is
    under 16 KiB, and while the layer is added on the GUI thread napari neither scans
    the data for contrast limits nor guesses whether it is multiscale (the keywords
    carry both); the layer shows the result with the limits of its data."""
    from multiprocessing import connection

    from napari.components import ViewerModel
    from napari.layers._scalar_field import scalar_field
    from napari.layers.image import image as image_module

    from gui.napari_plugin.widget import ReconstructWidget

    received: list[int] = []
    real_loads = connection._ForkingPickler.loads

    def loads(buf, *args, **kwargs):  # what the executor's reader thread unpickles
        received.append(len(memoryview(buf).cast("B")))
        return real_loads(buf, *args, **kwargs)

    monkeypatch.setattr(connection._ForkingPickler, "loads", loads)
    on_gui: list[str] = []

    def noting(name, real):
        def call(*args, **kwargs):
            if threading.current_thread() is threading.main_thread():
                on_gui.append(name)
            return real(*args, **kwargs)
        return call

    monkeypatch.setattr(image_module, "calc_data_range",
                        noting("calc_data_range", image_module.calc_data_range))
    monkeypatch.setattr(scalar_field, "guess_multiscale",
                        noting("guess_multiscale", scalar_field.guess_multiscale))

    n = 128
    psf, raw = _problem(n)
    np.save(tmp_path / "psf.npy", psf + 20)
    viewer = ViewerModel()
    viewer.add_image(raw, name="raw", contrast_limits=[0, 1], multiscale=False)
    widget = ReconstructWidget(viewer)
    ends: list = []
    widget.done.connect(ends.append)
    try:
        widget.psf_run.setText(str(tmp_path / "psf.npy"))
        widget.form.widgets["method"].setCurrentText("admm")
        widget.form.widgets["iterations"].setValue(5)
        widget.form.widgets["tv"].setCurrentText("0.001")
        on_gui.clear()
        received.clear()
        widget.run()
        wait(lambda: ends, 300.0, "the widget's reconstruction")
        assert ends[0] is not None, widget.error.text()
        data, kwargs, _ = ends[0]
        assert data.shape == (n, n) and data.nbytes == 4 * n * n >= 4 * _SMALL
        assert received and max(received) < _SMALL, received
        assert on_gui == [], on_gui
        layer = viewer.layers["raw recon"]
        assert layer.multiscale is False
        assert list(layer.contrast_limits) == pytest.approx(
            [float(data.min()), float(data.max())])
        assert kwargs["contrast_limits"] == pytest.approx(list(layer.contrast_limits))
    finally:
        widget.close()
        widget.deleteLater()


def test_contrast_limits_are_those_napari_computes():
    """The limits the solver's process sends are napari's own for the same array
    (finite range; a constant array widened to 0..1)."""
    from napari.layers.utils.layer_utils import calc_data_range

    from gui.napari_plugin.widget import contrast_limits

    rng = np.random.default_rng(0)
    for data in (rng.random((4, 16, 16), dtype=np.float32) * 7 - 2,
                 np.full((8, 8), 3.5, np.float32), np.zeros((8, 8), np.float32)):
        assert contrast_limits(data) == pytest.approx(list(calc_data_range(data)))
    with_nan = rng.random((8, 8)).astype(np.float32)
    with_nan[0, 0] = np.nan
    assert contrast_limits(with_nan) == pytest.approx(
        [float(np.nanmin(with_nan)), float(np.nanmax(with_nan))])


def test_the_widget_calls_reconstruct_with_its_options_object(tmp_path, monkeypatch):
    """``reconstruct(model, raw, options)``: the form's ReconOptions are passed whole
    (the dark level resolved as the commands resolve it, a stack's Wiener as ADMM), not
    unpacked into keywords."""
    from napari.layers import Image

    import recon
    from gui.napari_plugin.widget import reconstruct_layer
    from recon.options import ReconOptions

    calls: list = []
    real = recon.reconstruct

    def recording(model, raw, *args, **kwargs):
        calls.append((args, kwargs))
        return real(model, raw, *args, **kwargs)

    monkeypatch.setattr(recon, "reconstruct", recording)
    psf, raw = _problem(32)
    np.save(tmp_path / "psf.npy", psf + 20)
    np.save(tmp_path / "stack.npy", np.stack([psf, psf.T]) + 20)
    layer = Image(raw, name="raw")
    reconstruct_layer(layer, tmp_path / "psf.npy", method="admm", iterations=3,
                      tv=0.001, dark="20")
    reconstruct_layer(layer, tmp_path / "stack.npy", method="wiener", iterations=3,
                      tv=0.001, dark="20", depths_mm=[10.0, 12.0])
    assert len(calls) == 2
    for (args, kwargs), method in zip(calls, ("admm", "admm"), strict=True):
        assert kwargs == {} and len(args) == 1 and isinstance(args[0], ReconOptions)
        assert args[0].method == method and float(args[0].dark) == 20.0


def _share_and_exit(queue) -> None:
    """In a child process: a result block made and left untaken, as when napari is
    killed while its solver finishes; the child then ends."""
    from gui.napari_plugin.widget import share_array

    queue.put(share_array(np.arange(12, dtype=np.float32).reshape(3, 4)))


def test_a_result_block_left_untaken_is_removed_when_its_maker_has_ended():
    """A solver's result that napari never took (killed mid-solve) stays in /dev/shm
    only while the solver that made it runs: the next start of the widget's solver
    removes it. A block whose maker still runs is never removed."""
    import multiprocessing
    import os

    from gui.napari_plugin import widget
    from instrument.acquisition.shared_slot import SHM_DIR, reclaim_orphaned_slots

    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    child = ctx.Process(target=_share_and_exit, args=(queue,))
    child.start()
    name, shape, dtype = queue.get(timeout=120)
    child.join(timeout=120)
    assert child.exitcode == 0
    path = os.path.join(SHM_DIR, name)
    assert os.path.exists(path)  # left behind by a maker that has ended
    alive = widget.share_array(np.ones(3, np.float32))  # this process's: kept
    try:
        with widget._SOLVER_LOCK:
            held, widget._SOLVER[:] = list(widget._SOLVER), []
        try:
            pool = widget._solver_pool()  # a new solver: reclaims first
            pool.shutdown()
        finally:
            with widget._SOLVER_LOCK:
                widget._SOLVER[:] = held
        assert not os.path.exists(path)
        assert os.path.exists(os.path.join(SHM_DIR, alive[0]))
        np.testing.assert_array_equal(widget._take_shared(alive), np.ones(3, np.float32))
    finally:
        if os.path.exists(path):
            os.unlink(path)
        reclaim_orphaned_slots()
    with pytest.raises(RuntimeError, match="press Reconstruct again"):
        widget._take_shared((name, shape, dtype))  # reclaimed: said so, not a traceback


def _place() -> tuple[int, int, int]:
    """In the solver's process: its session, its pid and its nice value."""
    import os

    return os.getsid(0), os.getpid(), os.nice(0)


def test_the_solver_runs_in_a_scheduling_group_of_its_own_below_the_viewer():
    """The widget's solver leads a session of its own (under the kernel's autogroup, a
    scheduling group apart from napari's, so its work does not use up the viewer's
    group's share) at SOLVER_NICE below this process. On the old code it shared
    napari's session."""
    import os

    from gui.napari_plugin import widget

    with widget._SOLVER_LOCK:
        held, widget._SOLVER[:] = list(widget._SOLVER), []
    try:
        pool = widget._solver_pool()
        try:
            session, pid, nice = pool.submit(_place).result(timeout=600)
        finally:
            pool.shutdown()
    finally:
        with widget._SOLVER_LOCK:
            widget._SOLVER[:] = held
    assert session == pid != os.getsid(0)
    assert nice == min(19, os.nice(0) + widget.SOLVER_NICE)


def test_yield_to_parent_in_a_child_that_already_leads_a_session():
    """A child started in a session of its own (setsid refused: it leads one already)
    still takes the nice value and says it leads its session."""
    import subprocess
    import sys

    code = ("from diffuserlab.processes import yield_to_parent as y; import json;"
            "print(json.dumps(y(7)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, start_new_session=True, check=True)
    import json
    import os

    assert json.loads(out.stdout) == {"session": True, "nice": min(19, os.nice(0) + 7)}


def test_the_solver_is_shut_down_before_the_interpreter_s_teardown(tmp_path):
    """At exit the widget's solver pool is shut down and dropped by an atexit hook, so
    it is not collected during the interpreter's teardown (where concurrent.futures'
    callback printed "Exception ignored ... 'NoneType' object has no attribute
    'util'" after CI's last test). A hook registered before the widget's runs after
    it: on the old code the pool is still held there."""
    import subprocess
    import sys

    script = tmp_path / "solver_at_exit.py"
    script.write_text(
        "import atexit\n"
        "def check():\n"
        "    from gui.napari_plugin import widget\n"
        "    print('held at exit:', len(widget._SOLVER), flush=True)\n"
        "if __name__ == '__main__':  # not in the spawned solver, which imports this\n"
        "    atexit.register(check)\n"
        "    from gui.napari_plugin import widget\n"
        "    widget._solver_pool().submit(int).result(timeout=600)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=600, check=True)
    assert out.stdout.count("held at exit:") == 1, out.stdout + out.stderr
    assert "held at exit: 0" in out.stdout, out.stdout + out.stderr
    assert "Exception ignored" not in out.stderr, out.stderr
