"""The docs' napari screenshot: a run opened with the plugin in a real napari window.

    Xvfb :55 & DISPLAY=:55 QT_QPA_PLATFORM=xcb \\
        python -m gui.napari_plugin.screenshot RUN.zarr OUT.png [--frame 10]

Registers the plugin's manifest with npe2 (so it works from a checkout that is not
installed), opens ``RUN.zarr`` through napari's reader API, shows the frames and the
products side by side (napari's grid) with the scale bar in the run's units, and saves
the whole window. ``--also V.zarr`` opens more (a recon3d volume: every layer kept),
``--widget`` docks the Reconstruct widget.
"""

from __future__ import annotations

import argparse

import numpy as np

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Open a run in napari and save a screenshot of the window; 0 on success."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("out")
    parser.add_argument("--frame", type=int, default=0, help="the frame shown")
    parser.add_argument("--layers", default="frames,recon_admm,recon_admm_dff",
                        help="comma-separated layer name endings to show")
    parser.add_argument("--also", action="append", default=[],
                        help="another run or recon3d volume to open (all its layers)")
    parser.add_argument("--widget", action="store_true", help="dock the Reconstruct widget")
    parser.add_argument("--ndisplay", type=int, choices=(2, 3), default=2,
                        help="3: the last three axes rendered (a video's frame and a "
                             "volume's planes at their depths), no grid")
    args = parser.parse_args(argv)
    import napari
    import npe2

    from . import MANIFEST

    pm = npe2.PluginManager.instance()
    manifest = npe2.PluginManifest.from_file(MANIFEST)
    if manifest.name not in pm._manifests:
        pm.register(manifest)
    viewer = napari.Viewer(show=True)
    layers = viewer.open(args.run, plugin=manifest.name)
    keep = [w.strip() for w in args.layers.split(",")]
    for layer in list(layers):
        if not any(layer.name.endswith(" " + k) for k in keep):
            viewer.layers.remove(layer)
    for layer in viewer.layers:
        layer.contrast_limits = [float(v) for v in (layer.data[args.frame].min(),
                                                    layer.data[args.frame].max())]
    for path in args.also:
        for layer in viewer.open(path, plugin=manifest.name):
            data = np.asarray(layer.data)
            layer.contrast_limits = [float(np.percentile(data, 50)),
                                     float(np.percentile(data, 99.9))]
            layer.colormap, layer.blending = "magma", "additive"
    if args.widget:
        from .widget import ReconstructWidget

        viewer.window.add_dock_widget(ReconstructWidget(viewer), name="Reconstruct")
    viewer.dims.set_current_step(0, args.frame)
    viewer.canvas.grid.enabled = args.ndisplay == 2
    viewer.dims.ndisplay = args.ndisplay
    viewer.canvas.overlays.scale_bar.visible = True
    viewer.layers.selection.active = viewer.layers[0]
    viewer.window.resize(1400, 800)
    viewer.reset_view()
    napari.qt.get_qapp().processEvents()
    viewer.screenshot(args.out, canvas_only=False)
    viewer.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
