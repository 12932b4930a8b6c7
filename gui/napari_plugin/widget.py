"""napari widget: reconstruct the current image layer with the PSF of a run.

:func:`reconstruct_layer` is the widget's function (npe2 ``autogenerate``: magicgui
builds its form from the signature). It takes the plane napari shows of the chosen
layer (a frame of a run's frames, or a 2-D image), loads the PSF stack of a run (or a
TIFF/.npy stack, :func:`instrument.stacks.load_psf_stack`), and runs
:func:`recon.reconstruct`: with one depth (``depth_mm``, or a stack of one plane) an
image, else the whole stack as a volume. The result comes back as a new layer, on the
model grid (:data:`recon.io.DATA_ORIENTATION`), scaled by the layer's pixel size
times the binning; a volume's first axis is that of a stored volume
(:func:`instrument.ome.volume_axes`: ``z`` in micrometer for evenly spaced depths,
else ``plane``).
"""

# (no ``from __future__ import annotations``: magicgui builds the form from the
# annotations at run time; napari's types are strings it resolves by importing napari,
# the optional extra)
from pathlib import Path
from typing import Literal

import numpy as np

__all__ = ["METHODS", "reconstruct_layer"]

#: Methods the widget offers (``recon.reconstruct``'s, for one PSF and for a stack).
METHODS = ("auto", "admm", "fista", "wiener")


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


def reconstruct_layer(layer: "napari.layers.Image", psf_run: Path,  # noqa: F821
                      product: str = "psf_stack", depth_mm: float = 0.0,
                      method: Literal["auto", "admm", "fista", "wiener"] = "auto",
                      iterations: int = 100, bin_factor: int = 1,
                      viewer: "napari.Viewer" = None,  # noqa: F821
                      ) -> "napari.types.LayerDataTuple":  # noqa: F821
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
    method : str
        One of :data:`METHODS` (``recon.reconstruct``'s).
    iterations : int
    bin_factor : int
    viewer : napari.Viewer, optional
        Given by napari: which plane it shows.

    Returns
    -------
    tuple
        ``(image or volume float32, {"name", "scale", "axis_labels", "units",
        "metadata"}, "image")``.

    Raises
    ------
    instrument.runstore.RunStoreError
        No PSF stack at ``psf_run`` or no plane near ``depth_mm``.
    recon.errors.ReconInputError
        A measurement that does not fit the PSF (napari shows the message).
    """
    from instrument.ome import volume_axes
    from instrument.stacks import load_psf_stack, pick_depth
    from recon import PsfStack, reconstruct
    from recon.io import DATA_ORIENTATION

    raw = _plane(layer, viewer).astype(np.float32)
    stack, depths, _ = load_psf_stack(psf_run, product=product)
    pitch = [float(s) * bin_factor for s in layer.scale[-2:]]
    units = [str(u) for u in layer.units[-2:]] if hasattr(layer, "units") else ["pixel"] * 2
    meta = {"psf": str(psf_run), "product": product, "method": method,
            "source_layer": layer.name, "orientation": DATA_ORIENTATION}
    if depth_mm > 0 or len(stack) == 1:
        psf, depth = pick_depth(stack, depths, depth_mm if depth_mm > 0 else None)
        rec = reconstruct(psf, raw, method, iterations=iterations, bin_factor=bin_factor)
        meta.update(depth_mm=depth, method_used=rec.info.method)
        return (np.asarray(rec.image, np.float32),
                {"name": f"{layer.name} recon {depth:g} mm", "scale": pitch,
                 "axis_labels": ["y", "x"], "units": units, "metadata": meta}, "image")
    rec = reconstruct(PsfStack(stack, depths), raw, method if method != "wiener" else "admm",
                      iterations=iterations, bin_factor=bin_factor)
    volume = np.asarray(rec.volume, np.float32)
    first, _ = volume_axes(rec.depths_mm, volume.shape[0])  # as a stored volume's
    meta.update(depths_mm=list(rec.depths_mm), method_used=rec.info.method)
    return (volume,
            {"name": f"{layer.name} volume", "scale": [first.scale, *pitch],
             "axis_labels": [first.name, "y", "x"], "units": [first.unit or "pixel", *units],
             "metadata": meta}, "image")
