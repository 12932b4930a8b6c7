"""napari widget: reconstruct the current image layer with the PSF of a run.

:class:`ReconstructWidget` is the widget (npe2 ``widgets``: napari docks it, handing
it the viewer). Its reconstruction options are generated from the one declaration the
command line is generated from (:class:`recon.options.ReconOptions`, the fields that
``recon`` and ``recon3d`` share, :func:`widget_fields`) by the GUI's form builder
(:class:`gui.forms.OptionsForm`), with the command line's defaults, the dark level
included. :func:`reconstruct_layer` does the work: it takes the plane napari shows of
the chosen layer (a frame of a run's frames, or a 2-D image), loads the PSF: the stack
of a run, a TIFF/.npy stack (:func:`instrument.runs.stacks.load_psf_stack`), a plain 2-D
PSF image (a TIFF/.npy file, or a 2-D layer of the viewer) without depths; resolves
the dark level as the commands do (:func:`instrument.processing.reconstruct_files.resolve_dark`,
with the level recorded with a run's frames, as ``recon-run`` takes it) and runs
:func:`recon.reconstruct`: with one depth (``depth_mm``, or a stack of one plane) an
image, else the whole stack as a volume. The widget runs it from a worker thread
(napari's :func:`~napari.qt.threading.create_worker`) in a process of its own
(:func:`solve_in_process`, started when the widget is made: :func:`prestart_solver`),
whose result comes back through shared memory with its contrast limits, so that
napari's GUI thread only adds the layer; the viewer stays responsive. It shows a refusal in its
own words (a command-line flag named by its field,
:func:`gui.messages.operator_text`). The result comes back as a new layer, on the
model grid (:data:`recon.io.DATA_ORIENTATION`), scaled by the layer's pixel size
times the binning; a volume's first axis is that of a stored volume
(:func:`instrument.runs.ome.volume_axes`).
"""

from __future__ import annotations

import atexit
import multiprocessing
import threading
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QWidget,
)

from diffuserlab.processes import yield_to_parent
from instrument.options import COMMAND_FIELDS
from recon.options import ReconOptions

from ..fields import choose_psf_path
from ..forms import OptionsForm, lay_out

__all__ = ["ReconstructWidget", "reconstruct_layer", "widget_fields"]


def widget_fields() -> tuple[str, ...]:
    """The reconstruction options the widget offers: the fields of ``recon3d`` that
    ``recon`` offers too (both an image and a volume take them), in ``recon3d``'s
    order (:data:`instrument.options.COMMAND_FIELDS`)."""
    return tuple(f for f in COMMAND_FIELDS["recon3d"] if f in COMMAND_FIELDS["recon"])


def _plane(layer, step: Sequence[int] | None) -> np.ndarray:
    """The 2-D plane of ``layer`` at the viewer's ``step`` (its leading axes; None:
    the first plane)."""
    data = layer.data
    lead = data.ndim - 2
    if lead <= 0:
        return np.asarray(data)
    step = tuple(step) if step is not None else (0,) * data.ndim
    index = tuple(min(int(s), n - 1) for s, n in zip(step[-data.ndim:][:lead],
                                                      data.shape[:lead], strict=True))
    return np.asarray(data[index])


def _load_psf(psf, product: str, depths_mm: Sequence[float] | None = None
              ) -> tuple[np.ndarray, list, bool, str]:
    """``(stack (n, rows, cols), depths_mm, calibrated, source)`` of a PSF given as a
    run store or a TIFF/.npy stack (:func:`instrument.runs.stacks.load_psf_stack`; a stack
    that records no depths takes ``depths_mm``, one per plane), a plain 2-D image file
    or array (one plane, no depth).

    Raises
    ------
    instrument.runs.runstore.RunStoreError
        A stack of several planes whose depths are missing (neither recorded nor
        given: the message says so and names the widget's depths field), or no PSF.
    """
    from instrument.runs.runstore import RunStoreError
    from instrument.runs.stacks import dark_subtracted, load_psf_stack

    if isinstance(psf, np.ndarray):
        if psf.ndim != 2:
            raise RunStoreError(f"the PSF layer has {psf.ndim} dimensions: choose a 2-D "
                                "image, or give a PSF run or stack file")
        return psf[None].astype(np.float32), [None], False, "a layer"
    path = Path(psf)
    try:
        stack, depths, _ = load_psf_stack(path, depths_mm=depths_mm or None,
                                          product=product)
    except RunStoreError:
        if path.is_dir() or not path.is_file():
            raise
        image = _plain_image(path)
        if image.ndim == 2:  # a plain PSF image: one plane, no depth
            return image[None].astype(np.float32), [None], False, str(path)
        raise RunStoreError(
            f"the depths are missing: {path} holds a stack of {image.shape[0]} planes "
            "and records no depth for them; give one depth per plane (mm) in the "
            "'depths (mm)' field (e.g. 20, 25, 40), or import the stack with its depths "
            "(diffuserlab runs import-psf --depths)") from None
    return stack, list(depths), dark_subtracted(path), str(path)


def _plain_image(path: Path) -> np.ndarray:
    """The array of an image file, of whatever dimensions (a stack is not refused
    here: :func:`_load_psf` says what it lacks)."""
    if path.suffix.lower() == ".npy":
        return np.load(path, allow_pickle=False)
    from recon.errors import ReconInputError
    from recon.io import load_image

    try:
        return load_image(path)
    except ReconInputError:
        import tifffile

        return tifffile.imread(path)


def _psf_pitch_um(psf, product: str, bin_factor: int) -> float | None:
    """The reconstruction grid's pitch (um) a PSF run records (its frames' pitch times
    the product's binning and ``bin_factor``, as ``recon`` and ``recon3d`` scale their
    outputs); None for a file, a layer or a run that records none."""
    if isinstance(psf, np.ndarray):
        return None
    from instrument.processing.reconstruct_files import _grid_pitch_um

    return _grid_pitch_um(str(psf), product, None, bin_factor)


def _recorded_dark(layer) -> float | None:
    """The dark level (DN) recorded with the run whose frames ``layer`` shows (a
    simulated camera's offset, as ``recon-run`` takes it); None if none."""
    from instrument.runs.runstore import RunStore, RunStoreError

    run = (getattr(layer, "metadata", None) or {}).get("run")
    if not run:
        return None
    try:
        level = (RunStore.open(run).attrs.get("simulated") or {}).get("dark_offset_dn")
    except (RunStoreError, OSError):
        return None
    return None if level is None else float(level)


def reconstruct_layer(layer, psf_run: Path | np.ndarray, product: str = "psf_stack",
                      depth_mm: float = 0.0, *, options: ReconOptions | None = None,
                      viewer=None, step: Sequence[int] | None = None,
                      depths_mm: Sequence[float] | None = None, **values) -> tuple:
    """Reconstruct the plane of ``layer`` that napari shows with a run's PSF.

    Parameters
    ----------
    layer : napari.layers.Image
        A raw measurement: a run's frames (the frame shown) or a 2-D image, the
        size of one PSF plane.
    psf_run : Path or ndarray
        A run store with a PSF stack product, a TIFF/.npy stack recording its
        depths, or a plain PSF image (a TIFF/.npy file or an array (rows, cols)),
        reconstructed as one plane of no depth. A ``calibrate psf-from-scenes`` run
        reconstructs with its recipe unless the options name a method, count or prior
        (:func:`instrument.processing.reconstruct_files.scene_recipe_default`, as ``recon``).
    product : str
        The run's product (default ``psf_stack``).
    depth_mm : float
        The depth of the PSF for a 2-D image (mm; 0: the stack's only plane, or
        every plane as a volume).
    options : recon.options.ReconOptions, optional
        The reconstruction's options (the widget's form); default: ``values``
        validated, the others at the declared defaults.
    viewer : napari.Viewer, optional
        Given by napari: which plane it shows.
    step : sequence of int, optional
        The viewer's current step, read on the GUI thread (instead of ``viewer``).
    depths_mm : sequence of float, optional
        One depth per plane (mm) of a TIFF/.npy stack that records none.
    **values
        :class:`~recon.options.ReconOptions` fields (``method="admm"``,
        ``iterations=30``, ``dark="none"``) when no ``options`` is given.

    Returns
    -------
    tuple
        ``(image or volume float32, {"name", "scale", "axis_labels", "units",
        "metadata"}, "image")``; ``y``, ``x`` in micrometres at the PSF run's pitch
        times the binning when the run records one (as ``recon3d`` scales its
        volume), else the layer's scale times the binning.

    Raises
    ------
    diffuserlab.errors.InputError
        A value of ``values`` the declaration refuses (names the keyword).
    instrument.runs.runstore.RunStoreError
        No PSF stack at ``psf_run`` or no plane near ``depth_mm``.
    recon.errors.ReconInputError
        A measurement that does not fit the PSF, a calibration run's PSF with the dark
        level ``auto`` and no level recorded with the layer's run (give the frames'
        level; the widget shows the message), a PSF file that cannot be read.
    """
    from instrument.processing.reconstruct_files import resolve_dark, scene_recipe_default
    from instrument.runs.ome import volume_axes
    from instrument.runs.stacks import pick_depth
    from recon import PsfStack, reconstruct
    from recon.early_stop import named
    from recon.io import DATA_ORIENTATION

    if options is None:
        dark = values.get("dark")
        if isinstance(dark, str):  # as the form and the command line parse it
            values["dark"] = ReconOptions.spec("dark").parse(dark)
        options = ReconOptions.validated(values, front="python")
    if not isinstance(psf_run, np.ndarray):  # a scene-calibrated run: its recipe, as recon's
        options = scene_recipe_default(psf_run, options)
    if step is None and viewer is not None:
        step = viewer.dims.current_step
    raw = _plane(layer, step).astype(np.float32)
    stack, depths, calibrated, source = _load_psf(psf_run, product, depths_mm)
    stack, dark = resolve_dark(options.dark, stack, calibrated=calibrated,
                               recorded=_recorded_dark(layer), what=source)
    bin_factor = options.bin_factor
    run_pitch = _psf_pitch_um(psf_run, product, bin_factor)
    if run_pitch is not None:  # the PSF run's pitch, as recon3d's volume is scaled
        pitch, units = [run_pitch] * 2, ["micrometer"] * 2
    else:
        pitch = [float(s) * bin_factor for s in layer.scale[-2:]]
        units = ([str(u) for u in layer.units[-2:]] if hasattr(layer, "units")
                 else ["pixel"] * 2)
    meta = {"psf": source, "product": product, "method": options.method,
            "dark": str(options.dark), "source_layer": layer.name,
            "orientation": DATA_ORIENTATION}
    if named(options.early_stop):
        meta["early_stop"] = options.early_stop
    options = options.replace(dark=dark)  # the level resolved as the commands resolve it
    if depths == [None]:  # a plain PSF image: its one plane, no depth
        rec = reconstruct(stack[0], raw, options)
        meta.update(method_used=rec.info.method)
        return (np.asarray(rec.image, np.float32),
                {"name": f"{layer.name} recon", "scale": pitch, "axis_labels": ["y", "x"],
                 "units": units, "metadata": meta}, "image")
    if depth_mm > 0 or len(stack) == 1:
        psf, depth = pick_depth(stack, depths, depth_mm if depth_mm > 0 else None)
        rec = reconstruct(psf, raw, options)
        meta.update(depth_mm=depth, method_used=rec.info.method)
        return (np.asarray(rec.image, np.float32),
                {"name": f"{layer.name} recon {depth:g} mm", "scale": pitch,
                 "axis_labels": ["y", "x"], "units": units, "metadata": meta}, "image")
    if options.method == "wiener":  # a stack has no Wiener solve: its ADMM
        options = options.replace(method="admm")
    rec = reconstruct(PsfStack(stack, depths), raw, options)
    volume = np.asarray(rec.volume, np.float32)
    first, _ = volume_axes(rec.depths_mm, volume.shape[0])  # as a stored volume's
    meta.update(depths_mm=list(rec.depths_mm), method_used=rec.info.method)
    return (volume,
            {"name": f"{layer.name} volume", "scale": [first.scale, *pitch],
             "translate": [getattr(first, "origin", 0.0), 0.0, 0.0],
             "axis_labels": [first.name, "y", "x"], "units": [first.unit or "pixel", *units],
             "metadata": meta}, "image")


def layer_view(layer, step: Sequence[int] | None) -> SimpleNamespace:
    """What :func:`reconstruct_layer` reads of ``layer``, picklable: the plane shown at
    ``step`` (read here: a run's frame is read from its store), its scale, units, name
    and the run it came from (its recorded dark level)."""
    meta = getattr(layer, "metadata", None) or {}
    return SimpleNamespace(
        data=_plane(layer, step), scale=tuple(float(v) for v in layer.scale[-2:]),
        units=tuple(str(u) for u in getattr(layer, "units", ("pixel",) * 2)[-2:]),
        name=str(layer.name), metadata={"run": meta.get("run")} if meta.get("run") else {})


#: The solving process's scheduling priority (``nice``), in a scheduling group of its own
#: (:func:`diffuserlab.processes.yield_to_parent`): below the viewer's, so on a busy
#: machine napari's GUI thread gets a core first.
SOLVER_NICE = 10
#: The process the widget's solves run in (started at the first solve, kept for the
#: next: its imports and compilations are done once), and the lock that makes it.
_SOLVER: list = []
_SOLVER_LOCK = threading.Lock()


def _release_solver() -> None:
    """At interpreter exit (:mod:`atexit`): shut the solver's pool down and drop it.

    Kept in a module global to its end, the pool would be collected during the
    interpreter's teardown, when :mod:`concurrent.futures`' collection callback finds
    its modules already cleared and prints "Exception ignored in ... weakref_cb ...
    'NoneType' object has no attribute 'util'" (seen after CI's last test). atexit runs
    before that teardown (and after the pool's manager thread was joined)."""
    with _SOLVER_LOCK:
        pools, _SOLVER[:] = list(_SOLVER), []
    for pool in pools:
        pool.shutdown(wait=False, cancel_futures=True)


atexit.register(_release_solver)


def contrast_limits(data: np.ndarray) -> list[float]:
    """The contrast limits napari would compute for a layer of ``data`` (its range,
    as :func:`napari.layers.utils.layer_utils.calc_data_range` gives it for an array
    of this size; a constant or empty array widened to include 0 and 1, non-finite
    values left out), computed where the solve runs, so the viewer's GUI thread never
    scans the result."""
    good = np.isfinite(data)
    finite = data if good.all() else data[good]
    if finite.size == 0:
        return [0.0, 1.0]
    low, high = float(finite.min()), float(finite.max())
    if low == high:
        low, high = min(low, 0.0), max(high, 1.0)
    return [low, high]


def _solve_shared(view: SimpleNamespace, psf, product: str, depth_mm: float,
                  **keywords) -> tuple:
    """In the solver's process: :func:`reconstruct_layer`, its array put in a shared
    memory block and its contrast limits (:func:`contrast_limits`) and
    ``multiscale=False`` added to the layer's keywords, so that what crosses the pipe
    is a few hundred bytes, not the array (unpickling a 25 x 512 x 512 volume held
    napari's interpreter lock for ~70 ms).

    Returns
    -------
    tuple
        ``((block name, shape, dtype), layer keywords, layer type)``: the block is
        the caller's to copy, close and unlink (:func:`_take_shared`).
    """
    data, kwargs, kind = reconstruct_layer(view, psf, product, depth_mm, **keywords)
    data = np.ascontiguousarray(data)
    kwargs = {**kwargs, "contrast_limits": contrast_limits(data), "multiscale": False}
    return share_array(data), kwargs, kind


def share_array(data: np.ndarray) -> tuple:
    """``data`` copied into a new shared memory block for another process to take.

    The block is named after this process
    (:func:`instrument.acquisition.shared_slot.owned_block_name`), so that if the
    taker never takes it (napari closed or killed mid-solve) it is removed once this
    process has ended, at the next start of the widget's solver
    (:func:`instrument.acquisition.shared_slot.reclaim_orphaned_slots`), never while
    it runs.

    Parameters
    ----------
    data : ndarray, C-contiguous, any shape and dtype

    Returns
    -------
    tuple
        ``(block name, shape, dtype string)``, for :func:`_take_shared`.
    """
    from multiprocessing import resource_tracker, shared_memory

    from instrument.acquisition.shared_slot import owned_block_name

    block = shared_memory.SharedMemory(name=owned_block_name(), create=True,
                                       size=max(data.nbytes, 1))
    try:
        np.ndarray(data.shape, data.dtype, buffer=block.buf)[...] = data
    except BaseException:
        block.close()
        block.unlink()
        raise
    block.close()  # the caller unlinks it: this process no longer tracks it
    resource_tracker.unregister(block._name, "shared_memory")  # noqa: SLF001
    return block.name, data.shape, data.dtype.str


def _take_shared(handle: tuple) -> np.ndarray:
    """The array of a :func:`_solve_shared` block, copied into this process's memory
    (NumPy's copy releases the interpreter lock), the block closed and unlinked."""
    from multiprocessing import shared_memory

    name, shape, dtype = handle
    try:
        block = shared_memory.SharedMemory(name=name)
    except FileNotFoundError:  # its maker ended and another process reclaimed it
        raise RuntimeError("the reconstruction's process ended before its result was "
                           "read; press Reconstruct again") from None
    try:
        out = np.empty(shape, dtype)
        np.copyto(out, np.ndarray(shape, dtype, buffer=block.buf))
    finally:
        block.close()
        block.unlink()
    return out


def _solver_pool():
    """The solver's process pool (one process at :data:`SOLVER_NICE`), made at the first
    call and kept; before it is made, the result blocks that ended solvers left
    untaken (napari killed mid-solve) are removed."""
    from concurrent.futures import ProcessPoolExecutor

    with _SOLVER_LOCK:
        if not _SOLVER:
            from instrument.acquisition.shared_slot import reclaim_orphaned_slots

            reclaim_orphaned_slots()  # result blocks of solvers that ended untaken
            ctx = multiprocessing.get_context("spawn")
            _SOLVER.append(ProcessPoolExecutor(max_workers=1, mp_context=ctx,
                                               initializer=yield_to_parent,
                                               initargs=(SOLVER_NICE,)))
        return _SOLVER[0]


def _warm() -> None:
    """In the solver's process: import what a solve needs, before the first solve."""
    import instrument.processing.reconstruct_files  # noqa: F401
    import instrument.runs.stacks  # noqa: F401
    import recon.volume.api  # noqa: F401


def prestart_solver() -> None:
    """Start the solver's process and its imports now (from a thread of its own), so the
    first Reconstruct does not wait for them; a failure here is left to the first solve
    to report."""
    def start() -> None:
        try:
            _solver_pool().submit(_warm).result()
        except Exception:  # noqa: BLE001 (the first solve starts a new one and says why)
            with _SOLVER_LOCK:
                _SOLVER.clear()

    threading.Thread(target=start, name="napari-solver-start", daemon=True).start()


def solve_in_process(view: SimpleNamespace, psf, product: str, depth_mm: float,
                     **keywords) -> tuple:
    """:func:`reconstruct_layer` of a :func:`layer_view` in a process of its own, its
    result ready for napari.

    The solver's compiled kernels hold Python's interpreter lock while they run (up to
    0.9 s per call measured at load 12: ``python -m soak.napari_widget_benchmark``);
    on a thread of napari's process that froze the viewer. In a child process at
    :data:`SOLVER_NICE` the viewer's GUI thread never waits for it, and on a busy
    machine gets a core before it. The array comes back through shared memory
    (:func:`_solve_shared`) and is copied on the calling thread, and the layer's
    keywords carry its contrast limits and ``multiscale=False``: what is left for the
    GUI thread is napari's ``add_layer``. Called on the widget's worker thread.

    Returns
    -------
    tuple
        ``(array, layer keywords, layer type)`` as :func:`reconstruct_layer`'s, the
        keywords with ``contrast_limits`` and ``multiscale``.

    Raises
    ------
    The errors of :func:`reconstruct_layer`, as raised in the child.
    """
    from concurrent.futures.process import BrokenProcessPool

    pool = _solver_pool()
    try:
        handle, kwargs, kind = pool.submit(_solve_shared, view, psf, product, depth_mm,
                                           **keywords).result()
    except BrokenProcessPool:  # the child died (killed, out of memory): a new one next
        with _SOLVER_LOCK:
            if _SOLVER and _SOLVER[0] is pool:
                _SOLVER.clear()
        raise RuntimeError("the reconstruction's process ended before it finished (killed "
                           "or out of memory); press Reconstruct again") from None
    return _take_shared(handle), kwargs, kind


class ReconstructWidget(QWidget):
    """The dock widget: the layer, the PSF, its product and depth, the reconstruction
    options (:func:`widget_fields`, generated) and Reconstruct.

    Parameters
    ----------
    napari_viewer : napari.Viewer
        Given by napari (its ``layers``, ``dims`` and ``add_layer``).

    Attributes
    ----------
    form : gui.forms.OptionsForm
        The reconstruction options' widgets.
    error : QLabel
        A refused value or input, in words.
    done : Signal(object)
        Emitted on the GUI thread when a reconstruction ends: its layer data
        (:func:`reconstruct_layer`), added to the viewer, or None when it was refused
        (:attr:`error` says why).
    """

    done = Signal(object)

    def __init__(self, napari_viewer, parent=None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        self.worker = None
        grid = QGridLayout(self)
        self.layer = QComboBox()
        self.layer.setToolTip("the raw measurement: the plane the viewer shows of it")
        self.psf_run = QLineEdit()
        self.psf_run.setPlaceholderText("PSF run (RUN.zarr), TIFF/.npy stack or image, "
                                        "or a 2-D layer's name")
        browse = QPushButton("Browse...")
        browse.clicked.connect(self._browse)
        psf = QWidget()
        row = QHBoxLayout(psf)
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(self.psf_run, 1)
        row.addWidget(browse)
        self.product = QLineEdit("psf_stack")
        self.depth = QDoubleSpinBox()
        self.depth.setRange(0.0, 1e4)
        self.depth.setDecimals(3)
        self.depth.setSpecialValueText("only or every plane")
        self.depth.setToolTip("the PSF's depth for a 2-D image (mm); 0: the stack's only "
                              "plane, or every plane as a volume")
        self.depths = QLineEdit()
        self.depths.setPlaceholderText("recorded with the stack")
        self.depths.setToolTip("one depth per plane (mm, e.g. 20, 25, 40) of a TIFF/.npy "
                               "stack that records none")
        self.form = OptionsForm(ReconOptions, widget_fields(), name="napari")
        rows = [(QLabel("layer:"), self.layer), (QLabel("PSF:"), psf),
                (QLabel("product:"), self.product), (QLabel("depth (mm):"), self.depth),
                (QLabel("depths (mm):"), self.depths), *self.form.rows()]
        end = lay_out(grid, rows)
        self.button = QPushButton("Reconstruct")
        self.button.clicked.connect(self.run)
        grid.addWidget(self.button, end, 0, 1, 2)
        self.error = QLabel("")
        self.error.setWordWrap(True)
        self.error.setStyleSheet("color: #c0392b")
        grid.addWidget(self.error, end + 1, 0, 1, 2)
        grid.setRowStretch(end + 2, 1)
        grid.setColumnStretch(1, 1)
        prestart_solver()
        events = getattr(getattr(napari_viewer, "layers", None), "events", None)
        for name in ("inserted", "removed"):
            if events is not None and hasattr(events, name):
                getattr(events, name).connect(lambda *_: self.refresh_layers())
        self.refresh_layers()

    def _browse(self) -> None:
        path = choose_psf_path(self, "PSF stack or image (TIFF, .npy)")
        if path:
            self.psf_run.setText(path)

    def image_layers(self) -> list:
        """The viewer's image layers (those with 2-D planes)."""
        return [layer for layer in getattr(self.viewer, "layers", [])
                if type(layer).__name__ == "Image"]

    def refresh_layers(self) -> None:
        """Offer the viewer's image layers (the choice kept while its layer is there)."""
        current = self.layer.currentText()
        self.layer.clear()
        self.layer.addItems([layer.name for layer in self.image_layers()])
        if current:
            self.layer.setCurrentText(current)

    def _refuse(self, exc: BaseException) -> None:
        """Show why ``exc`` stopped the reconstruction, in the widget's words (a flag
        named by its field); :attr:`done` gives None."""
        from ..workers import readable_error

        self.error.setText(readable_error(exc, self.form.flag_labels()))
        self.button.setEnabled(True)
        self.done.emit(None)

    def run(self):
        """Reconstruct with the form's values on a worker thread; the result is added to
        the viewer when it is done (:attr:`done`).

        Returns
        -------
        napari.qt.threading.FunctionWorker or None
            The started worker; None when an input was refused at once (:attr:`error`
            says why, :attr:`done` gives None).
        """
        from diffuserlab.errors import InputError

        self.error.setText("")
        layers = {layer.name: layer for layer in self.image_layers()}
        try:
            layer = layers.get(self.layer.currentText())
            if layer is None:
                raise InputError("choose the image layer to reconstruct")
            text = self.psf_run.text().strip()
            if not text:
                raise InputError("give the PSF: a run store with a PSF stack, a TIFF/.npy "
                                 "stack or image, or a 2-D image layer")
            psf = np.asarray(layers[text].data) if text in layers else Path(text)
            options = self.form.values()
            depths = self.depths_mm()
        except InputError as exc:
            self._refuse(exc)
            return None
        from napari.qt.threading import create_worker

        step = tuple(self.viewer.dims.current_step)  # read here, on the GUI thread

        def solve(layer, psf, product, depth_mm, **keywords):  # on the worker thread
            return solve_in_process(layer_view(layer, step), psf, product, depth_mm,
                                    **keywords)

        self.worker = create_worker(
            solve, layer, psf, self.product.text().strip() or "psf_stack",
            self.depth.value(), options=options, depths_mm=depths, _start_thread=False,
            _connect={"returned": self._add, "errored": self._refuse})
        self.button.setEnabled(False)
        self.worker.start()
        return self.worker

    def depths_mm(self) -> list[float] | None:
        """The depths field's values (mm; None when empty).

        Raises
        ------
        diffuserlab.errors.InputError
            A value that is not a number.
        """
        from diffuserlab.errors import InputError

        text = self.depths.text().replace(",", " ").split()
        try:
            return [float(v) for v in text] or None
        except ValueError:
            raise InputError(f"'depths (mm)' {self.depths.text()!r}: give one number per "
                             "plane, e.g. 20, 25, 40") from None

    def _add(self, data: tuple) -> None:
        from napari.layers import Layer

        self.viewer.add_layer(Layer.create(*data))
        self.button.setEnabled(True)
        self.done.emit(data)
