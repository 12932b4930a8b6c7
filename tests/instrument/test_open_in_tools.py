"""Every output opens right in the field's readers (the ``interop`` extra): bioio
(bioio-ome-zarr, bioio-ome-tiff), ome-zarr-py, xarray and tifffile see one-letter
axes, micrometre pixel sizes and the first plane's depth, for a calibration run and
its products, a ``recon`` OME-TIFF, a PSF run from ``runs import-psf``, a ``recon3d``
volume and a ``runs export`` TIFF."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
import zarr

from instrument.cli import main
from instrument.runs.tiff_export import read_tiff_metadata
from instrument.writer.products import write_volume
from tests.drivers.interop.clients import client

from .test_ome import BINNING, PITCH_UM, _every_product_kind, _sweep

bioio = client("bioio", "bioio")
bioio_ome_zarr = client("bioio_ome_zarr", "bioio-ome-zarr")
bioio_ome_tiff = client("bioio_ome_tiff", "bioio-ome-tiff")
ome_io = client("ome_zarr.io", "ome-zarr")
ome_reader = client("ome_zarr.reader", "ome-zarr")


def _bioio_zarr(path):
    return bioio.BioImage(str(path), reader=bioio_ome_zarr.Reader)


def _ome_zarr_py(path) -> tuple[list[str], list[float], list[float]]:
    """ome-zarr-py's reading of the image at ``path``: axes, scale, translation."""
    (node, *_) = list(ome_reader.Reader(ome_io.parse_url(str(path)))())
    transforms = {t["type"]: t for t in node.metadata["coordinateTransformations"][0]}
    return ([a["name"] for a in node.metadata["axes"]], transforms["scale"]["scale"],
            transforms["translation"]["translation"])


def test_bioio_opens_a_calibration_run_and_every_image_product(tmp_path):
    """bioio takes only one-letter axes (it refused ``z_mm``, ``plane``, ``y_bin2``,
    ``node``) and drops any axis not among T, C, Z, Y, X: every image keeps every
    element, and its pixel size in micrometres."""
    store = _sweep(tmp_path / "s.zarr")
    images = _every_product_kind(store)
    group = zarr.open_group(store.path, mode="r")
    pitch = PITCH_UM * BINNING
    frames = _bioio_zarr(store.path)
    assert frames.dims.T == group["frames"].shape[0]  # the frames in acquisition order
    assert frames.physical_pixel_sizes.Y == pytest.approx(pitch)
    for name in images:
        image = _bioio_zarr(store.path / "products" / name)
        assert int(np.prod(image.shape)) == group[f"products/{name}/0"].size, name
        b = 2 if name == "recon_admm" else 1  # binning: a scale, not a name
        assert image.physical_pixel_sizes.X == pytest.approx(pitch * b), name
    assert _bioio_zarr(store.path / "products/psf_stack").physical_pixel_sizes.Z == 1000.0
    assert _bioio_zarr(store.path / "products/psf_grid_registered").dims.C == 4


def test_recon_writes_an_ome_tiff_with_its_pixel_size_and_record(tmp_path, capsys):
    rng = np.random.default_rng(0)
    psf = np.zeros((40, 48), np.float32)
    psf[18:22, 20:26] = 1.0
    raw = psf + 0.05 * rng.random((40, 48)).astype(np.float32)
    np.save(tmp_path / "p.npy", psf)
    np.save(tmp_path / "r.npy", raw)
    args = ["recon", "--psf", str(tmp_path / "p.npy"), "--raw", str(tmp_path / "r.npy"),
            "--method", "wiener", "--bin", "2", "--pitch-um", "3.45"]
    assert main([*args, "--out", str(tmp_path / "o.png")]) == 0
    with tifffile.TiffFile(tmp_path / "o.tif") as tif:
        assert tif.is_ome and tif.series[0].axes == "YX"
        image = tifffile.xml2dict(tif.ome_metadata)["OME"]["Image"]
        assert image["Pixels"]["PhysicalSizeX"] == pytest.approx(6.9)  # pitch x bin
        assert image["Pixels"]["PhysicalSizeXUnit"] == "µm"
        record = read_tiff_metadata(tif)
        data = tif.asarray()
    assert record["method"] == "wiener" and record["pixel_size_um"] == pytest.approx(6.9)
    assert data.dtype == np.float32 and data.shape == (20, 24)
    assert (tmp_path / "o.png").is_file()  # the view as it was
    seen = bioio.BioImage(str(tmp_path / "o.tif"), reader=bioio_ome_tiff.Reader)
    assert seen.physical_pixel_sizes.Y == pytest.approx(6.9)
    assert seen.dims.Y == 20 and seen.dims.X == 24
    capsys.readouterr()
    assert main([*args[:-1], "0", "--out", str(tmp_path / "bad.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--pitch-um" in err
    assert not (tmp_path / "bad.png").exists()


def test_import_psf_pitch_and_uneven_depths_open_with_their_origin(tmp_path, capsys):
    """A default sweep's depths are uneven (uniform in 1/z): z in micrometres at the
    mean spacing from the first depth, each depth listed; ``--pitch-um`` gives the
    stack's pixel size."""
    stack = np.random.default_rng(1).random((3, 16, 20)).astype(np.float32)
    np.save(tmp_path / "s.npy", stack)
    run = tmp_path / "psf.zarr"
    assert main(["runs", "import-psf", str(tmp_path / "s.npy"), "--depths", "20,25,40",
                 "--pitch-um", "2.5", "--out", str(run)]) == 0
    axes, scale, origin = _ome_zarr_py(run / "products/psf_stack")
    assert axes == ["z", "y", "x"]
    assert scale == pytest.approx([10000.0, 2.5, 2.5]) and origin[0] == 20000.0
    attrs = zarr.open_group(run / "products/psf_stack", mode="r").attrs
    assert attrs["ome"]["multiscales"][0]["metadata"]["depths_mm"] == [20.0, 25.0, 40.0]
    xr = pytest.importorskip("xarray")
    ds = xr.open_dataset(run, engine="zarr", group="products/psf_stack", consolidated=False)
    assert ds["0"].dims == ("z", "y", "x") and ds["0"].attrs["depths_mm"] == [20, 25, 40]
    seen = _bioio_zarr(run / "products/psf_stack")
    assert seen.dims.Z == 3 and seen.physical_pixel_sizes.X == 2.5
    # its ImageJ export has a z spacing (the mean) and origin, every depth in its Info
    out = tmp_path / "psf.tif"
    assert main(["runs", "export", str(run), "--out", str(out)]) == 0
    with tifffile.TiffFile(out) as tif:
        ij = tif.imagej_metadata
        assert ij["spacing"] == pytest.approx(10000.0) and ij["unit"] == "um"
        # ImageJ's calibration: z = (slice - zorigin) * spacing; slice 0 at 20 mm
        assert (0 - ij["zorigin"]) * ij["spacing"] == pytest.approx(20000.0)
        assert "zorigin=-2.0" in tif.pages[0].description.splitlines()
        assert json.loads(tif.imagej_metadata["Info"])["depths_mm"] == [20, 25, 40]
    ome = tmp_path / "psf.ome.tif"  # an OME-TIFF: each plane's depth as its PositionZ
    assert main(["runs", "export", str(run), "--out", str(ome)]) == 0
    seen = bioio.BioImage(str(ome), reader=bioio_ome_tiff.Reader)
    planes = seen.ome_metadata.images[0].pixels.planes
    assert [pl.position_z for pl in planes] == [20000.0, 25000.0, 40000.0]
    assert seen.physical_pixel_sizes.Z == pytest.approx(10000.0)
    capsys.readouterr()
    assert main(["runs", "import-psf", str(tmp_path / "s.npy"), "--depths", "20,25,40",
                 "--pitch-um", "-1", "--out", str(tmp_path / "bad.zarr")]) == 2
    assert "--pitch-um" in capsys.readouterr().err
    assert not (tmp_path / "bad.zarr").exists()


def test_a_volume_opens_with_its_first_depth(tmp_path):
    path = tmp_path / "v.zarr"
    write_volume(path, np.ones((3, 8, 10), np.float32),
                 {"depths_mm": [5.0, 5.5, 6.0], "bin_factor": 2}, pitch_um=6.9)
    axes, scale, origin = _ome_zarr_py(path)
    assert axes == ["z", "y", "x"] and scale == [500.0, 6.9, 6.9]
    assert origin == [5000.0, 0.0, 0.0]
    seen = _bioio_zarr(path)
    assert (seen.dims.Z, seen.physical_pixel_sizes.Z) == (3, 500.0)
