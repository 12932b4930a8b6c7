"""The napari plugin (npe2; install the ``napari`` extra): a reader for run stores and
recon3d volumes (:mod:`gui.napari_plugin.reader`) and a widget that reconstructs the
current layer with a run's PSF (:mod:`gui.napari_plugin.widget`).

The manifest is ``napari.yaml`` beside this file, registered under the
``napari.manifest`` entry point; nothing here imports napari until napari calls in.
"""

from pathlib import Path

__all__ = ["MANIFEST"]

#: The plugin's npe2 manifest.
MANIFEST = Path(__file__).with_name("napari.yaml")
