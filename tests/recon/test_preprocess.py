"""Tests for recon.preprocess: dark subtraction, binning, validation, prepare_pair."""

from __future__ import annotations

import dataclasses
import logging
import warnings

import numpy as np
import pytest

from recon.errors import ReconInputError
from recon.io import load_image
from recon.preprocess import (
    Prepared,
    SaturationWarning,
    box_bin,
    dark_level,
    normalize,
    prepare_pair,
    saturation_fraction,
    subtract_dark,
    validate_measurement,
    validate_psf,
)
from tests.real_data import sample_paths


def _psf_and_raw(shape=(32, 40), dark=100, dtype=np.uint16):
    """Synthetic uint16 PSF (dark floor + a few bright spots) and raw (floor + ramp)."""
    psf = np.full(shape, dark, dtype=dtype)
    psf[20, 25] = 5000
    psf[10:12, 30:33] = 3000
    raw = np.full(shape, dark, dtype=dtype)
    raw += np.arange(shape[1], dtype=dtype)[None, :]
    raw[0, 0] = dark - 7  # below the dark level: noise that must stay negative
    return psf, raw


# --------------------------------------------------------------------------- dark_level


def test_dark_level_2d_uses_region_mean():
    image = np.full((30, 30), 1000, dtype=np.uint16)
    image[5:15, 5:15] = np.arange(100, dtype=np.uint16).reshape(10, 10)
    level = dark_level(image)
    assert isinstance(level, float)
    assert level == pytest.approx(49.5)


def test_dark_level_3d_per_channel_float32():
    image = np.zeros((20, 20, 3), dtype=np.uint16)
    image[..., 0] = 10
    image[..., 1] = 20
    image[..., 2] = 30
    image[0, 0] = 60000  # outside the region: ignored
    level = dark_level(image)
    assert isinstance(level, np.ndarray)
    assert level.dtype == np.float32
    np.testing.assert_array_equal(level, [10, 20, 30])


def test_dark_level_custom_region():
    image = np.arange(100, dtype=np.float64).reshape(10, 10)
    assert dark_level(image, (slice(0, 2), slice(0, 2))) == pytest.approx((0 + 1 + 10 + 11) / 4)


def test_dark_level_region_outside_image_refused():
    with pytest.raises(ReconInputError,
                       match="image is 4x4 pixels, too small for its dark corner .rows 5:15, "
                       "cols 5:15.*--dark"):
        dark_level(np.ones((4, 4)))


def test_dark_level_bad_region_refused():
    with pytest.raises(ReconInputError, match="pair of slices"):
        dark_level(np.ones((20, 20)), (5, 15))


# --------------------------------------------------------------------------- subtract_dark


def test_subtract_dark_scalar_keeps_negatives_float32():
    image = np.array([[10, 20], [30, 5]], dtype=np.uint16)
    out = subtract_dark(image, 12.5)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[-2.5, 7.5], [17.5, -7.5]])


def test_subtract_dark_clip_negative():
    image = np.array([[10, 20], [30, 5]], dtype=np.uint16)
    out = subtract_dark(image, 12.5, clip_negative=True)
    np.testing.assert_array_equal(out, [[0, 7.5], [17.5, 0]])


def test_subtract_dark_per_channel_vector():
    image = np.ones((3, 4, 3), dtype=np.uint8) * np.array([10, 20, 30], dtype=np.uint8)
    out = subtract_dark(image, np.array([1, 2, 3]))
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out[1, 2], [9, 18, 27])


def test_subtract_dark_frame():
    image = np.arange(12, dtype=np.uint16).reshape(3, 4)
    frame = np.full((3, 4), 3, dtype=np.uint16)
    frame[0, 0] = 5
    out = subtract_dark(image, frame)
    expected = image.astype(np.float32) - frame
    np.testing.assert_array_equal(out, expected)
    assert out[0, 0] == -5  # no unsigned wrap-around


def test_subtract_dark_shape_mismatch_names_both_shapes():
    with pytest.raises(ReconInputError) as info:
        subtract_dark(np.ones((3, 4)), np.ones((4, 3)))
    assert "(4, 3)" in str(info.value) and "(3, 4)" in str(info.value)


def test_subtract_dark_wrong_vector_length_refused():
    with pytest.raises(ReconInputError, match="dark of shape \\(2,\\) does not match"):
        subtract_dark(np.ones((3, 4, 3)), np.array([1.0, 2.0]))


def test_subtract_dark_non_finite_refused():
    with pytest.raises(ReconInputError, match="1 NaN/inf"):
        subtract_dark(np.ones((3, 4)), float("nan"))


# --------------------------------------------------------------------------- box_bin


def test_box_bin_hand_computed():
    image = np.arange(24, dtype=np.uint16).reshape(4, 6)
    # blocks: [[0,1],[6,7]] -> 3.5 ; [[2,3],[8,9]] -> 5.5 ; [[4,5],[10,11]] -> 7.5
    #         [[12,13],[18,19]] -> 15.5 ; 17.5 ; 19.5
    out = box_bin(image, 2)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[3.5, 5.5, 7.5], [15.5, 17.5, 19.5]])


def test_box_bin_non_divisible_crops_and_warns(caplog):
    image = np.arange(35, dtype=np.float64).reshape(5, 7)
    with caplog.at_level(logging.WARNING, logger="recon.preprocess"):
        out = box_bin(image, 2)
    # kept rows 0-3, cols 0-5: block (0,0) = mean(0,1,7,8) = 4, then +2 per block col,
    # +14 per block row
    np.testing.assert_array_equal(out, [[4, 6, 8], [18, 20, 22]])
    assert any("not divisible" in r.getMessage() for r in caplog.records)
    assert any(r.levelno == logging.WARNING for r in caplog.records)


def test_box_bin_divisible_does_not_warn(caplog):
    with caplog.at_level(logging.WARNING, logger="recon.preprocess"):
        box_bin(np.ones((8, 8)), 4)
    assert not caplog.records


def test_box_bin_per_channel():
    image = np.zeros((4, 4, 2), dtype=np.float32)
    image[..., 0] = np.arange(16).reshape(4, 4)
    image[..., 1] = 7
    out = box_bin(image, 2)
    assert out.shape == (2, 2, 2)
    np.testing.assert_array_equal(out[..., 0], [[2.5, 4.5], [10.5, 12.5]])
    np.testing.assert_array_equal(out[..., 1], 7)


def test_box_bin_factor_one_returns_float32_copy():
    image = np.arange(6, dtype=np.float32).reshape(2, 3)
    out = box_bin(image, 1)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, image)
    out[0, 0] = 99
    assert image[0, 0] == 0  # a copy, not a view


def test_box_bin_numpy_integer_factor():
    np.testing.assert_array_equal(box_bin(np.ones((4, 4)), np.int64(2)), np.ones((2, 2)))


@pytest.mark.parametrize("factor", [0, -2, 2.0, 1.5, True, "2", None])
def test_box_bin_invalid_factor(factor):
    with pytest.raises(ReconInputError, match="bin factor must be an integer >= 1"):
        box_bin(np.ones((8, 8)), factor)


def test_box_bin_factor_larger_than_image():
    with pytest.raises(ReconInputError, match="larger than the image \\(3x8\\)"):
        box_bin(np.ones((3, 8)), 4)


# --------------------------------------------------------------------------- saturation


def test_saturation_fraction_integer_dtype_max():
    image = np.zeros((10, 10), dtype=np.uint8)
    image.flat[:3] = 255
    image.flat[3] = 254
    assert saturation_fraction(image) == pytest.approx(0.03)


def test_saturation_fraction_explicit_full_scale():
    image = np.zeros((10, 10), dtype=np.uint16)
    image.flat[:5] = 4095
    assert saturation_fraction(image) == 0.0
    assert saturation_fraction(image, full_scale=4095) == pytest.approx(0.05)


def test_saturation_fraction_float():
    image = np.ones((4, 5), dtype=np.float32)
    image[0, 0] = 2.0
    assert saturation_fraction(image) == 0.0
    assert saturation_fraction(image, full_scale=2.0) == pytest.approx(0.05)


def test_saturation_fraction_bad_full_scale():
    with pytest.raises(ReconInputError, match="full_scale must be a positive finite number"):
        saturation_fraction(np.ones((2, 2)), full_scale=float("inf"))


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("validate", [validate_psf, validate_measurement])
def test_validate_nan_inf_counted(validate):
    image = np.ones((5, 5), dtype=np.float32)
    image[0, 0] = np.nan
    image[1, 1] = np.inf
    image[2, 2] = -np.inf
    with pytest.raises(ReconInputError, match="3 NaN/inf value"):
        validate(image)


@pytest.mark.parametrize("validate", [validate_psf, validate_measurement])
def test_validate_empty(validate):
    with pytest.raises(ReconInputError, match="is empty"):
        validate(np.ones((0, 5), dtype=np.float32))


@pytest.mark.parametrize("validate", [validate_psf, validate_measurement])
@pytest.mark.parametrize(
    "image",
    [
        np.ones((3, 3), dtype=bool),
        np.ones((3, 3), dtype=np.complex64),
        np.array([["a", "b"], ["c", "d"]]),
        np.array([[object(), object()]], dtype=object),
    ],
)
def test_validate_non_numeric(validate, image):
    with pytest.raises(ReconInputError, match="non-numeric dtype"):
        validate(image)


@pytest.mark.parametrize("validate", [validate_psf, validate_measurement])
def test_validate_not_2d_3d(validate):
    with pytest.raises(ReconInputError, match="must be 2D"):
        validate(np.ones(5))


def test_validate_psf_all_zero():
    with pytest.raises(ReconInputError, match="PSF is all zero"):
        validate_psf(np.zeros((4, 4), dtype=np.uint16))


def test_validate_psf_negative_only():
    psf = -np.ones((4, 4), dtype=np.float32)
    psf[0, 0] = 0
    with pytest.raises(ReconInputError, match="PSF has no positive values"):
        validate_psf(psf)


def test_validate_accepts_good_data():
    psf = np.zeros((4, 4), dtype=np.float32)
    psf[1, 1] = 1
    assert validate_psf(psf) is None
    raw = -np.ones((4, 4), dtype=np.float32)  # negative raw is allowed (noise)
    assert validate_measurement(raw) is None


# --------------------------------------------------------------------------- prepare_pair


def test_prepare_pair_tutorial_dark_from_psf_corner():
    psf, raw = _psf_and_raw(dark=100)
    psf[5:15, 5:15] = 101  # corner mean 101 -> used for both images
    out = prepare_pair(psf, raw)
    assert isinstance(out, Prepared)
    assert out.psf.dtype == np.float32 and out.raw.dtype == np.float32
    assert out.info["dark_mode"] == "psf_region"
    assert out.info["dark_level"] == pytest.approx(101.0)
    assert out.psf[20, 25] == pytest.approx(5000 - 101)
    assert out.psf.min() == 0.0  # 100 - 101 clipped for the PSF
    # raw keeps its negatives: 100 - 101 = -1 and (100 - 7) - 101 = -8
    assert out.raw[0, 0] == pytest.approx(93 - 101)
    assert out.raw[3, 0] == pytest.approx(-1)
    np.testing.assert_allclose(out.raw, raw.astype(np.float32) - 101)
    assert out.info["raw_levels"]["floor"] == pytest.approx(100, abs=1)
    assert out.info["psf_clipped_fraction"] > 0.5


def test_prepare_pair_info_contents():
    psf, raw = _psf_and_raw(shape=(32, 40))
    out = prepare_pair(psf, raw, bin_factor=2)
    info = out.info
    assert info["psf_shape_in"] == (32, 40)
    assert info["raw_shape_in"] == (32, 40)
    assert info["psf_dtype_in"] == "uint16"
    assert info["raw_dtype_in"] == "uint16"
    assert info["bin_factor"] == 2
    assert info["channels"] == 1
    assert info["saturated_fraction_psf"] == 0.0
    assert info["saturated_fraction_raw"] == 0.0
    assert info["dark_region"] == ((5, 15), (5, 15))
    assert info["psf_shape"] == (16, 20) and info["raw_shape"] == (16, 20)
    assert out.psf.shape == (16, 20) and out.raw.shape == (16, 20)


def test_prepare_pair_is_frozen():
    psf, raw = _psf_and_raw()
    out = prepare_pair(psf, raw)
    with pytest.raises(dataclasses.FrozenInstanceError):
        out.psf = np.zeros(3)


def test_prepare_pair_dark_none_string_skips():
    psf, raw = _psf_and_raw(dark=100)
    out = prepare_pair(psf, raw, dark="none")
    assert out.info["dark_mode"] == "none"
    assert out.info["dark_level"] is None
    np.testing.assert_array_equal(out.raw, raw.astype(np.float32))
    np.testing.assert_array_equal(out.psf, psf.astype(np.float32))


def test_prepare_pair_dark_scalar():
    psf, raw = _psf_and_raw(dark=100)
    out = prepare_pair(psf, raw, dark=90.0)
    assert out.info["dark_mode"] == "scalar"
    assert out.info["dark_level"] == 90.0
    np.testing.assert_allclose(out.raw, raw.astype(np.float32) - 90)
    assert out.psf[0, 0] == pytest.approx(10)


def test_prepare_pair_dark_frame_subtracted_from_both():
    psf, raw = _psf_and_raw(dark=100)
    frame = np.full(psf.shape, 100, dtype=np.uint16)
    frame[:, :10] = 98
    out = prepare_pair(psf, raw, dark=frame)
    assert out.info["dark_mode"] == "frame"
    assert out.info["dark_level"] == pytest.approx(frame.mean())
    np.testing.assert_allclose(out.raw, raw.astype(np.float32) - frame)
    np.testing.assert_allclose(out.psf, np.clip(psf.astype(np.float32) - frame, 0, None))


def test_prepare_pair_dark_frame_shape_mismatch():
    psf, raw = _psf_and_raw(shape=(32, 40))
    with pytest.raises(ReconInputError, match="dark of shape \\(8, 8\\) does not match"):
        prepare_pair(psf, raw, dark=np.zeros((8, 8)))


def test_prepare_pair_dark_bad_string():
    psf, raw = _psf_and_raw()
    with pytest.raises(ReconInputError, match="dark='auto' is not understood"):
        prepare_pair(psf, raw, dark="auto")


def test_prepare_pair_psf_without_signal_above_dark():
    psf = np.full((32, 40), 100, dtype=np.uint16)
    psf[5:15, 5:15] = 200  # bright "dark" corner: everything ends up <= 0
    raw = np.full((32, 40), 150, dtype=np.uint16)
    with pytest.raises(ReconInputError, match="PSF has no signal above the dark level"):
        prepare_pair(psf, raw)


def test_prepare_pair_psf_channel_without_signal():
    psf = np.full((32, 40, 3), 100, dtype=np.uint16)
    psf[20, 20, :2] = 1000  # channel 2 has nothing above its dark level
    raw = np.full((32, 40, 3), 120, dtype=np.uint16)
    with pytest.raises(
        ReconInputError, match="no signal above the dark level in channel\\(s\\) \\[2\\]"
    ):
        prepare_pair(psf, raw)


def test_prepare_pair_2d_psf_shared_over_channels():
    psf, raw2 = _psf_and_raw()
    raw = np.stack([raw2, raw2 + 10, raw2 + 20], axis=-1)
    out = prepare_pair(psf, raw, bin_factor=2)
    assert out.psf.shape == (16, 20)
    assert out.raw.shape == (16, 20, 3)
    assert out.info["channels"] == 3
    assert out.info["psf_shared_across_channels"] is True
    np.testing.assert_allclose(out.raw[..., 2] - out.raw[..., 0], 20)


def test_prepare_pair_3d_psf_per_channel_dark():
    psf = np.zeros((32, 40, 3), dtype=np.uint16)
    psf[...] = np.array([10, 20, 30], dtype=np.uint16)
    psf[20, 20] = 1000
    raw = np.full((32, 40, 3), 50, dtype=np.uint16)
    raw[16:, 20:] = 60  # some structure: a constant raw carries no image
    out = prepare_pair(psf, raw)
    assert out.info["dark_level"] == [10.0, 20.0, 30.0]
    np.testing.assert_allclose(out.raw[0, 0], [40, 30, 20])
    np.testing.assert_allclose(out.psf[20, 20], [990, 980, 970])


def test_prepare_pair_3d_psf_with_2d_raw_refused():
    psf = np.ones((32, 40, 3), dtype=np.uint16)
    raw = np.ones((32, 40), dtype=np.uint16)
    with pytest.raises(ReconInputError, match="PSF has 3 channels .* measurement is 2D"):
        prepare_pair(psf, raw)


def test_prepare_pair_channel_count_mismatch_refused():
    psf = np.ones((32, 40, 4), dtype=np.uint16)
    raw = np.ones((32, 40, 3), dtype=np.uint16)
    with pytest.raises(ReconInputError, match="PSF has 4 channels and the measurement 3"):
        prepare_pair(psf, raw)


def test_prepare_pair_spatial_mismatch_names_shapes():
    psf = np.ones((32, 40), dtype=np.uint16)
    raw = np.ones((30, 40), dtype=np.uint16)
    with pytest.raises(ReconInputError) as info:
        prepare_pair(psf, raw)
    message = str(info.value)
    assert "(32, 40)" in message and "(30, 40)" in message
    assert "crop" in message and "capture" in message


def test_prepare_pair_validates_before_conversion():
    psf, raw = _psf_and_raw()
    bad_psf = psf.astype(np.float32)
    bad_psf[3, 3] = np.nan
    # With bayer the float PSF would be refused by the demosaic step; validation comes first.
    with pytest.raises(ReconInputError, match="PSF contains 1 NaN/inf"):
        prepare_pair(bad_psf, raw, bayer="RGGB")
    bad_raw = raw.astype(np.float64)
    bad_raw[0, :4] = np.inf
    with pytest.raises(ReconInputError, match="measurement contains 4 NaN/inf"):
        prepare_pair(psf, bad_raw)
    with pytest.raises(ReconInputError, match="PSF is all zero"):
        prepare_pair(np.zeros_like(psf), raw)


def test_prepare_pair_bad_bin_factor():
    psf, raw = _psf_and_raw()
    with pytest.raises(ReconInputError, match="bin factor must be an integer"):
        prepare_pair(psf, raw, bin_factor=2.5)


def test_prepare_pair_bayer_demosaics_both():
    shape = (32, 40)
    psf = np.full(shape, 100, dtype=np.uint16)
    psf[20:22, 20:22] = 5000  # one full Bayer cell lit
    raw = np.full(shape, 100, dtype=np.uint16)
    raw[0::2, 0::2] = 400  # red sites of an RGGB sensor
    out = prepare_pair(psf, raw, bayer="RGGB")
    assert out.psf.shape == (32, 40, 3)
    assert out.raw.shape == (32, 40, 3)
    assert out.info["channels"] == 3
    assert out.info["dark_level"] == pytest.approx([100.0, 100.0, 100.0])
    interior = out.raw[4:-4, 4:-4]
    np.testing.assert_allclose(interior[..., 0], 300, atol=1)  # red = 400 - 100
    np.testing.assert_allclose(interior[..., 2], 0, atol=1)  # blue


def test_prepare_pair_saturation_warning(caplog):
    psf, raw = _psf_and_raw(shape=(32, 40))
    raw.flat[:10] = 65535  # 10 / 1280 = 0.78 % saturated
    with caplog.at_level(logging.WARNING, logger="recon.preprocess"):
        with pytest.warns(SaturationWarning, match="measurement: .* at full scale"):
            out = prepare_pair(psf, raw)
    assert out.info["saturated_fraction_raw"] == pytest.approx(10 / 1280)
    assert any("full scale" in r.getMessage() for r in caplog.records)


def test_prepare_pair_saturation_warning_psf_and_threshold():
    psf, raw = _psf_and_raw(shape=(32, 40))
    psf[25, 5:9] = 65535  # 4 / 1280 = 0.31 %
    with pytest.warns(SaturationWarning, match="PSF"):
        prepare_pair(psf, raw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = prepare_pair(psf, raw, warn_saturation=0.01)  # above the fraction: silent
        prepare_pair(psf, raw, warn_saturation=None)
    assert out.info["saturated_fraction_psf"] == pytest.approx(4 / 1280)


def test_prepare_pair_bad_warn_saturation():
    psf, raw = _psf_and_raw()
    with pytest.raises(ReconInputError, match="warn_saturation must be a fraction"):
        prepare_pair(psf, raw, warn_saturation=5)


def test_prepare_pair_real_tutorial_data():
    psf_path, raw_path = sample_paths()  # fails (not skips) when the data is missing
    psf = load_image(psf_path)
    raw = load_image(raw_path)
    assert psf.shape == (1200, 1600) and psf.dtype == np.uint16
    out = prepare_pair(psf, raw, bin_factor=4)
    for arr in (out.psf, out.raw):
        assert arr.shape == (300, 400)
        assert arr.dtype == np.float32
        assert np.isfinite(arr).all()
    assert out.psf.min() >= 0.0
    assert out.psf.sum() > 0.0
    assert out.info["dark_level"] == pytest.approx(float(psf[5:15, 5:15].mean()))


# --------------------------------------------------------------------------- normalize


def test_normalize_l2():
    image = np.array([[3.0, 0.0], [0.0, -4.0]])
    scaled, scale = normalize(image, "l2")
    assert scale == pytest.approx(5.0)
    assert scaled.dtype == np.float32
    assert np.linalg.norm(scaled) == pytest.approx(1.0)
    np.testing.assert_allclose(scaled * scale, image, rtol=1e-6)


def test_normalize_max_and_sum():
    image = np.array([[1, 2], [3, 4]], dtype=np.uint16)
    scaled, scale = normalize(image, "max")
    assert scale == 4.0
    np.testing.assert_allclose(scaled, [[0.25, 0.5], [0.75, 1.0]])
    scaled, scale = normalize(image, "sum")
    assert scale == 10.0
    assert scaled.sum() == pytest.approx(1.0)


def test_normalize_refusals():
    with pytest.raises(ReconInputError, match="all-zero image"):
        normalize(np.zeros((3, 3)), "l2")
    with pytest.raises(ReconInputError, match="unknown normalization mode 'l1'"):
        normalize(np.ones((3, 3)), "l1")
    with pytest.raises(ReconInputError, match="sums to -2"):
        normalize(np.array([[1.0, -3.0]]), "sum")
    with pytest.raises(ReconInputError, match="1 NaN/inf"):
        normalize(np.array([[1.0, np.nan]]), "max")


def test_full_scale_below_dtype_max_detects_shifted_12bit_saturation():
    """12-bit data shifted into uint16 saturates at 65520, not 65535."""
    raw = np.full((20, 20), 1000, np.uint16)
    raw[:4, :4] = 65520  # 4 % saturated
    psf = np.full((20, 20), 10, np.uint16)
    psf[10, 10] = 3000
    import warnings as _w

    with _w.catch_warnings():
        _w.simplefilter("error")
        prepare_pair(psf, raw)  # 65535 full scale: nothing saturated, no warning
    with pytest.warns(SaturationWarning, match="65520"):
        out = prepare_pair(psf, raw, full_scale=65520)
    assert out.info["saturated_fraction_raw"] == pytest.approx(0.04)
