"""The Results panel shows a reconstruction as the live view does: turned upright from
the model grid it is stored on (``recon.io.DATA_ORIENTATION``), and says so; frames and
PSFs, which carry no such orientation, as the sensor saw them."""

from __future__ import annotations

import numpy as np
import pytest

from instrument.runs.runstore import RunStoreError
from recon.io import DATA_ORIENTATION


def _asymmetric(shape=(12, 16)) -> np.ndarray:
    image = np.zeros(shape, np.float32)
    image[1:3, 2:5] = 1.0  # one corner lit: any flip moves it
    return image


def _run(path):
    from instrument.runs.runstore import RunStore

    n = 2
    store = RunStore.create(path, plan_name="video", plan_params={},
                            points=[{"t": float(k)} for k in range(n)],
                            frame_tags=[["frame"]] * n, frame_shape=(12, 16),
                            frame_dtype=np.uint16, coord_names=["exposure_s"])
    for i in range(n):
        store.write_frame(i, (1000 * _asymmetric()).astype(np.uint16), {"exposure_s": 0.01})
    store.create_frame_product("recon_admm", n, (12, 16), np.float32,
                               orientation=DATA_ORIENTATION)
    for i in range(n):
        store.write_product_frame("recon_admm", i, _asymmetric())
    store.write_product("psf_stack", _asymmetric()[None].repeat(2, 0), depths_mm=[1.0, 2.0])
    store.update_attrs(status="complete")
    return store


def test_a_reconstruction_product_is_shown_upright_and_a_psf_as_stored(qapp, wait, tmp_path):
    from gui.panels.results import UPRIGHT, ResultsPanel

    _run(tmp_path / "v.zarr")
    panel = ResultsPanel()
    job = panel.open(str(tmp_path / "v.zarr"))
    wait(lambda: job.done, 30, "the run")
    job = panel.show_product("recon_admm")
    wait(lambda: job.done, 30, "the product")
    np.testing.assert_array_equal(panel.volume[0], _asymmetric()[::-1, ::-1])
    assert panel.view.title().endswith(UPRIGHT)
    job = panel.show_product("psf_stack")
    wait(lambda: job.done, 30, "the PSF stack")
    np.testing.assert_array_equal(panel.volume[0], _asymmetric())
    assert UPRIGHT not in panel.view.title()


def test_a_reconstructed_tiff_is_shown_upright(qapp, wait, tmp_path):
    import tifffile

    from gui.panels.results import UPRIGHT, ResultsPanel

    tifffile.imwrite(tmp_path / "r.tif", _asymmetric(),
                     metadata={"orientation": {"png": "scene, upright",
                                               "tiff": DATA_ORIENTATION}})
    tifffile.imwrite(tmp_path / "raw.tif", _asymmetric(), metadata={"exposure_s": 0.01})
    panel = ResultsPanel()
    job = panel.open(str(tmp_path / "r.tif"))
    wait(lambda: job.done, 30, "the image")
    shown = panel.view.image
    np.testing.assert_array_equal(shown, _asymmetric()[::-1, ::-1])
    assert UPRIGHT in panel.view.title()
    job = panel.open(str(tmp_path / "raw.tif"))
    wait(lambda: job.done, 30, "the raw")
    np.testing.assert_array_equal(panel.view.image, _asymmetric())


def test_a_recon3d_volume_and_an_exported_stack_are_read_with_their_depths(tmp_path):
    import zarr

    from gui.panels.results import read_result
    from instrument.writer.products import write_volume

    volume = np.stack([_asymmetric(), 2 * _asymmetric()])
    write_volume(tmp_path / "v.zarr", volume, {"depths_mm": [1.0, 2.0],
                                               "orientation": DATA_ORIENTATION})
    got = read_result(str(tmp_path / "v.zarr"))  # an OME-Zarr image: the volume at 0
    assert got["kind"] == "volume" and got["depths_mm"] == [1.0, 2.0]
    assert got["array"].shape == volume.shape and "ome" not in got["text"]
    old = tmp_path / "old.zarr"  # a bare array, as recon3d wrote before
    arr = zarr.create_array(str(old), shape=volume.shape, dtype="float32")
    arr[:] = volume
    arr.attrs["depths_mm"] = [1.0, 2.0]
    assert read_result(str(old))["depths_mm"] == [1.0, 2.0]


def test_a_products_own_folder_is_read_through_its_run(tmp_path):
    """``RUN.zarr/products/NAME`` (an OME-Zarr image group) shows that product as the
    run's product list does: verified, a reconstruction upright."""
    from gui.panels.results import read_result

    store = _run(tmp_path / "v.zarr")
    got = read_result(str(store.path / "products" / "recon_admm"))
    assert got["kind"] == "volume" and got["upright"]
    np.testing.assert_array_equal(got["array"][0], _asymmetric()[::-1, ::-1])
    got = read_result(str(store.path / "products" / "psf_stack"))
    assert got["depths_mm"] == [1.0, 2.0] and "upright" not in got
    (store.path / "products/psf_stack/0/c/1/0/0").unlink()  # a plane deleted: named
    with pytest.raises(RunStoreError, match="product 'psf_stack'.*plane 1"):
        read_result(str(store.path / "products" / "psf_stack"))
