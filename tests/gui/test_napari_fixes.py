"""napari, issue 67: a ``calibrate psf-from-scenes`` run's colour PSF opens as layers
(it opened as none, silently); a TIFF/.npy stack without depths is refused as "the
depths are missing", and the widget's depths field gives them."""

from __future__ import annotations

import numpy as np
import pytest

napari = pytest.importorskip("napari")

from gui.napari_plugin.reader import read_product, read_run  # noqa: E402
from gui.napari_plugin.widget import reconstruct_layer  # noqa: E402
from instrument.runs.runstore import RunStore, RunStoreError  # noqa: E402


def test_a_colour_psf_from_scenes_run_opens_one_layer_per_channel(tmp_path):
    store = RunStore.create(tmp_path / "cal.zarr", plan_name="psf-from-scenes",
                            plan_params={}, points=[{}], frame_tags=[[]],
                            frame_shape=(24, 32), frame_dtype=np.float32, coord_names=[])
    psf = np.random.default_rng(0).random((1, 24, 32, 3)).astype(np.float32)
    store.write_product("psf_stack", psf, depths_mm=[20.0], channels=["R", "G", "B"],
                        units="DN")
    layers = read_run(str(store.path))
    assert [kw["name"] for _, kw, _ in layers] == [f"cal.zarr psf_stack {c}" for c in "RGB"]
    assert [kw["colormap"] for _, kw, _ in layers] == ["red", "green", "blue"]
    for k, (data, kw, kind) in enumerate(layers):
        np.testing.assert_array_equal(np.asarray(data), psf[..., k])
        assert kind == "image" and kw["axis_labels"] == ["z", "y", "x"]
        assert kw["metadata"]["depths_mm"] == [20.0]
    assert len(read_product(str(store.path / "products" / "psf_stack"))) == 3


def test_a_stack_without_depths_is_named_and_the_depths_field_gives_them(tmp_path):
    import tifffile
    from napari.layers import Image

    rng = np.random.default_rng(2)
    stack = np.zeros((3, 32, 32), np.float32)
    for k in range(3):
        stack[k, rng.integers(4, 28, 8), rng.integers(4, 28, 8)] = 1.0
    stack += 20  # the dark level of the raw and the PSF
    np.save(tmp_path / "s.npy", stack)
    tifffile.imwrite(tmp_path / "s.tif", stack)  # a TIFF with no depths recorded
    layer = Image(((stack - 20).sum(0) * 100 + 20).astype(np.float32), name="raw")
    for path in (tmp_path / "s.npy", tmp_path / "s.tif"):
        with pytest.raises(RunStoreError, match="the depths are missing") as refused:
            reconstruct_layer(layer, path, dark="20", method="admm", iterations=3)
        assert "stack reader" not in str(refused.value)
        assert "'depths (mm)'" in str(refused.value)
        data, kwargs, _ = reconstruct_layer(layer, path, dark="20", method="admm",
                                            iterations=3, depths_mm=[10.0, 11.0, 12.0])
        assert data.shape == (3, 32, 32)
        assert kwargs["metadata"]["depths_mm"] == [10.0, 11.0, 12.0]


def test_the_widget_reads_its_depths_field(qapp):
    from napari.components import ViewerModel

    from diffuserlab.errors import InputError
    from gui.napari_plugin.widget import ReconstructWidget

    widget = ReconstructWidget(ViewerModel())
    try:
        assert widget.depths_mm() is None
        widget.depths.setText("20, 25 40")
        assert widget.depths_mm() == [20.0, 25.0, 40.0]
        widget.depths.setText("20, x")
        with pytest.raises(InputError, match="depths"):
            widget.depths_mm()
    finally:
        widget.close()
        widget.deleteLater()
