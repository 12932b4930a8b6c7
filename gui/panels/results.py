"""Results viewer: 2D images, 3D volumes (slices with a depth slider, maximum-intensity
projections), a run store's frames and products (a product's own folder
``RUN.zarr/products/NAME`` too), and metrics JSON.

Nothing that reads a file or a store runs on the GUI thread: files are read on a
worker through the library's readers (:func:`recon.io.load_image`,
:class:`instrument.runs.runstore.RunStore`, tifffile / zarr for volumes); a run opens with
its summary as recorded (:meth:`~instrument.runs.runstore.RunStore.summary` without the
check), and its checksums are verified once, on a worker, with progress. Each step
of the frame slider asks for a frame; one reader reads the newest asked for (steps
made while it reads are skipped, not queued). Projections are
:func:`instrument.writer.products.projections`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QProgressBar,
    QPushButton,
    QSlider,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from ..fields import remember
from ..workers import Job
from .common import FrameView, error_label

__all__ = ["UPRIGHT", "ResultsPanel", "read_result"]

#: The title's note on a reconstruction turned upright for viewing.
UPRIGHT = " (upright; stored on the model grid)"
#: How often, at most, the image's levels and histogram follow while an operator steps
#: through a run's frames or a volume's planes, Hz (each costs the window ~5 ms).
STEPPING_HISTOGRAM_HZ = 5.0


def read_result(path: str) -> dict:
    """What the viewer shows for ``path`` (read on a worker).

    Returns
    -------
    dict
        ``kind`` (``"run"``, ``"volume"``, ``"image"``, ``"json"``), with ``store`` and
        ``summary`` (a run: its summary as recorded, no frame read), ``array`` and
        ``depths_mm`` (volumes: (n_z, rows, cols)), ``text`` (JSON, attributes).

    Raises
    ------
    OSError, ValueError, instrument.runs.runstore.RunStoreError
        Missing or unreadable file (the message names it).
    """
    from instrument.runs.runstore import RunStore, is_run_store, product_location
    from instrument.runs.tiff_export import read_tiff_metadata
    from recon.io import load_image

    p = Path(path)
    if not path.strip() or not p.exists():
        raise FileNotFoundError(2, "no such file or folder; choose an image, volume, run "
                                "store or metrics JSON", str(p))
    if p.is_dir() and is_run_store(p):
        store = RunStore.open(p)
        summary = store.summary(verify=False)
        return {"kind": "run", "store": store, "summary": summary,
                "text": json.dumps(summary, indent=1)}
    where = product_location(p) if p.is_dir() else None
    if where is not None:  # a product's own folder: read through its run, verified
        return _product(RunStore.open(where[0]), where[1])
    if p.is_dir():
        import zarr

        node = zarr.open(str(p), mode="r")
        # a recon3d volume: an OME-Zarr image (the volume at 0, attributes on the
        # group), or a bare array as written before
        arr = node["0"] if isinstance(node, zarr.Group) else node
        attrs = {k: v for k, v in node.attrs.items() if k != "ome"}
        return _upright({"kind": "volume", "array": np.asarray(arr[...]),
                         "depths_mm": attrs.get("depths_mm"),
                         "text": json.dumps(attrs, indent=1)}, attrs.get("orientation"))
    if p.suffix.lower() == ".json":
        return {"kind": "json", "text": json.dumps(json.loads(p.read_text()), indent=1)}
    if p.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        with tifffile.TiffFile(p) as tif:
            array = tif.asarray()
            meta = read_tiff_metadata(tif)  # runs export's ImageJ / OME-TIFF too
        if array.ndim == 3 and array.shape[-1] not in (3, 4):
            return _upright({"kind": "volume", "array": array,
                             "depths_mm": meta.get("depths_mm"),
                             "text": json.dumps(meta, indent=1)}, meta.get("orientation"))
        if meta:
            return _upright({"kind": "image", "array": array,
                             "text": json.dumps(meta, indent=1, default=str)},
                            meta.get("orientation"))
    return {"kind": "image", "array": load_image(p), "text": f"{p}"}


def _upright(result: dict, orientation) -> dict:
    """``result`` with its array turned upright (:func:`recon.io.scene_view`) when the
    data are a reconstruction on the model grid (``orientation`` is, or names in a
    dict, :data:`recon.io.DATA_ORIENTATION`), as the live view shows them; marked
    ``upright``. Anything else (frames, PSFs) is shown as the sensor saw it."""
    from recon.io import DATA_ORIENTATION, scene_view

    values = orientation.values() if isinstance(orientation, dict) else (orientation,)
    if DATA_ORIENTATION not in values:
        return result
    array = np.asarray(result["array"])
    axes = (1, 2) if result["kind"] == "volume" else (0, 1)
    return {**result, "array": scene_view(array, axes), "upright": True}


def _frame(store, index: int) -> dict:
    """Frame ``index`` of a run with its coordinates (read on a worker)."""
    if not store.done(range(index, index + 1))[0]:
        return {"index": index, "record": None}
    return {"index": index, "record": store.frame(index)}


def _product(store, name: str) -> dict:
    info = store.product_info(name)
    if "planes_done" in info and info["planes_done"] < info["shape"][0]:
        # a per-frame product still being made (or cut short): the frames it holds
        done = np.flatnonzero(store.product_frames_done(name))
        if not done.size:
            from ..workers import InputError

            raise InputError(
                f"product {name!r} of {store.path} holds no reconstructed frame: the "
                "batch refused every frame it reached (the Record panel and the log say "
                "why) or has not stored one yet; choose another product or reconstruct "
                "the run again")
        array = np.stack([store.product_frame(name, int(i)) for i in done])
        text = (f"{name}: frames {', '.join(str(int(i)) for i in done)} of "
                f"{info['shape'][0]} reconstructed\n{json.dumps(info, indent=1)}")
        return _upright({"kind": "volume", "array": array, "depths_mm": None, "text": text,
                         "axis": "frame"}, info.get("orientation"))
    array, attrs = store.product(name)
    array = np.asarray(array)
    text = json.dumps(attrs, indent=1, default=str)
    if array.ndim == 3 and array.shape[-1] not in (3, 4):
        return _upright({"kind": "volume", "array": array, "depths_mm": attrs.get("depths_mm"),
                         "text": text, "axis": "frame" if attrs.get("per_frame") else "plane",
                         "units": attrs.get("units")}, attrs.get("orientation"))
    return _upright({"kind": "image", "array": array, "text": text,
                     "units": attrs.get("units")}, attrs.get("orientation"))


class ResultsPanel(QWidget):
    """See the module docstring.

    Attributes
    ----------
    problems : list of str or None
        The open run's verification: None until it has finished.
    """

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.job: Job | None = None
        self.frame_job: Job | None = None
        self.verify_job: Job | None = None
        self.store = None
        self.summary_text = ""
        self.problems: list[str] | None = None
        self.volume: np.ndarray | None = None
        self.depths: list[float] | None = None
        self.axis = "plane"
        self.units: str | None = None
        self.upright = False
        self.path_shown: str | None = None
        self._wanted_frame: int | None = None
        self.frame_shown: int | None = None
        layout = QVBoxLayout(self)
        bar = QHBoxLayout()
        self.path = remember(QLineEdit(), "results/path")
        self.path.setObjectName("results.path")
        self.path.setPlaceholderText("image, volume (TIFF / Zarr), run store (.zarr) or "
                                     "metrics .json")
        self.path.returnPressed.connect(lambda: self.open(self.path.text().strip()))
        bar.addWidget(self.path, 1)
        for text, pick in (("File...", self._pick_file), ("Folder...", self._pick_folder)):
            b = QPushButton(text)
            b.clicked.connect(pick)
            bar.addWidget(b)
        layout.addLayout(bar)
        self.error = error_label()
        layout.addWidget(self.error)
        check = QHBoxLayout()
        self.verify_label = QLabel("")
        check.addWidget(self.verify_label, 1)
        self.verify_progress = QProgressBar()
        self.verify_progress.setFormat("checking checksums: %v / %m frames")
        self.verify_progress.setMaximumWidth(320)
        self.verify_progress.hide()
        check.addWidget(self.verify_progress)
        layout.addLayout(check)
        run_bar = QHBoxLayout()
        self.frame_label = QLabel("frame:")
        self.frame_label.setMinimumWidth(150)
        run_bar.addWidget(self.frame_label)
        self.frame_slider = QSlider(Qt.Orientation.Horizontal)
        self.frame_slider.setObjectName("results.frame")
        self.frame_slider.valueChanged.connect(self.show_frame)
        run_bar.addWidget(self.frame_slider, 1)
        self.products = QComboBox()
        self.products.setObjectName("results.products")
        self.products.activated.connect(lambda _: self.show_product(self.products.currentText()))
        run_bar.addWidget(QLabel("product:"))
        run_bar.addWidget(self.products)
        self.frame_info = QLabel("")
        self.frame_info.setObjectName("results.frame_info")
        self.frame_info.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.run_bar = QWidget()
        run_rows = QVBoxLayout(self.run_bar)
        run_rows.setContentsMargins(0, 0, 0, 0)
        run_rows.addLayout(run_bar)
        run_rows.addWidget(self.frame_info)
        layout.addWidget(self.run_bar)
        depth_bar = QHBoxLayout()
        self.depth_label = QLabel("depth:")
        self.depth_label.setMinimumWidth(190)
        depth_bar.addWidget(self.depth_label)
        self.depth_slider = QSlider(Qt.Orientation.Horizontal)
        self.depth_slider.setObjectName("results.depth")
        self.depth_slider.valueChanged.connect(self.show_slice)
        depth_bar.addWidget(self.depth_slider, 1)
        self.depth_bar = QWidget()
        self.depth_bar.setLayout(depth_bar)
        layout.addWidget(self.depth_bar)
        split = QSplitter(Qt.Orientation.Horizontal)
        images = QWidget()
        images_layout = QVBoxLayout(images)
        images_layout.setContentsMargins(0, 0, 0, 0)
        # a run's frames stepped through: levels and histogram follow at most 5 times a
        # second (the newest frame gets its own at the end of the period)
        self.view = FrameView("image", name="result", histogram_hz=STEPPING_HISTOGRAM_HZ)
        self.view.metadata = self._metadata
        images_layout.addWidget(self.view, 3)
        mips = QHBoxLayout()
        self.mip_views = {
            "xy": FrameView("max over depth", axes=("column (px)", "row (px)"), name="mip-xy"),
            "xz": FrameView("max over rows", axes=("column (px)", "plane (repeated)"),
                            name="mip-xz"),
            "yz": FrameView("max over columns", axes=("plane (repeated)", "row (px)"),
                            name="mip-yz")}
        for v in self.mip_views.values():
            v.setMinimumSize(150, 130)
            v.histogram.hide()
            v.metadata = self._metadata
            mips.addWidget(v)
        self.mips = QWidget()
        self.mips.setLayout(mips)
        images_layout.addWidget(self.mips, 2)
        split.addWidget(images)
        self.text = QPlainTextEdit()
        self.text.setReadOnly(True)
        split.addWidget(self.text)
        split.setSizes([700, 300])
        layout.addWidget(split, 1)
        self._mode(None)

    def _mode(self, kind: str | None, volume: bool = False) -> None:
        self.run_bar.setVisible(kind == "run")
        self.depth_bar.setVisible(volume)
        self.mips.setVisible(volume)  # the projections of a volume only
        if not volume:
            for view in self.mip_views.values():
                view.clear()

    def _pick_file(self) -> None:
        path = QFileDialog.getOpenFileName(self, "open a result")[0]
        if path:
            self.open(path)

    def _pick_folder(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "open a run store or Zarr volume")
        if path:
            self.open(path)

    def _metadata(self) -> dict:
        out: dict = {"kind": "result", "path": self.path_shown}
        if self.store is not None and self.frame_shown is not None and self.volume is None:
            out["frame"] = self.frame_shown
        if self.volume is not None:
            out[self.axis] = self.depth_slider.value()
            if self.depths is not None and self.depth_slider.value() < len(self.depths):
                out["depth_mm"] = self.depths[self.depth_slider.value()]
            out["product"] = self.products.currentText() if self.store is not None else None
        return out

    # -- loading -------------------------------------------------------------------------
    def open(self, path: str, product: str | None = None) -> Job:
        """Read ``path`` on a worker and show it (a run's ``product`` if given); a run's
        checksums are then verified on another worker."""
        self.path.setText(path)
        self.error.setText("")
        if self.verify_job is not None:
            self.verify_job.cancel()
        job = Job(lambda job: read_result(path), name="read-result", owner=self)
        self.job = job

        def show(result: dict) -> None:
            if job is not self.job:  # another file was opened meanwhile
                return
            self.path_shown = path
            self.show_result(result)
            if product is not None:
                self.show_product(product)

        def failed(text: str) -> None:
            if job is self.job:
                self.clear_image()
                self.error.setText(text)

        job.succeeded.connect(show)
        job.failed.connect(failed)
        return job.start()

    def show_result(self, result: dict) -> None:
        kind = result["kind"]
        self.text.setPlainText(result.get("text", ""))
        self.store = None
        self.problems = None
        self.verify_label.setText("")
        self.verify_progress.hide()
        if kind == "json":
            self._mode("json")
            return
        if kind == "run":
            self.store = result["store"]
            self.summary_text = result["text"]
            n = self.store.n_frames
            self.frame_slider.blockSignals(True)
            self.frame_slider.setRange(0, max(n - 1, 0))
            self.frame_slider.setValue(0)
            self.frame_slider.blockSignals(False)
            self.products.clear()
            self.products.addItems(list(result["summary"].get("products", {})))
            self._mode("run")
            self.volume = None
            self.show_frame(0)
            self.verify()
            return
        self._show_array(result, None)

    def verify(self) -> Job | None:
        """Check the open run's checksums once, on a worker, with progress."""
        store = self.store
        if store is None:
            return None
        self.verify_progress.setRange(0, 0)
        self.verify_progress.show()
        self.verify_label.setText("checking the run's checksums ...")

        def check(job: Job) -> list[str]:
            def progress(k: int, n: int) -> None:
                if job.cancelled:
                    raise _Cancelled
                if k == n or k % 25 == 0:
                    job.report((k, n))

            try:
                return store.verify(on_progress=progress)
            except _Cancelled:
                return None

        job = Job(check, name="verify-run", owner=self)
        self.verify_job = job

        def progress(kn) -> None:
            if job is self.verify_job:
                self.verify_progress.setRange(0, kn[1])
                self.verify_progress.setValue(kn[0])

        def done(problems) -> None:
            if job is not self.verify_job or problems is None:
                return
            self.problems = problems
            self.verify_progress.hide()
            if problems:
                self.verify_label.setText(
                    f'<b style="color:#b00020">{len(problems)} problem(s) found</b> (listed '
                    "beside the image)")
                self.summary_text += "\n\nproblems:\n" + "\n".join(problems)
                self.text.setPlainText(self.summary_text)
            else:
                self.verify_label.setText("checksums verified: every frame and product is "
                                          "intact")

        job.progress.connect(progress)
        job.succeeded.connect(done)
        job.failed.connect(lambda text: (self.verify_progress.hide(),
                                         self.verify_label.setText(f"check failed: {text}")))
        return job.start()

    def _show_array(self, result: dict, kind: str | None) -> None:
        if result["kind"] == "volume":
            self.volume = np.asarray(result["array"], np.float32)
            self.depths = result.get("depths_mm")
            self.axis = result.get("axis", "plane")
            self.units = result.get("units")
            self.upright = bool(result.get("upright"))
            self.depth_label.setText("depth:" if self.axis == "plane" else "frame:")
            self._mode(kind, volume=True)
            self.depth_slider.setRange(0, len(self.volume) - 1)
            self.depth_slider.setValue(0)
            self.show_slice(0)
            from instrument.writer.products import projections

            for name, image in projections(self.volume).items():
                self.mip_views[name].setImage(image, autoLevels=True)
                self.mip_views[name].view_all()
        else:
            self.volume = None
            self._mode(kind)
            self.view.setImage(np.asarray(result["array"]), autoLevels=True)
            units = result.get("units")
            self.view.setTitle("image" + (f" ({units})" if units else "")
                               + (UPRIGHT if result.get("upright") else ""))
        self.view.view_all()  # a new result: the whole of it, not the last one's zoom

    def show_slice(self, index: int) -> None:
        """Show plane ``index`` of the volume (in memory: no file is read)."""
        if self.volume is None or not 0 <= index < len(self.volume):
            return
        depth = (f", z = {self.depths[index]:.2f} mm" if self.depths is not None
                 and index < len(self.depths) else "")
        depth += f" ({self.units})" if self.units else ""
        self.depth_label.setText(f"{self.axis} {index + 1} of {len(self.volume)}{depth}")
        self.view.setImage(self.volume[index], autoLevels=True)
        self.view.setTitle(f"{self.axis} {index + 1}{depth}"
                           + (UPRIGHT if self.upright else ""))

    def show_frame(self, index: int) -> None:
        """Ask for frame ``index`` of the open run: read on a worker, the newest asked
        for shown (slider steps made while one is read are skipped)."""
        if self.store is None or self.store.n_frames == 0:
            return
        self._wanted_frame = int(index)
        self.frame_label.setText(f"frame {index + 1} of {self.store.n_frames} ...")
        if self.frame_job is None or self.frame_job.done:
            self._read_frame()

    def _read_frame(self) -> None:
        store, index = self.store, self._wanted_frame
        if store is None or index is None:
            return
        job = Job(lambda job: _frame(store, index), name="read-frame", owner=self)
        self.frame_job = job
        job.succeeded.connect(lambda result: self._frame_read(store, result))
        job.failed.connect(self.error.setText)
        job.finished.connect(self._next_frame)
        job.start()

    def _next_frame(self) -> None:
        if self.frame_job is not None and self._wanted_frame is not None and (
                self.frame_shown != self._wanted_frame):
            self._read_frame()

    def _frame_read(self, store, result: dict) -> None:
        if store is not self.store or self._wanted_frame is None:
            return  # another run opened, or a product shown meanwhile
        index, rec = result["index"], result["record"]
        self.frame_shown = index
        if rec is None:
            self.frame_label.setText(f"frame {index + 1}: not captured")
            return
        self.volume = None
        self._mode("run")
        self.frame_label.setText(f"frame {index + 1} of {self.store.n_frames}")
        self.view.setImage(rec.image, autoLevels=True)
        coords = ", ".join(f"{k} {v:.4g}" for k, v in rec.coords.items()
                           if isinstance(v, float) and np.isfinite(v))
        self.view.setTitle(f"frame {index + 1} (point {rec.point}, {rec.tag}) (DN)")
        # beside the slider, not in the summary: re-laying out the summary's text on
        # every step costs the window about as much as the image
        self.frame_info.setText(f"frame index {index}: {coords}" if coords else
                                f"frame index {index}")
        if self.text.toPlainText() != self.summary_text:  # a product's text was shown
            self.text.setPlainText(self.summary_text)

    def show_product(self, name: str) -> Job | None:
        """Show product ``name`` of the open run (2D, or a volume with its depths), read
        on a worker."""
        store = self.store
        if store is None or not name:
            return None
        self._wanted_frame = None
        job = Job(lambda job: _product(store, name), name="read-product", owner=self)
        self.job = job

        def show(result: dict) -> None:
            if store is not self.store:
                return
            self.text.setPlainText(result["text"])
            if self.products.currentText() != name:
                self.products.setCurrentText(name)
            self._show_array(result, "run")

        def failed(text: str) -> None:
            if store is not self.store:
                return
            self.clear_image()  # not the previous product's image under this one's name
            self.error.setText(text)

        job.succeeded.connect(show)
        job.failed.connect(failed)
        return job.start()

    def clear_image(self) -> None:
        """Show no image (nor a volume, its projections or its text): what was shown
        is not what the panel now names."""
        self.volume = None
        self._mode("run" if self.store is not None else None)
        self.view.clear()
        self.view.setTitle("image")
        self.text.setPlainText(self.summary_text if self.store is not None else "")


class _Cancelled(Exception):
    """Another run was opened while this one's checksums were checked."""
