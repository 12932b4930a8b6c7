"""napari widget: reconstruct the current image layer with the PSF of a run.

:class:`ReconstructWidget` is the widget (npe2 ``widgets``: napari docks it, handing
it the viewer). Its reconstruction options are generated from the one declaration the
command line is generated from (:class:`recon.options.ReconOptions`, the fields that
``recon`` and ``recon3d`` share, :func:`widget_fields`) by the GUI's form builder
(:class:`gui.forms.OptionsForm`), with the command line's defaults, the dark level
included. :func:`reconstruct_layer` does the work: it takes the plane napari shows of
the chosen layer (a frame of a run's frames, or a 2-D image), loads the PSF stack of a
run (or a TIFF/.npy stack, :func:`instrument.stacks.load_psf_stack`), resolves the dark
level as the commands do (:func:`instrument.reconstruct_files.resolve_dark`) and runs
:func:`recon.reconstruct`: with one depth (``depth_mm``, or a stack of one plane) an
image, else the whole stack as a volume. The result comes back as a new layer, on the
model grid (:data:`recon.io.DATA_ORIENTATION`), scaled by the layer's pixel size
times the binning; a volume's first axis is that of a stored volume
(:func:`instrument.ome.volume_axes`: ``z`` in micrometer for evenly spaced depths,
else ``plane``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QWidget,
)

from instrument.cli.recon_flags import COMMAND_FIELDS
from recon.options import ReconOptions

from ..forms import OptionsForm, lay_out

__all__ = ["ReconstructWidget", "reconstruct_layer", "widget_fields"]


def widget_fields() -> tuple[str, ...]:
    """The reconstruction options the widget offers: the fields of ``recon3d`` that
    ``recon`` offers too (both an image and a volume take them), in ``recon3d``'s
    order (:data:`instrument.cli.recon_flags.COMMAND_FIELDS`)."""
    return tuple(f for f in COMMAND_FIELDS["recon3d"] if f in COMMAND_FIELDS["recon"])


def _plane(layer, viewer) -> np.ndarray:
    """The 2-D plane of ``layer`` that ``viewer`` shows (its leading axes at the
    viewer's current step)."""
    data = layer.data
    lead = data.ndim - 2
    if lead <= 0:
        return np.asarray(data)
    step = viewer.dims.current_step if viewer is not None else (0,) * data.ndim
    index = tuple(min(int(s), n - 1) for s, n in zip(step[-data.ndim:][:lead],
                                                      data.shape[:lead], strict=True))
    return np.asarray(data[index])


def reconstruct_layer(layer, psf_run: Path, product: str = "psf_stack",
                      depth_mm: float = 0.0, *, options: ReconOptions | None = None,
                      viewer=None, **values) -> tuple:
    """Reconstruct the plane of ``layer`` that napari shows with a run's PSF.

    Parameters
    ----------
    layer : napari.layers.Image
        A raw measurement: a run's frames (the frame shown) or a 2-D image, the
        size of one PSF plane.
    psf_run : Path
        A run store with a PSF stack product, or a TIFF/.npy stack recording its
        depths.
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
    **values
        :class:`~recon.options.ReconOptions` fields (``method="admm"``,
        ``iterations=30``, ``dark="none"``) when no ``options`` is given.

    Returns
    -------
    tuple
        ``(image or volume float32, {"name", "scale", "axis_labels", "units",
        "metadata"}, "image")``.

    Raises
    ------
    diffuserlab.errors.InputError
        A value of ``values`` the declaration refuses (names the keyword).
    instrument.runstore.RunStoreError
        No PSF stack at ``psf_run`` or no plane near ``depth_mm``.
    recon.errors.ReconInputError
        A measurement that does not fit the PSF, a calibration run's PSF with the dark
        level ``auto`` (give the frames' level; napari shows the message).
    """
    from instrument.ome import volume_axes
    from instrument.reconstruct_files import resolve_dark
    from instrument.stacks import dark_subtracted, load_psf_stack, pick_depth
    from recon import PsfStack, reconstruct
    from recon.io import DATA_ORIENTATION

    if options is None:
        dark = values.get("dark")
        if isinstance(dark, str):  # as the form and the command line parse it
            values["dark"] = ReconOptions.spec("dark").parse(dark)
        options = ReconOptions.validated(values, front="python")
    raw = _plane(layer, viewer).astype(np.float32)
    stack, depths, _ = load_psf_stack(psf_run, product=product)
    stack, dark = resolve_dark(options.dark, stack, calibrated=dark_subtracted(psf_run),
                               what=str(psf_run))
    bin_factor = options.bin_factor
    pitch = [float(s) * bin_factor for s in layer.scale[-2:]]
    units = [str(u) for u in layer.units[-2:]] if hasattr(layer, "units") else ["pixel"] * 2
    meta = {"psf": str(psf_run), "product": product, "method": options.method,
            "dark": str(options.dark), "source_layer": layer.name,
            "orientation": DATA_ORIENTATION}
    if depth_mm > 0 or len(stack) == 1:
        psf, depth = pick_depth(stack, depths, depth_mm if depth_mm > 0 else None)
        rec = reconstruct(psf, raw, **{**options.keywords("image"), "dark": dark})
        meta.update(depth_mm=depth, method_used=rec.info.method)
        return (np.asarray(rec.image, np.float32),
                {"name": f"{layer.name} recon {depth:g} mm", "scale": pitch,
                 "axis_labels": ["y", "x"], "units": units, "metadata": meta}, "image")
    keywords = {**options.keywords("volume"), "dark": dark}
    if keywords["method"] == "wiener":  # a stack has no Wiener solve: its ADMM
        keywords["method"] = "admm"
    rec = reconstruct(PsfStack(stack, depths), raw, **keywords)
    volume = np.asarray(rec.volume, np.float32)
    first, _ = volume_axes(rec.depths_mm, volume.shape[0])  # as a stored volume's
    meta.update(depths_mm=list(rec.depths_mm), method_used=rec.info.method)
    return (volume,
            {"name": f"{layer.name} volume", "scale": [first.scale, *pitch],
             "axis_labels": [first.name, "y", "x"], "units": [first.unit or "pixel", *units],
             "metadata": meta}, "image")


class ReconstructWidget(QWidget):
    """The dock widget: the layer, the PSF run, its product and depth, the
    reconstruction options (:func:`widget_fields`, generated) and Reconstruct.

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
    """

    def __init__(self, napari_viewer, parent=None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        grid = QGridLayout(self)
        self.layer = QComboBox()
        self.layer.setToolTip("the raw measurement: the plane the viewer shows of it")
        self.psf_run = QLineEdit()
        self.psf_run.setPlaceholderText("PSF run (RUN.zarr) or TIFF/.npy stack")
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
        self.form = OptionsForm(ReconOptions, widget_fields(), name="napari")
        rows = [(QLabel("layer:"), self.layer), (QLabel("PSF:"), psf),
                (QLabel("product:"), self.product), (QLabel("depth (mm):"), self.depth),
                *self.form.rows()]
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
        events = getattr(getattr(napari_viewer, "layers", None), "events", None)
        for name in ("inserted", "removed"):
            if events is not None and hasattr(events, name):
                getattr(events, name).connect(lambda *_: self.refresh_layers())
        self.refresh_layers()

    def _browse(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "PSF run store") or \
            QFileDialog.getOpenFileName(self, "PSF stack (TIFF, .npy)")[0]
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

    def run(self):
        """Reconstruct with the form's values and add the result to the viewer.

        Returns
        -------
        tuple or None
            :func:`reconstruct_layer`'s layer data; None when an input was refused
            (:attr:`error` says why).
        """
        from diffuserlab.errors import InputError
        from instrument.runstore import RunStoreError
        from recon.errors import ReconInputError

        self.error.setText("")
        layers = {layer.name: layer for layer in self.image_layers()}
        try:
            layer = layers.get(self.layer.currentText())
            if layer is None:
                raise InputError("choose the image layer to reconstruct")
            if not self.psf_run.text().strip():
                raise InputError("give the PSF: a run store with a PSF stack, or a "
                                 "TIFF/.npy stack")
            data = reconstruct_layer(layer, Path(self.psf_run.text().strip()),
                                     self.product.text().strip() or "psf_stack",
                                     self.depth.value(), options=self.form.values(),
                                     viewer=self.viewer)
        except (InputError, RunStoreError, ReconInputError) as exc:
            self.error.setText(str(exc))
            return None
        from napari.layers import Layer

        self.viewer.add_layer(Layer.create(*data))
        return data
