"""Tests for recon.io: image loading and Bayer demosaicing (writing:
tests/instrument/test_writer_files.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import tifffile

from recon.errors import ReconInputError
from recon.io import BAYER_PATTERNS, demosaic_bayer, load_image

RNG = np.random.default_rng(1234)

# --------------------------------------------------------------------------- load: formats


def test_load_tiff_uint16_native_dtype(tmp_path):
    data = RNG.integers(0, 65535, size=(12, 17), dtype=np.uint16)
    path = tmp_path / "a.tif"
    tifffile.imwrite(path, data)
    out = load_image(path)
    assert out.dtype == np.uint16
    np.testing.assert_array_equal(out, data)


def test_load_tiff_uppercase_extension(tmp_path):
    data = RNG.integers(0, 255, size=(6, 7), dtype=np.uint8)
    path = tmp_path / "a.TIFF"
    tifffile.imwrite(path, data)
    np.testing.assert_array_equal(load_image(str(path)), data)


def test_load_tiff_planar_rgb_moves_channels_last(tmp_path):
    planes = RNG.integers(0, 4000, size=(3, 10, 14), dtype=np.uint16)
    path = tmp_path / "planar.tif"
    tifffile.imwrite(path, planes, photometric="rgb", planarconfig="separate")
    out = load_image(path)
    assert out.shape == (10, 14, 3)
    np.testing.assert_array_equal(out, np.moveaxis(planes, 0, -1))


@pytest.mark.parametrize("pages", [3, 4])
def test_grey_pages_are_frames_never_colour(tmp_path, pages):
    """Colour comes from the samples per pixel (photometric tag), not from a page count:
    three (or four) grey pages are three frames, refused where one image is expected,
    however the same numbers load when the file says they are RGB."""
    planes = RNG.integers(0, 4000, size=(pages, 10, 14), dtype=np.uint16)
    path = tmp_path / "pages.tif"
    tifffile.imwrite(path, planes, photometric="minisblack")
    with pytest.raises(ReconInputError, match=f"stack of {pages} images of 10x14.*photometric"):
        load_image(path)
    tifffile.imwrite(path, np.moveaxis(planes, 0, -1),
                     photometric="rgb", extrasamples=[] if pages == 3 else ["unassalpha"])
    assert load_image(path).shape == (10, 14, pages)


def test_load_singleton_leading_axis_is_dropped(tmp_path):
    data = RNG.random((1, 9, 11)).astype(np.float32)
    path = tmp_path / "one.npy"
    np.save(path, data)
    out = load_image(path)
    assert out.shape == (9, 11)
    np.testing.assert_array_equal(out, data[0])


def test_load_png_converts_bgr_to_rgb(tmp_path):
    bgr = np.zeros((8, 9, 3), dtype=np.uint8)
    bgr[..., 0] = 10  # blue in OpenCV order
    bgr[..., 1] = 20
    bgr[..., 2] = 200  # red in OpenCV order
    path = tmp_path / "c.png"
    assert cv2.imwrite(str(path), bgr)
    out = load_image(path)
    assert out.shape == (8, 9, 3)
    assert out.dtype == np.uint8
    assert (out[..., 0] == 200).all()  # red first
    assert (out[..., 1] == 20).all()
    assert (out[..., 2] == 10).all()


def test_load_png_bgra_to_rgba_and_uint16(tmp_path):
    bgra = np.zeros((5, 6, 4), dtype=np.uint16)
    bgra[..., 0] = 1000
    bgra[..., 1] = 2000
    bgra[..., 2] = 3000
    bgra[..., 3] = 65535
    path = tmp_path / "d.png"
    assert cv2.imwrite(str(path), bgra)
    out = load_image(path)
    assert out.dtype == np.uint16
    np.testing.assert_array_equal(out[0, 0], [3000, 2000, 1000, 65535])


def test_load_bmp_and_jpeg_gray(tmp_path):
    gray = np.full((16, 16), 128, dtype=np.uint8)
    for name in ("g.bmp", "g.jpg", "g.jpeg"):
        path = tmp_path / name
        assert cv2.imwrite(str(path), gray)
        out = load_image(path)
        assert out.shape == (16, 16), name
        assert abs(int(out.mean()) - 128) <= 1, name


# --------------------------------------------------------------------------- load refusals


def test_load_missing_file(tmp_path):
    path = tmp_path / "nope.tif"
    with pytest.raises(ReconInputError, match="not found") as info:
        load_image(path)
    assert "nope.tif" in str(info.value)


def test_load_unsupported_extension_lists_supported(tmp_path):
    path = tmp_path / "img.gif"
    path.write_bytes(b"GIF89a")
    with pytest.raises(ReconInputError, match="unsupported file extension '.gif'") as info:
        load_image(path)
    message = str(info.value)
    for ext in (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp", ".npy"):
        assert ext in message
    assert "img.gif" in message


def test_load_directory_refused(tmp_path):
    path = tmp_path / "folder.tif"
    path.mkdir()
    with pytest.raises(ReconInputError, match="not a regular file"):
        load_image(path)


@pytest.mark.parametrize(
    ("name", "fragment"),
    [
        ("bad.png", "could not decode"),
        ("bad.jpg", "could not decode"),
        ("bad.tif", "cannot read as TIFF"),
        ("bad.npy", "cannot read as .npy"),
    ],
)
def test_load_corrupt_files(tmp_path, name, fragment):
    path = tmp_path / name
    path.write_bytes(b"this is not an image" * 5)
    with pytest.raises(ReconInputError, match=fragment) as info:
        load_image(path)
    assert name in str(info.value)
    assert "\n" not in str(info.value)


def test_load_truncated_tiff(tmp_path):
    good = tmp_path / "good.tif"
    tifffile.imwrite(good, np.ones((64, 64), dtype=np.uint16))
    bad = tmp_path / "trunc.tif"
    bad.write_bytes(good.read_bytes()[:100])
    with pytest.raises(ReconInputError, match="trunc.tif"):
        load_image(bad)


def test_load_pickled_npy_refused(tmp_path):
    path = tmp_path / "obj.npy"
    np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ReconInputError, match="cannot read as .npy"):
        load_image(path)


def test_load_npz_behind_npy_name_refused(tmp_path):
    path = tmp_path / "arch.npy"
    with open(path, "wb") as fh:
        np.savez(fh, a=np.ones((3, 3)))
    with pytest.raises(ReconInputError, match="npz archive"):
        load_image(path)


def test_load_complex_refused(tmp_path):
    path = tmp_path / "c.npy"
    np.save(path, np.ones((4, 4), dtype=np.complex64))
    with pytest.raises(ReconInputError, match="not a numeric image type"):
        load_image(path)


@pytest.mark.parametrize("shape", [(7,), (2, 3, 4, 5, 6), ()])
def test_load_not_2d_or_3d(tmp_path, shape):
    path = tmp_path / "d.npy"
    np.save(path, np.ones(shape, dtype=np.float32))
    with pytest.raises(ReconInputError, match="must be 2D"):
        load_image(path)


def test_load_stack_3d_refused(tmp_path):
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, np.ones((10, 20, 30), dtype=np.uint16), photometric="minisblack")
    with pytest.raises(ReconInputError, match="stack of 10 images of 20x30"):
        load_image(path)


def test_load_stack_4d_refused(tmp_path):
    path = tmp_path / "stack4.npy"
    np.save(path, np.ones((5, 20, 30, 3), dtype=np.uint8))
    with pytest.raises(ReconInputError, match="stack of 5 images"):
        load_image(path)


# --------------------------------------------------------------------------- Bayer


def _mosaic(pattern: str, values: dict[str, int], shape=(16, 20), dtype=np.uint16):
    """Synthetic Bayer mosaic: each colour plane constant at values[colour]."""
    mosaic = np.zeros(shape, dtype=dtype)
    for k, colour in enumerate(pattern):
        dy, dx = divmod(k, 2)
        mosaic[dy::2, dx::2] = values[colour]
    return mosaic


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_bayer_mapping(pattern, dtype):
    values = {"R": 10, "G": 100, "B": 200}
    mosaic = _mosaic(pattern, values, dtype=dtype)
    rgb = demosaic_bayer(mosaic, pattern)
    assert rgb.shape == (16, 20, 3)
    assert rgb.dtype == dtype
    interior = rgb[2:-2, 2:-2].reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(interior.mean(axis=0), [10, 100, 200], atol=0.5)


def test_bayer_pattern_case_insensitive_and_list():
    assert set(BAYER_PATTERNS) == {"RGGB", "BGGR", "GRBG", "GBRG"}
    mosaic = _mosaic("RGGB", {"R": 1000, "G": 2000, "B": 3000})
    np.testing.assert_array_equal(demosaic_bayer(mosaic, "rggb"), demosaic_bayer(mosaic, "RGGB"))


def test_bayer_refusals():
    mosaic = np.zeros((8, 8), dtype=np.uint16)
    with pytest.raises(ReconInputError, match="unknown Bayer pattern 'RGBG'"):
        demosaic_bayer(mosaic, "RGBG")
    with pytest.raises(ReconInputError, match="needs a 2D raw mosaic"):
        demosaic_bayer(np.zeros((8, 8, 3), dtype=np.uint16), "RGGB")
    with pytest.raises(ReconInputError, match="uint8 or uint16"):
        demosaic_bayer(mosaic.astype(np.float32), "RGGB")
    with pytest.raises(ReconInputError, match="smaller than 3x3"):
        demosaic_bayer(np.zeros((1, 8), dtype=np.uint8), "RGGB")
