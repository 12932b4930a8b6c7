"""What docs/open-data.md says of the field's tools holds (issue 67): bioio opens a
product's folder only when given bioio-ome-zarr's reader, bioio's Z coordinates of an
OME-TIFF ignore each plane's PositionZ, and xarray's open_datatree refuses a video run
with a binned product (a tree wants one size per dimension name) while each group
opens alone, the way round the docs give."""

from __future__ import annotations

import numpy as np
import pytest

from instrument.cli import main

bioio = pytest.importorskip("bioio")
bioio_ome_zarr = pytest.importorskip("bioio_ome_zarr")
bioio_ome_tiff = pytest.importorskip("bioio_ome_tiff")
xr = pytest.importorskip("xarray")


def test_bioio_needs_the_reader_for_a_product_folder_and_ignores_position_z(tmp_path):
    from bioio_base.exceptions import UnsupportedFileFormatError

    np.save(tmp_path / "s.npy", np.random.default_rng(0).random((3, 16, 20), np.float32))
    run = tmp_path / "p.zarr"
    assert main(["runs", "import-psf", str(tmp_path / "s.npy"), "--depths", "20,25,40",
                 "--pitch-um", "2.5", "--out", str(run)]) == 0
    folder = str(run / "products" / "psf_stack")
    with pytest.raises(UnsupportedFileFormatError):
        bioio.BioImage(folder)
    assert bioio.BioImage(folder, reader=bioio_ome_zarr.Reader).dims.Z == 3
    assert main(["runs", "export", str(run), "--out", str(tmp_path / "p.ome.tif")]) == 0
    seen = bioio.BioImage(str(tmp_path / "p.ome.tif"), reader=bioio_ome_tiff.Reader)
    planes = seen.ome_metadata.images[0].pixels.planes
    assert [p.position_z for p in planes] == [20000.0, 25000.0, 40000.0]  # in the file
    z = seen.xarray_dask_data.coords["Z"].values  # bioio's own: from 0, mean spacing
    np.testing.assert_allclose(z, [0.0, 10000.0, 20000.0])


def test_open_datatree_refuses_a_binned_product_and_each_group_opens(tmp_path):
    from tests.instrument.test_ome import _video

    store = _video(tmp_path / "v.zarr")
    store.create_frame_product("recon_wiener", store.n_frames, (6, 8), bin_factor=2)
    with pytest.raises(ValueError, match="not aligned with its parents"):
        xr.open_datatree(store.path, engine="zarr", consolidated=False)
    root = xr.open_dataset(store.path, engine="zarr", consolidated=False)
    recon = xr.open_dataset(store.path, engine="zarr", group="products/recon_wiener",
                            consolidated=False)["0"]
    assert root["frames"].dims == recon.dims == ("t", "y", "x")
    assert recon.shape == (store.n_frames, 6, 8)


def test_uneven_depths_reach_xarray_and_napari_users_as_the_true_depths(tmp_path):
    """The docs' recipe gives xarray a coordinate of the true depths; the napari
    plugin's layer carries them in its metadata (the scale is their mean spacing)."""
    from gui.napari_plugin.reader import read_run

    np.save(tmp_path / "s.npy", np.random.default_rng(1).random((3, 16, 20), np.float32))
    run = tmp_path / "p.zarr"
    assert main(["runs", "import-psf", str(tmp_path / "s.npy"), "--depths", "20,25,40",
                 "--out", str(run)]) == 0
    psf = xr.open_dataset(run, engine="zarr", group="products/psf_stack",
                          consolidated=False)["0"]
    psf = psf.assign_coords(z_mm=("z", psf.attrs["depths_mm"]))
    assert psf.swap_dims(z="z_mm").sel(z_mm=25.0).shape == (16, 20)
    np.testing.assert_array_equal(psf["z_mm"].values, [20.0, 25.0, 40.0])
    (_, kwargs, _), = read_run(str(run))
    assert kwargs["metadata"]["depths_mm"] == [20.0, 25.0, 40.0]
    assert "mean spacing" in kwargs["metadata"]["z_scale"]
