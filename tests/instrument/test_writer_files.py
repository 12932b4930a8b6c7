"""Tests for instrument.writer.files and atomic: the float TIFF, PNG view and .npy
written whole or not at all, read back with recon.io.load_image."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import tifffile

from instrument.writer.files import save_image
from recon.errors import ReconInputError
from recon.io import load_image

RNG = np.random.default_rng(1234)

# --------------------------------------------------------------------------- round trips


def test_roundtrip_tif_float32(tmp_path):
    data = (RNG.standard_normal((13, 21)) * 100).astype(np.float32)
    path = tmp_path / "sub" / "dir" / "x.tif"  # parents created
    save_image(path, data)
    out = load_image(path)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, data)


def test_roundtrip_tif_converts_to_float32_and_keeps_rgb(tmp_path):
    data = RNG.integers(0, 65535, size=(7, 11, 3), dtype=np.uint16)
    path = tmp_path / "rgb.tiff"
    save_image(path, data)
    out = load_image(path)
    assert out.dtype == np.float32
    assert out.shape == (7, 11, 3)
    np.testing.assert_array_equal(out, data.astype(np.float32))


def test_roundtrip_npy_keeps_dtype(tmp_path):
    data = RNG.integers(-500, 500, size=(5, 8, 3), dtype=np.int16)
    path = tmp_path / "n" / "x.npy"
    save_image(path, data)
    out = load_image(path)
    assert out.dtype == np.int16
    np.testing.assert_array_equal(out, data)


def test_roundtrip_png_gray_scaling(tmp_path):
    # Ramp 0..99999: the 99.9th percentile is ~99899.  Negatives go to 0.
    data = np.arange(100_000, dtype=np.float64).reshape(250, 400)
    data[0, 0] = -50.0
    path = tmp_path / "view.png"
    save_image(path, data)
    out = load_image(path)
    assert out.dtype == np.uint8
    assert out.shape == data.shape
    top = np.percentile(np.clip(data, 0, None), 99.9)
    assert out[0, 0] == 0  # negative clipped to 0
    assert out.flat[-1] == 255  # above the percentile: clipped
    mid = int(round(top / 2))
    assert abs(int(out.flat[mid]) - 128) <= 1
    expected = np.rint(np.clip(np.clip(data, 0, None) * 255.0 / top, 0, 255))
    np.testing.assert_array_equal(out, expected.astype(np.uint8))


def test_roundtrip_png_rgb_channel_order(tmp_path):
    data = np.zeros((10, 10, 3), dtype=np.float32)
    data[..., 0] = 1.0  # red only
    path = tmp_path / "red.png"
    save_image(path, data)
    raw_bgr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert (raw_bgr[..., 2] == 255).all() and (raw_bgr[..., :2] == 0).all()
    out = load_image(path)
    assert (out[..., 0] == 255).all()
    assert (out[..., 1:] == 0).all()


def test_save_png_all_zero_and_nan(tmp_path):
    data = np.zeros((4, 5), dtype=np.float32)
    data[1, 1] = np.nan
    path = tmp_path / "z.png"
    save_image(path, data)
    out = load_image(path)
    assert out.dtype == np.uint8
    assert (out == 0).all()


# --------------------------------------------------------------------------- save refusals


def test_save_unsupported_extension(tmp_path):
    with pytest.raises(ReconInputError, match="use one of .tif, .tiff, .png, .npy"):
        save_image(tmp_path / "x.jpg", np.ones((4, 4)))
    assert not (tmp_path / "x.jpg").exists()


@pytest.mark.parametrize("shape", [(5,), (2, 3, 4, 5), (0, 4)])
def test_save_bad_shape(tmp_path, shape):
    with pytest.raises(ReconInputError, match="cannot save an array of shape"):
        save_image(tmp_path / "x.tif", np.ones(shape))


def test_save_png_bad_channel_count(tmp_path):
    with pytest.raises(ReconInputError, match="needs 1, 3 or 4 channels, the image has 5"):
        save_image(tmp_path / "x.png", np.ones((4, 4, 5)))


def test_save_non_numeric(tmp_path):
    with pytest.raises(ReconInputError, match="cannot save dtype"):
        save_image(tmp_path / "x.npy", np.array([["a", "b"], ["c", "d"]]))


# ----------------------------------------------------------------------------- atomic writes


def test_atomic_path_renames_into_place_on_success(tmp_path):
    from instrument.atomic import atomic_path

    final = tmp_path / "sub" / "m.json"
    with atomic_path(final) as tmp:
        assert tmp.parent == final.parent and tmp.suffix == ".json" and tmp != final
        tmp.write_text("{}")
        assert not final.exists()
    assert final.read_text() == "{}"
    assert [p.name for p in final.parent.iterdir()] == ["m.json"]


@pytest.mark.parametrize("existing", [None, b"earlier"])
def test_atomic_path_failure_leaves_no_file_and_no_temp(tmp_path, existing):
    from instrument.atomic import atomic_path

    final = tmp_path / "m.json"
    if existing is not None:
        final.write_bytes(existing)
    with pytest.raises(RuntimeError, match="crash"), atomic_path(final) as tmp:
        tmp.write_text('{"half": ')
        raise RuntimeError("crash while writing")
    names = [p.name for p in tmp_path.iterdir()]
    if existing is None:
        assert names == []
    else:
        assert names == ["m.json"] and final.read_bytes() == existing


@pytest.mark.parametrize("name", ["out.tif", "out.png", "out.npy"])
@pytest.mark.parametrize("error, raised, words", [
    # the disk's problem: an OSError naming the file and the free space (exit 2)
    (OSError(28, "No space left on device"), OSError, "No space left.*free.*out"),
    # anything else the system refuses: a ReconInputError saying what to check
    (OSError(13, "Permission denied"), ReconInputError, "cannot write"),
], ids=["ENOSPC", "EACCES"])
def test_save_image_failure_leaves_no_partial_file(tmp_path, monkeypatch, name, error,
                                                   raised, words):
    import cv2

    from instrument.writer import files

    def half_then_fail(path, *args, **kwargs):
        open(path if not hasattr(path, "write") else path.name, "ab").write(b"partial")
        raise error

    monkeypatch.setattr(tifffile, "imwrite", half_then_fail)
    monkeypatch.setattr(cv2, "imwrite", half_then_fail)
    monkeypatch.setattr(np, "save", half_then_fail)
    with pytest.raises(raised, match=words):
        files.save_image(tmp_path / name, np.ones((4, 4), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_save_image_npy_keeps_its_name_and_replaces(tmp_path):
    path = tmp_path / "a.npy"
    save_image(path, np.zeros((3, 3)))
    save_image(path, np.ones((3, 3)))
    assert np.array_equal(load_image(path), np.ones((3, 3)))
    assert [p.name for p in tmp_path.iterdir()] == ["a.npy"]
