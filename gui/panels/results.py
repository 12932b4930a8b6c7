"""Results viewer: 2D images, 3D volumes (slices with a depth slider, maximum-intensity
projections), a run store's frames and products, and metrics JSON.

Files are read on a worker through the library's readers (:func:`recon.io.load_image`,
:class:`instrument.runstore.RunStore`, tifffile / zarr for volumes); projections are
:func:`instrument.reconstruct_files.projections`.
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
    QPushButton,
    QSlider,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from ..workers import Job
from .common import FrameView, error_label

__all__ = ["ResultsPanel", "read_result"]


def read_result(path: str) -> dict:
    """What the viewer shows for ``path``.

    Returns
    -------
    dict
        ``kind`` (``"run"``, ``"volume"``, ``"image"``, ``"json"``), with ``store``
        (a run), ``array`` and ``depths_mm`` (volumes: (n_z, rows, cols)), ``text``
        (JSON, attributes).

    Raises
    ------
    OSError, ValueError, instrument.runstore.RunStoreError
        Missing or unreadable file (the message names it).
    """
    from instrument.runstore import RunStore, is_run_store
    from recon.io import load_image

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p} does not exist; choose an image, volume, run store or "
                                "metrics JSON")
    if p.is_dir() and is_run_store(p):
        store = RunStore.open(p)
        return {"kind": "run", "store": store, "text": store.to_json()}
    if p.is_dir():
        import zarr

        arr = zarr.open_array(str(p), mode="r")
        attrs = dict(arr.attrs)
        return {"kind": "volume", "array": np.asarray(arr[...]),
                "depths_mm": attrs.get("depths_mm"), "text": json.dumps(attrs, indent=1)}
    if p.suffix.lower() == ".json":
        return {"kind": "json", "text": json.dumps(json.loads(p.read_text()), indent=1)}
    if p.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        with tifffile.TiffFile(p) as tif:
            array = tif.asarray()
            meta = dict(tif.shaped_metadata[0]) if tif.shaped_metadata else {}
        if array.ndim == 3 and array.shape[-1] not in (3, 4):
            return {"kind": "volume", "array": array, "depths_mm": meta.get("depths_mm"),
                    "text": json.dumps(meta, indent=1)}
    return {"kind": "image", "array": load_image(p), "text": f"{p}"}


def _product(store, name: str) -> dict:
    info = store.product_info(name)
    if "planes_done" in info and info["planes_done"] < info["shape"][0]:
        # a per-frame product still being made (or cut short): the frames it holds
        done = np.flatnonzero(store.product_frames_done(name))
        if not done.size:
            raise ValueError(f"product {name!r} of {store.path} holds no frame yet")
        array = np.stack([store.product_frame(name, int(i)) for i in done])
        text = (f"{name}: frames {', '.join(str(int(i)) for i in done)} of "
                f"{info['shape'][0]} reconstructed\n{json.dumps(info, indent=1)}")
        return {"kind": "volume", "array": array, "depths_mm": None, "text": text,
                "axis": "frame"}
    array, attrs = store.product(name)
    array = np.asarray(array)
    text = json.dumps(attrs, indent=1, default=str)
    if array.ndim == 3 and array.shape[-1] not in (3, 4):
        return {"kind": "volume", "array": array, "depths_mm": attrs.get("depths_mm"),
                "text": text, "axis": "frame" if attrs.get("per_frame") else "plane",
                "units": attrs.get("units")}
    return {"kind": "image", "array": array, "text": text, "units": attrs.get("units")}


class ResultsPanel(QWidget):
    """See the module docstring."""

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.job: Job | None = None
        self.store = None
        self.volume: np.ndarray | None = None
        self.depths: list[float] | None = None
        self.axis = "plane"
        self.units: str | None = None
        layout = QVBoxLayout(self)
        bar = QHBoxLayout()
        self.path = QLineEdit()
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
        run_bar = QHBoxLayout()
        self.frame_label = QLabel("frame:")
        run_bar.addWidget(self.frame_label)
        self.frame_slider = QSlider(Qt.Orientation.Horizontal)
        self.frame_slider.valueChanged.connect(self.show_frame)
        run_bar.addWidget(self.frame_slider, 1)
        self.products = QComboBox()
        self.products.activated.connect(lambda _: self.show_product(self.products.currentText()))
        run_bar.addWidget(QLabel("product:"))
        run_bar.addWidget(self.products)
        self.run_bar = QWidget()
        self.run_bar.setLayout(run_bar)
        layout.addWidget(self.run_bar)
        depth_bar = QHBoxLayout()
        self.depth_label = QLabel("depth:")
        self.depth_label.setMinimumWidth(190)
        depth_bar.addWidget(self.depth_label)
        self.depth_slider = QSlider(Qt.Orientation.Horizontal)
        self.depth_slider.valueChanged.connect(self.show_slice)
        depth_bar.addWidget(self.depth_slider, 1)
        self.depth_bar = QWidget()
        self.depth_bar.setLayout(depth_bar)
        layout.addWidget(self.depth_bar)
        split = QSplitter(Qt.Orientation.Horizontal)
        images = QWidget()
        images_layout = QVBoxLayout(images)
        images_layout.setContentsMargins(0, 0, 0, 0)
        self.view = FrameView("image")
        images_layout.addWidget(self.view, 3)
        mips = QHBoxLayout()
        self.mip_views = {
            "xy": FrameView("max over depth", axes=("column (px)", "row (px)")),
            "xz": FrameView("max over rows", axes=("column (px)", "plane (repeated)")),
            "yz": FrameView("max over columns", axes=("plane (repeated)", "row (px)"))}
        for v in self.mip_views.values():
            v.setMinimumSize(200, 180)
            v.histogram.hide()
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
        # the projections stay visible (blank for a 2D image): hiding pyqtgraph views
        # before they were ever shown crashed PySide6 6.12 at interpreter exit
        self.run_bar.setVisible(kind == "run")
        self.depth_bar.setVisible(volume)
        if not volume:
            for view in self.mip_views.values():
                view.item.clear()
                view.image = None

    def _pick_file(self) -> None:
        path = QFileDialog.getOpenFileName(self, "open a result")[0]
        if path:
            self.open(path)

    def _pick_folder(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "open a run store or Zarr volume")
        if path:
            self.open(path)

    # -- loading -------------------------------------------------------------------------
    def open(self, path: str, product: str | None = None) -> Job:
        """Read ``path`` on a worker and show it (a run's ``product`` if given)."""
        self.path.setText(path)
        self.error.setText("")
        job = Job(lambda job: read_result(path), name="read-result")
        self.job = job

        def show(result: dict) -> None:
            if job is not self.job:  # another file was opened meanwhile
                return
            self.show_result(result)
            if product is not None:
                self.show_product(product)

        job.succeeded.connect(show)
        job.failed.connect(self.error.setText)
        return job.start()

    def show_result(self, result: dict) -> None:
        kind = result["kind"]
        self.text.setPlainText(result.get("text", ""))
        if kind == "json":
            self._mode("json")
            return
        if kind == "run":
            self.store = result["store"]
            n = self.store.n_frames
            self.frame_slider.setRange(0, max(n - 1, 0))
            self.products.clear()
            self.products.addItems(self.store.products())
            self._mode("run")
            self.frame_slider.setValue(0)
            self.show_frame(0)
            return
        self._show_array(result, None)

    def _show_array(self, result: dict, kind: str | None) -> None:
        if result["kind"] == "volume":
            self.volume = np.asarray(result["array"], np.float32)
            self.depths = result.get("depths_mm")
            self.axis = result.get("axis", "plane")
            self.units = result.get("units")
            self.depth_label.setText("depth:" if self.axis == "plane" else "frame:")
            self._mode(kind, volume=True)
            self.depth_slider.setRange(0, len(self.volume) - 1)
            self.depth_slider.setValue(0)
            self.show_slice(0)
            from instrument.reconstruct_files import projections

            for name, image in projections(self.volume).items():
                self.mip_views[name].setImage(image, autoLevels=True)
        else:
            self.volume = None
            self._mode(kind)
            self.view.setImage(np.asarray(result["array"]), autoLevels=True)
            units = result.get("units")
            self.view.setTitle("image" + (f" ({units})" if units else ""))

    def show_slice(self, index: int) -> None:
        """Show plane ``index`` of the volume."""
        if self.volume is None or not 0 <= index < len(self.volume):
            return
        depth = (f", z = {self.depths[index]:.2f} mm" if self.depths is not None
                 and index < len(self.depths) else "")
        depth += f" ({self.units})" if self.units else ""
        self.depth_label.setText(f"{self.axis} {index + 1} of {len(self.volume)}{depth}")
        self.view.setImage(self.volume[index], autoLevels=True)
        self.view.setTitle(f"{self.axis} {index + 1}{depth}")

    def show_frame(self, index: int) -> None:
        """Show frame ``index`` of the open run (with its coordinates)."""
        if self.store is None or self.store.n_frames == 0:
            return
        if not self.store.done()[index]:
            self.frame_label.setText(f"frame {index}: not captured")
            return
        rec = self.store.frame(index)
        self.volume = None
        self._mode("run")
        self.frame_label.setText(f"frame {index + 1} of {self.store.n_frames}")
        self.view.setImage(rec.image, autoLevels=True)
        coords = ", ".join(f"{k} {v:.4g}" for k, v in rec.coords.items()
                           if isinstance(v, float) and np.isfinite(v))
        self.view.setTitle(f"frame {index + 1} (point {rec.point}, {rec.tag}) (DN)")
        self.text.setPlainText(f"frame {index}: {coords}\n\n{self.store.to_json()}")

    def show_product(self, name: str) -> None:
        """Show product ``name`` of the open run (2D, or a volume with its depths)."""
        if self.store is None or not name:
            return
        try:
            result = _product(self.store, name)
        except Exception as exc:  # noqa: BLE001 (shown, never raised)
            from ..workers import readable_error

            self.error.setText(readable_error(exc))
            return
        self.text.setPlainText(result["text"])
        self._show_array(result, "run")
