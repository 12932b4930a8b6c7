"""The napari plugin, headless: its npe2 manifest, the reader on a sweep, a video and a
recon3d volume through napari's reader API, the reconstruction widget."""

from __future__ import annotations

import numpy as np
import pytest

napari = pytest.importorskip("napari")  # the napari extra (installed in CI)
npe2 = pytest.importorskip("npe2")

from gui.napari_plugin import MANIFEST  # noqa: E402
from gui.napari_plugin.widget import reconstruct_layer  # noqa: E402
from instrument.reconstruct_files import write_volume  # noqa: E402
from tests.instrument.test_ome import FPS, PITCH_UM, _sweep, _video  # noqa: E402


@pytest.fixture(scope="module")
def plugin():
    pm = npe2.PluginManager.instance()
    manifest = npe2.PluginManifest.from_file(MANIFEST)
    if manifest.name not in pm._manifests:
        pm.register(manifest)
    yield manifest.name


def _open(path, plugin):
    from napari.components import ViewerModel

    viewer = ViewerModel()
    layers = viewer.open(str(path), plugin=plugin)
    return viewer, {layer.name: layer for layer in layers}


def test_manifest_validates_and_names_its_contributions():
    manifest = npe2.PluginManifest.from_file(MANIFEST)
    assert [r.command for r in manifest.contributions.readers] == ["diffuserlab.get_reader"]
    assert manifest.contributions.widgets[0].autogenerate


def test_reader_on_a_sweep_frames_tags_and_products(tmp_path, plugin):
    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 10.5, 11.0])
    store.write_product("dark_mean", np.full((16, 20), 3, np.float32))
    store.write_product("slm_lut", np.zeros(256))  # no image: no layer
    _, layers = _open(store.path, plugin)
    assert sorted(layers) == ["s.zarr dark_mean", "s.zarr frames", "s.zarr psf_stack"]
    frames = layers["s.zarr frames"]
    assert frames.data.shape == (6, 16, 20)
    assert int(np.asarray(frames.data[3])[0, 0]) == 3  # read lazily, verified
    assert frames.metadata["tags"] == ["psf", "dark"] * 3
    assert list(frames.axis_labels) == ["z_mm", "y", "x"]
    assert str(frames.units[-1]) == "micrometer"
    assert list(frames.scale[-2:]) == pytest.approx([2 * PITCH_UM] * 2)
    psf = layers["s.zarr psf_stack"]
    assert list(psf.axis_labels) == ["z", "y", "x"]
    assert psf.scale[0] == pytest.approx(500.0) and psf.metadata["depths_mm"][1] == 10.5


def test_reader_on_a_video_with_its_time_axis(tmp_path, plugin):
    store = _video(tmp_path / "v.zarr")
    store.create_frame_product("recon_admm", store.n_frames, (6, 8), bin_factor=2)
    store.write_product_frame("recon_admm", 0, np.full((6, 8), 7.0))
    _, layers = _open(store.path, plugin)
    frames = layers["v.zarr frames"]
    assert list(frames.axis_labels)[0] == "t" and str(frames.units[0]) == "second"
    assert frames.scale[0] == pytest.approx(1 / FPS)
    recon = layers["v.zarr recon_admm"]
    assert recon.data.shape == (6, 6, 8) and recon.scale[-1] == pytest.approx(2 * PITCH_UM)
    assert float(np.asarray(recon.data[0])[0, 0]) == 7.0
    assert float(np.asarray(recon.data[1]).max()) == 0.0  # not computed yet


def test_reader_on_a_recon3d_volume(tmp_path, plugin):
    path = tmp_path / "vol.zarr"
    write_volume(path, np.ones((3, 8, 10), np.float32), {"depths_mm": [1.0, 2.0, 4.0]},
                 pitch_um=6.9)
    _, layers = _open(path, plugin)
    (layer,) = layers.values()
    assert layer.data.shape == (3, 8, 10) and list(layer.axis_labels) == ["plane", "y", "x"]
    assert layer.metadata["depths_mm"] == [1.0, 2.0, 4.0]
    assert layer.scale[-1] == pytest.approx(6.9)


def test_reader_declines_other_folders(tmp_path):
    from gui.napari_plugin.reader import get_reader

    (tmp_path / "x.zarr").mkdir()
    assert get_reader(str(tmp_path / "x.zarr")) is None


def test_widget_reconstructs_the_shown_frame_with_a_runs_psf(tmp_path, plugin):
    from napari.layers import Image

    rng = np.random.default_rng(1)
    n = 32
    psf = np.zeros((n, n), np.float32)
    psf[rng.integers(4, n - 4, 12), rng.integers(4, n - 4, 12)] = 1.0
    scene = np.zeros((n, n), np.float32)
    scene[12:18, 10:14] = 1.0
    from scipy.signal import fftconvolve

    raw = fftconvolve(scene, psf, mode="same") * 500 + 20 + rng.normal(0, 1, (n, n))
    store = _sweep(tmp_path / "psf.zarr", n_points=1, shape=(n, n))
    store.write_product("psf_stack", psf[None], depths_mm=[10.0])
    layer = Image(np.stack([np.zeros_like(raw), raw]), name="raw", scale=(1, 3.45, 3.45))

    class Viewer:  # the plane napari shows: frame 1
        class dims:
            current_step = (1, 0, 0)

    data, kwargs, kind = reconstruct_layer(layer, store.path, method="admm",
                                           iterations=30, viewer=Viewer)
    assert kind == "image" and data.shape == (n, n)
    assert kwargs["scale"] == pytest.approx([3.45, 3.45])
    assert kwargs["metadata"]["depth_mm"] == 10.0
    inside, outside = data[scene > 0].mean(), data[scene == 0].mean()
    assert inside > 3 * outside  # the object is found, not the raw's blur
    # napari's widget machinery builds the form from the manifest's function
    widget = npe2.PluginManager.instance().get_manifest(plugin).contributions.widgets[0]
    assert widget.get_callable() is not None


def test_widget_form_from_the_manifest_reconstructs(tmp_path, plugin, qapp):
    """The widget napari builds from the manifest (magicgui on the function; a canvas
    needs OpenGL, which the offscreen platform lacks, so no viewer window)."""
    from napari.layers import Image

    rng = np.random.default_rng(2)
    n = 24
    psf = np.zeros((n, n), np.float32)
    psf[rng.integers(3, n - 3, 8), rng.integers(3, n - 3, 8)] = 1.0
    store = _sweep(tmp_path / "psf.zarr", n_points=1, shape=(n, n))
    store.write_product("psf_stack", psf[None], depths_mm=[10.0])
    contribution = npe2.PluginManager.instance().get_manifest(plugin).contributions.widgets[0]
    widget = contribution.get_callable()()  # autogenerate: a magicgui factory
    assert list(widget.method.choices) == ["auto", "admm", "fista", "wiener"]
    layer = Image(rng.random((n, n)).astype(np.float32) * 100 + 10, name="raw")
    widget.layer.choices = [layer]  # (napari fills it with the viewer's image layers)
    widget.layer.value = layer
    widget.psf_run.value = store.path
    widget.method.value = "wiener"
    data, kwargs, kind = widget()
    assert kind == "image" and data.shape == (n, n) and kwargs["name"] == "raw recon 10 mm"
