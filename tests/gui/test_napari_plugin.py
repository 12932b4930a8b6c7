"""The napari plugin, headless: its npe2 manifest, the reader on a sweep, a video, a
product's own folder, a run of the layout before the image groups and a recon3d
volume through napari's reader API, napari's own reader on a product, the
reconstruction widget (one depth and a stack)."""

from __future__ import annotations

import numpy as np
import pytest

napari = pytest.importorskip("napari")  # the napari extra (installed in CI)
npe2 = pytest.importorskip("npe2")

from gui.napari_plugin import MANIFEST  # noqa: E402
from gui.napari_plugin.widget import reconstruct_layer  # noqa: E402
from instrument.writer.products import write_volume  # noqa: E402
from recon.errors import ReconInputError  # noqa: E402
from tests.instrument.test_ome import (  # noqa: E402
    BINNING,
    FPS,
    PITCH_UM,
    _strip_to_legacy,
    _sweep,
    _to_old_layout,
    _video,
)


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
    widget = manifest.contributions.widgets[0]
    assert widget.command == "diffuserlab.reconstruct_widget" and not widget.autogenerate


def test_reader_on_a_sweep_frames_tags_and_products(tmp_path, plugin):
    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 10.5, 11.0])
    store.write_product("dark_mean", np.full((16, 20), 3, np.float32))
    store.write_product("slm_lut", np.zeros(256))  # no image: no layer
    _, layers = _open(store.path, plugin)
    assert sorted(layers) == ["s.zarr dark_mean", "s.zarr frames", "s.zarr psf_stack"]
    frames = layers["s.zarr frames"]
    # the frames' axis (OME ``t``, unitless: the acquisition order) is napari's
    # ``frame``, in front of a t of one frame and a z of one plane (kept apart from a
    # video's t and a volume's z)
    assert list(frames.axis_labels) == ["frame", "t", "z", "y", "x"]
    assert frames.data.shape == (6, 1, 1, 16, 20)
    assert int(np.asarray(frames.data[3]).ravel()[0]) == 3  # read lazily, verified
    assert frames.metadata["tags"] == ["psf", "dark"] * 3
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
    # t, then a z of one plane (a volume's z stays apart from t in the viewer)
    assert list(frames.axis_labels)[:2] == ["t", "z"] and frames.data.shape == (6, 1, 12, 16)
    assert [str(u) for u in frames.units] == ["second", "micrometer"] + ["micrometer"] * 2
    assert frames.scale[0] == pytest.approx(1 / FPS)
    recon = layers["v.zarr recon_admm"]
    assert recon.data.shape == (6, 1, 6, 8) and recon.scale[-1] == pytest.approx(2 * PITCH_UM)
    assert float(np.asarray(recon.data[0])[0, 0, 0]) == 7.0
    assert float(np.asarray(recon.data[1]).max()) == 0.0  # not computed yet


def test_reader_on_an_imported_psf_stack_shows_the_stack(tmp_path, plugin):
    """A run made by ``runs import-psf`` has no frames: no empty frames layer (napari
    cannot show one), its PSF stack shown."""
    from instrument.runs.stacks import import_psf_stack

    np.save(tmp_path / "psf.npy", np.full((3, 16, 20), 2, np.float32))
    store = import_psf_stack(tmp_path / "psf.npy", tmp_path / "imp.zarr",
                             depths_mm=[10.0, 10.5, 11.0])
    _, layers = _open(store.path, plugin)
    assert sorted(layers) == ["imp.zarr psf_stack"]
    assert layers["imp.zarr psf_stack"].data.shape == (3, 16, 20)


def test_reader_on_a_products_own_folder(tmp_path, plugin):
    """``RUN.zarr/products/NAME`` (an OME-Zarr image group) opens as that product's
    layer, read through its run (verified); a table's folder gives none."""
    store = _video(tmp_path / "v.zarr")
    store.create_frame_product("recon_admm", store.n_frames, (6, 8), bin_factor=2)
    store.write_product_frame("recon_admm", 2, np.full((6, 8), 5.0))
    store.write_product("lut", np.arange(9.0))
    for folder in ("products/recon_admm", "products/recon_admm/0"):
        _, layers = _open(store.path / folder, plugin)
        (layer,) = layers.values()
        assert layer.name == "v.zarr recon_admm" and layer.data.shape == (6, 1, 6, 8)
        # binned axes named y_bin2, x_bin2, or (OME axes t, c, z, y, x) y, x
        assert list(layer.axis_labels) in (["t", "z", "y_bin2", "x_bin2"],
                                           ["t", "z", "y", "x"])
        assert str(layer.units[0]) == "second" and layer.scale[0] == pytest.approx(1 / FPS)
        assert float(np.asarray(layer.data[2])[0, 0, 0]) == 5.0
    from gui.napari_plugin.reader import get_reader, read_product

    assert get_reader(str(store.path / "products/lut")) is read_product
    assert read_product(str(store.path / "products/lut")) == []
    assert get_reader(str(store.path / "products")) is None
    assert get_reader(str(store.path / "products/recon_admm__done")) is None


def test_napari_own_reader_shows_a_product_as_one_image(tmp_path, plugin):
    """napari's builtin reader (no plugin of ours) opens a product's group as one image,
    not the products as levels of a pyramid. (Its layer data, through npe2: with its
    layers made in a ViewerModel here, a later test of the GUI folder crashed.)"""
    pm = npe2.PluginManager.instance()
    registered = "napari" in pm._manifests
    if not registered:  # the builtins alone (discovering every plugin installed is not
        # this test's business, and leaves them loaded for the tests after it)
        pm.register(npe2.PluginManifest.from_distribution("napari"))
    try:
        _napari_reads_one_image(tmp_path)
    finally:
        if not registered:
            pm.unregister("napari")


def _napari_reads_one_image(tmp_path):
    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 10.5, 11.0])
    store.write_product("dark_mean", np.full((16, 20), 3, np.float32))
    def levels(name):  # the layer data napari's reader gives: its pyramid levels
        (layer,) = npe2.read([str(store.path / "products" / name)], plugin_name="napari",
                             stack=False)
        assert layer[2:] in ((), ("image",))  # an image
        return layer[0] if isinstance(layer[0], list) else [layer[0]]

    # one level: the product's array, not every array of products/ as a pyramid; a
    # stack's group also holds its depth coordinate z, which napari's reader (every
    # array of the group a level) takes for a second level, so napari refuses that
    # layer: docs/open-data.md says so (the plugin reads the stack)
    assert [level.shape for level in levels("psf_stack")] == [(3, 16, 20), (3,)]
    (dark,) = levels("dark_mean")
    assert float(np.asarray(dark)[0, 0]) == 3.0


def test_reader_on_a_run_of_the_layout_before(tmp_path, plugin):
    """A run written before the image groups (and before the OME-Zarr description):
    the same layers, axes computed as for a new run; after runs upgrade, the same."""
    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack", np.full((3, 16, 20), 2, np.float32),
                        depths_mm=[10.0, 10.5, 11.0])
    store.write_product("dark_mean", np.full((16, 20), 3, np.float32))
    _to_old_layout(store.path)
    _strip_to_legacy(store.path)
    _, old = _open(store.path, plugin)
    assert sorted(old) == ["s.zarr dark_mean", "s.zarr frames", "s.zarr psf_stack"]
    assert list(old["s.zarr psf_stack"].axis_labels) == ["z", "y", "x"]
    assert float(np.asarray(old["s.zarr psf_stack"].data)[1, 0, 0]) == 2.0
    from instrument.runs.runstore import RunStore

    RunStore.open(store.path, "r+").upgrade()
    _, new = _open(store.path, plugin)
    assert sorted(new) == sorted(old)
    for name, layer in new.items():
        assert list(layer.axis_labels) == list(old[name].axis_labels)
        assert list(layer.scale) == pytest.approx(list(old[name].scale))


def test_reader_on_a_recon3d_volume(tmp_path, plugin):
    path = tmp_path / "vol.zarr"
    write_volume(path, np.ones((3, 8, 10), np.float32), {"depths_mm": [1.0, 2.0, 4.0]},
                 pitch_um=6.9)
    _, layers = _open(path, plugin)
    (layer,) = layers.values()
    # uneven depths: a ``plane`` axis, or (OME axes t, c, z, y, x) z from the first depth
    assert layer.data.shape == (3, 8, 10) and list(layer.axis_labels)[1:] == ["y", "x"]
    assert (layer.axis_labels[0], layer.translate[0]) in (("plane", 0.0), ("z", 1000.0))
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
                                           iterations=30, dark="20", viewer=Viewer)
    assert kind == "image" and data.shape == (n, n)
    # the PSF run's pitch (its camera's 3.45 um binned by 2), as recon3d scales it
    assert kwargs["scale"] == pytest.approx([PITCH_UM * BINNING] * 2)
    assert kwargs["units"] == ["micrometer"] * 2
    assert kwargs["metadata"]["depth_mm"] == 10.0
    inside, outside = data[scene > 0].mean(), data[scene == 0].mean()
    assert inside > 3 * outside  # the object is found, not the raw's blur
    # the run's PSF is dark-subtracted: auto needs the frames' level, as the commands do
    with pytest.raises(ReconInputError, match="dark"):
        reconstruct_layer(layer, store.path, method="wiener", viewer=Viewer)


def _solve(widget, wait):
    """Press Reconstruct and wait for its end (the widget's ``done``): the layer data,
    or None when refused."""
    ends = []
    widget.done.connect(ends.append)
    widget.run()
    wait(lambda: ends, 120.0, "the widget's reconstruction")
    widget.done.disconnect(ends.append)
    return ends[0]


def test_widget_form_from_the_manifest_reconstructs(tmp_path, plugin, wait):
    """The widget napari docks from the manifest, its options generated from the
    reconstruction's declaration with the command line's defaults (a canvas needs
    OpenGL, which the offscreen platform lacks, so a viewer model, no window)."""
    from napari.components import ViewerModel

    from instrument.cli import build_parser

    rng = np.random.default_rng(2)
    n = 24
    psf = np.zeros((n, n), np.float32)
    psf[rng.integers(3, n - 3, 8), rng.integers(3, n - 3, 8)] = 1.0
    store = _sweep(tmp_path / "psf.zarr", n_points=1, shape=(n, n))
    store.write_product("psf_stack", psf[None], depths_mm=[10.0])
    contribution = npe2.PluginManager.instance().get_manifest(plugin).contributions.widgets[0]
    viewer = ViewerModel()
    widget = contribution.get_callable()(napari_viewer=viewer)  # as napari docks it
    try:
        cli = build_parser().parse_args(["recon", "--psf", "p.npy", "--raw", "r.npy"])
        fields = widget.form.widgets
        assert fields["iterations"].value() == cli.iterations == 200  # not 100
        method = fields["method"]
        assert [method.itemText(i) for i in range(method.count())] == [
            "auto", "wiener", "gd", "fista", "admm"]
        assert method.currentText() == cli.method
        assert fields["dark"].placeholderText() == cli.dark == "auto"
        viewer.add_image(rng.random((n, n)).astype(np.float32) * 100 + 10, name="raw")
        assert widget.layer.currentText() == "raw"  # the viewer's image layers, offered
        widget.psf_run.setText(str(store.path))
        method.setCurrentText("wiener")
        # dark auto with a calibration run's PSF and a layer of no run: refused, the
        # message naming the widget's field, not the command line's flag
        assert _solve(widget, wait) is None and "raw recon 10 mm" not in viewer.layers
        assert "'dark level'" in widget.error.text() and "--dark" not in widget.error.text()
        fields["dark"].setText("10")
        data, kwargs, kind = _solve(widget, wait)
        assert kind == "image" and data.shape == (n, n) and kwargs["name"] == "raw recon 10 mm"
        assert "raw recon 10 mm" in viewer.layers and widget.error.text() == ""
        assert kwargs["metadata"]["dark"] == "10" and kwargs["metadata"]["method"] == "wiener"
        fields["iterations"].setValue(fields["iterations"].minimum())
        fields["tv"].setCurrentText("-1")
        assert _solve(widget, wait) is None and widget.error.text().startswith("'TV weight")
    finally:  # not left to the collector (see tests/gui/conftest.py): deleted by the
        # GUI thread's event loop
        widget.close()
        widget.deleteLater()


def test_widget_reconstructs_a_volume_with_a_psf_stack(tmp_path, plugin):
    """A run's PSF stack of several depths and no depth asked for: the whole stack, a
    volume layer whose first axis is the depths' (``z`` in micrometer when evenly
    spaced, as a stored volume's; else ``plane`` with the depths in its metadata)."""
    from napari.layers import Image
    from scipy.signal import fftconvolve

    from instrument.runs.ome import volume_axes

    rng = np.random.default_rng(3)
    n, pitch = 32, 3.45
    psfs = np.zeros((3, n, n), np.float32)
    for k in range(3):
        psfs[k, rng.integers(4, n - 4, 6 + 2 * k), rng.integers(4, n - 4, 6 + 2 * k)] = 1.0
    scene = np.zeros((3, n, n), np.float32)
    scene[1, 12:18, 10:14] = 1.0
    raw = sum(fftconvolve(scene[k], psfs[k], mode="same") for k in range(3)) * 500 + 20
    layer = Image(raw.astype(np.float32), name="raw", scale=(pitch, pitch))
    # uneven depths: ``plane`` (no unit), or, with the OME axes t, c, z, y, x, ``z`` at
    # their mean spacing from the first depth (instrument.runs.ome.volume_axes: either)
    uneven = ("plane", 1.0, "pixel") if volume_axes([10.0, 11.0, 13.0], 3)[0].name == \
        "plane" else ("z", 1500.0, "micrometer")
    for depths, first in (([10.0, 10.5, 11.0], ("z", 500.0, "micrometer")),
                          ([10.0, 11.0, 13.0], uneven)):
        store = _sweep(tmp_path / f"psf{depths[-1]:g}.zarr", n_points=1, shape=(n, n))
        store.write_product("psf_stack", psfs, depths_mm=depths)
        data, kwargs, kind = reconstruct_layer(layer, store.path, method="admm",
                                               iterations=5, dark="20")
        assert kind == "image" and data.shape == (3, n, n) and data.dtype == np.float32
        assert kwargs["name"] == "raw volume"
        assert kwargs["axis_labels"] == [first[0], "y", "x"]
        run_pitch = PITCH_UM * BINNING  # the PSF run's, not the layer's, as recon3d's
        assert kwargs["scale"] == pytest.approx([first[1], run_pitch, run_pitch])
        assert kwargs["units"][0] == first[2]
        assert kwargs["metadata"]["depths_mm"] == depths
        volume = Image(data, **{k: kwargs[k] for k in ("scale", "axis_labels", "units")})
        assert list(volume.axis_labels) == [first[0], "y", "x"]


def _scene_and_psf(n, seed):
    from scipy.signal import fftconvolve

    rng = np.random.default_rng(seed)
    psf = np.zeros((n, n), np.float32)
    psf[rng.integers(4, n - 4, 12), rng.integers(4, n - 4, 12)] = 1.0
    scene = np.zeros((n, n), np.float32)
    scene[12:18, 10:14] = 1.0
    return scene, psf, fftconvolve(scene, psf, mode="same") * 500


def _docked(plugin, viewer):
    contribution = npe2.PluginManager.instance().get_manifest(plugin).contributions.widgets[0]
    return contribution.get_callable()(napari_viewer=viewer)


def test_widget_on_a_recorded_runs_frames_with_a_calibration_runs_psf(tmp_path, plugin,
                                                                      wait):
    """The documented case: a recorded run's frames (opened with the reader) and one
    depth of a calibration run, every option at the command line's default (dark
    auto): the level recorded with the frames is used, as ``recon-run`` uses it."""
    from napari.components import ViewerModel

    from instrument.runs.runstore import RunStore
    from instrument.runs.runstore_records import VIDEO_PLAN

    n, offset = 32, 20
    scene, psf, blurred = _scene_and_psf(n, 4)
    raw = np.clip(blurred + offset, 0, 255).astype(np.uint8)
    video = RunStore.create(tmp_path / "video.zarr", plan_name=VIDEO_PLAN,
                            plan_params={"frames": 2}, points=[{}],
                            frame_tags=[["video"] * 2], frame_shape=(n, n),
                            frame_dtype=np.uint8, coord_names=["exposure_s"])
    video.update_attrs(camera={"id": "cam", "pixel_pitch_um": PITCH_UM,
                               "frame_rate_hz": FPS},
                       simulated={"dark_offset_dn": float(offset)})
    video.write_frames(0, np.stack([raw, raw]), np.full((2, 1), 0.01))
    calibration = _sweep(tmp_path / "psf.zarr", n_points=3, shape=(n, n))
    calibration.write_product("psf_stack", np.stack([psf * 0, psf, psf * 0]),
                              depths_mm=[10.0, 11.0, 12.0])
    viewer = ViewerModel()
    viewer.open(str(video.path), plugin=plugin)
    widget = _docked(plugin, viewer)
    try:
        widget.layer.setCurrentText("video.zarr frames")
        widget.psf_run.setText(str(calibration.path))
        widget.depth.setValue(11.0)
        data, kwargs, _ = _solve(widget, wait)
        assert widget.error.text() == "" and kwargs["metadata"]["depth_mm"] == 11.0
        assert kwargs["metadata"]["dark"] == "auto"
        assert data[scene > 0].mean() > 3 * data[scene == 0].mean()
    finally:
        widget.close()
        widget.deleteLater()


def test_widget_takes_a_plain_psf_image_file_or_layer(tmp_path, plugin, wait):
    """A 2-D PSF without depths, as a .npy or TIFF file or as a 2-D layer of the viewer:
    its one plane, the dark level at its default (auto: the PSF's dark corner)."""
    import tifffile
    from napari.components import ViewerModel

    n = 32
    scene, psf, blurred = _scene_and_psf(n, 5)
    np.save(tmp_path / "psf.npy", psf + 20)
    tifffile.imwrite(tmp_path / "psf.tif", psf + 20)
    viewer = ViewerModel()
    viewer.add_image((blurred + 20).astype(np.float32), name="raw")
    viewer.add_image(psf + 20, name="psf layer")
    widget = _docked(plugin, viewer)
    try:
        widget.layer.setCurrentText("raw")
        for given in (str(tmp_path / "psf.npy"), str(tmp_path / "psf.tif"), "psf layer"):
            widget.psf_run.setText(given)
            data, kwargs, _ = _solve(widget, wait)
            assert widget.error.text() == "", given
            assert kwargs["name"] == "raw recon" and data.shape == (n, n)
            assert data[scene > 0].mean() > 3 * data[scene == 0].mean(), given
            viewer.layers.remove("raw recon")
    finally:
        widget.close()
        widget.deleteLater()


def test_widget_solves_on_a_worker_thread(tmp_path, plugin, wait, monkeypatch):
    """The solve runs on a worker: while it is held, the GUI thread's event loop runs
    (a queued call is delivered) and nothing is added; released, the layer comes."""
    import threading

    from napari.components import ViewerModel
    from PySide6.QtCore import QTimer

    import gui.napari_plugin.widget as module

    n = 32
    _, psf, blurred = _scene_and_psf(n, 6)
    np.save(tmp_path / "psf.npy", psf + 20)
    release, solving, real = threading.Event(), threading.Event(), module.solve_in_process
    threads = []

    def held(*args, **kwargs):
        threads.append(threading.current_thread())
        solving.set()
        release.wait(120.0)  # hang guard: the test sets it
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "solve_in_process", held)
    viewer = ViewerModel()
    viewer.add_image((blurred + 20).astype(np.float32), name="raw")
    widget = _docked(plugin, viewer)
    ends, ticks = [], []
    widget.done.connect(ends.append)
    try:
        widget.psf_run.setText(str(tmp_path / "psf.npy"))
        widget.run()
        wait(solving.is_set, 60.0, "the worker's solve to start")
        QTimer.singleShot(0, lambda: ticks.append(1))
        wait(lambda: ticks, 60.0, "the event loop while the solve is held")
        assert not ends and "raw recon" not in viewer.layers
        assert not widget.button.isEnabled()  # one solve at a time
        release.set()
        wait(lambda: ends, 120.0, "the reconstruction")
        assert ends[0][1]["name"] == "raw recon" and "raw recon" in viewer.layers
        assert widget.button.isEnabled()
        assert threads and threads[0] is not threading.main_thread()  # off the GUI thread
    finally:
        release.set()
        widget.close()
        widget.deleteLater()


def test_a_volume_and_a_video_in_one_viewer_keep_their_units(tmp_path, plugin):
    """A recon3d volume's z (micrometer) and a video's t (second) on separate viewer
    axes: the layers' units agree axis by axis, so napari keeps them (with a clash it
    drops them: "Inconsistent units across layers", when the layer list's units are
    None)."""
    from napari.components import ViewerModel

    video = _video(tmp_path / "v.zarr")
    path = tmp_path / "vol.zarr"
    write_volume(path, np.ones((3, 12, 16), np.float32), {"depths_mm": [1.0, 1.5, 2.0]},
                 pitch_um=PITCH_UM)
    viewer = ViewerModel()
    viewer.open(str(video.path), plugin=plugin)
    viewer.open(str(path), plugin=plugin)
    units = viewer.layers.extent.units
    assert units is not None  # napari's condition for its unit warning
    assert [str(u) for u in units] == ["second", "micrometer", "micrometer", "micrometer"]
    assert tuple(viewer.dims.axis_labels) == ("t", "z", "y", "x")  # t and z apart
    # t: the video's frames; z: the volume's planes (from 0, or from its first depth
    # where the volume records it), at the volume's spacing, not in micrometre steps
    assert viewer.dims.nsteps[0] == 6 and viewer.dims.nsteps[1] in (3, 5)


def test_a_calibration_run_and_a_video_in_one_viewer_keep_their_units(tmp_path, plugin):
    """A sweep's frames (unitless order), a grid's ``c`` and planes of unknown depth
    beside a video's t (second) and a stack's z (micrometer): each on its own viewer
    axis, so the units agree axis by axis (they clashed: napari's "Inconsistent units
    across layers" for the frames with a video, and for a grid run alone)."""
    from napari.components import ViewerModel

    store = _sweep(tmp_path / "s.zarr")
    store.write_product("psf_stack", np.ones((3, 16, 20), np.float32),
                        depths_mm=[10.0, 10.5, 11.0])
    store.write_product("psf_grid_registered", np.ones((4, 16, 20), np.float32))
    store.write_product("bead_images", np.ones((4, 16, 20), np.float32), bin_factor=1)
    video = _video(tmp_path / "v.zarr")
    viewer = ViewerModel()
    viewer.open(str(store.path), plugin=plugin)
    assert viewer.layers.extent.units is not None  # the calibration run alone
    viewer.open(str(video.path), plugin=plugin)
    units = viewer.layers.extent.units
    assert units is not None  # napari's condition for its unit warning
    assert [str(u) for u in units] == ["pixel", "second"] + ["micrometer"] * 3
    # the unitless axes share the first viewer axis (its label one layer's)
    assert tuple(viewer.dims.axis_labels)[1:] == ("t", "z", "y", "x")
    layers = {layer.name: layer for layer in viewer.layers}
    assert list(layers["s.zarr psf_grid_registered"].axis_labels)[:3] == ["c", "t", "z"]
    assert list(layers["s.zarr bead_images"].axis_labels)[0] == "plane"
    # the sweep's 6 frames, the video's 6 frames at its interval, the stack's 3 planes
    assert viewer.dims.nsteps[0] == 6 and viewer.dims.nsteps[1] == 6
    assert layers["s.zarr psf_stack"].translate[0] == pytest.approx(10000.0)
