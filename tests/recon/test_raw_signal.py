"""The raw checked after its dark level (recon.preprocess.signal), in 2D, 3D and on the
PSF-grid path: what is refused, and what real and physical data pass.

The command-line cases (exit 2, one line, inputs unchanged) are the ``no-signal`` class
of the fault table (tests/faults/test_fault_table.py)."""

from __future__ import annotations

import numpy as np
import pytest

import recon
from recon import reconstruct_volume
from recon.preprocess import RawSignalError, check_raw_signal, prepare_pair
from recon.preprocess.signal import check_pair_ranges, noise_sigma
from recon.sample import load_sample


def _camera_pair(rng, dark=3168.0, shape=(48, 48)):
    """A PSF with a dark corner and a raw of the same camera: Poisson light plus read
    noise on one dark level, uint16."""
    psf = np.zeros(shape)
    psf[20:40, 20:40] = 4000 * rng.random((20, 20)) ** 3
    scene = np.zeros(shape)
    scene[10:30, 10:30] = 1.0
    light = 30 * np.real(np.fft.ifft2(np.fft.fft2(psf) * np.fft.fft2(scene))) / psf.sum()
    light = np.clip(light, 0, None) + 50

    def sense(x):
        return np.clip(rng.poisson(x) + rng.normal(dark, 4, shape), 0, 65535).astype(np.uint16)

    return sense(psf), sense(light)


def test_the_real_tutorial_pair_passes_and_records_the_raws_levels():
    try:
        prepared = load_sample(4)
    except recon.errors.ReconInputError as exc:
        pytest.skip(str(exc))
    levels = prepared.info["raw_levels"]
    # the raw's floor (its darkest 0.1 %) lies above the PSF corner's dark level
    assert levels["floor"] > prepared.info["dark_level"]


def test_a_physical_pair_passes_in_every_method():
    rng = np.random.default_rng(0)
    psf, raw = _camera_pair(rng)
    for method in ("wiener", "fista", "admm"):
        out = recon.reconstruct(psf, raw, method, iterations=3, tv=1e-4)
        assert out.image.max() > 0


@pytest.mark.parametrize("make, words", [
    (lambda psf, raw: (raw // 256).astype(np.uint8), "uint8"),  # 8-bit export
    (lambda psf, raw: raw.astype(np.float32) - 3168.0, "below the dark level 31"),
    (lambda psf, raw: np.full_like(raw, 4000), "constant"),
    (lambda psf, raw: np.where(np.arange(raw.size).reshape(raw.shape) % 10 == 0, 900,
                               65535).astype(np.uint16), "90.0% of the raw is at full scale"),
])
def test_raws_without_signal_are_refused_in_every_method(make, words):
    rng = np.random.default_rng(1)
    psf, raw = _camera_pair(rng)
    bad = make(psf, raw)
    for method in ("auto", "wiener", "gd", "fista", "admm"):
        with pytest.raises(RawSignalError, match=words):
            recon.reconstruct(psf, bad, method, iterations=2, tv=1e-4)


def test_a_lone_extreme_value_is_refused_and_named():
    rng = np.random.default_rng(2)
    psf, raw = _camera_pair(rng)
    raw = raw.astype(np.float32)
    raw[5, 6] = 1e38
    with pytest.raises(RawSignalError, match=r"full scale 65535"):
        recon.reconstruct(psf, raw, "wiener")
    with pytest.raises(RawSignalError, match=r"raw sample \(5, 6\) is 1e\+38"):
        recon.reconstruct(psf.astype(np.float32), raw, "wiener")


def test_mixed_bit_depths_pass_when_told_but_the_dark_check_still_holds():
    rng = np.random.default_rng(3)
    psf, raw = _camera_pair(rng, dark=3.0)
    raw8 = np.clip(raw, 0, 255).astype(np.uint8)
    with pytest.raises(RawSignalError, match="uint16 .* uint8"):
        prepare_pair(psf, raw8)
    prepared = prepare_pair(psf, raw8, allow_mixed_ranges=True)  # dark 3 fits the raw
    assert prepared.raw.max() > 0
    with pytest.raises(RawSignalError, match="below"):
        prepare_pair(psf + np.uint16(3000), raw8, allow_mixed_ranges=True)


def test_a_dark_level_drifting_by_a_few_counts_is_not_refused():
    """The PSF's dark corner 2 % of the raw's range above the raw's own dark level
    (temperature drift between the captures) is tolerated; 10x further is refused."""
    rng = np.random.default_rng(4)
    psf, raw = _camera_pair(rng, dark=100.0)
    r = raw.astype(np.float64)
    floor, top = np.percentile(r, [0.1, 99.9])
    for drift, refused in ((0.015, False), (0.5, True)):
        level = floor + drift * (top - floor)  # a dark level above the raw's floor
        if refused:
            with pytest.raises(RawSignalError, match="below|no signal"):
                check_raw_signal(raw, r - level, dark_level=level, dark_source="test")
        else:
            check_raw_signal(raw, r - level, dark_level=level, dark_source="test")


def test_a_psf_corner_that_catches_light_is_warned_not_refused(caplog):
    """A PSF whose "dark" corner holds light gives a level above the raw's dark level:
    a few per cent of a dim raw lies below it (logged with both levels); half of it
    would be refused."""
    rng = np.random.default_rng(8)
    psf, raw = _camera_pair(rng, dark=100.0)
    psf[:20, :20] += np.uint16(60)  # light in the corner: its mean reads 160
    raw = rng.normal(400, 4, raw.shape)
    raw[:6] = rng.normal(100, 4, raw[:6].shape)  # 12 % of the raw at the true dark level
    with caplog.at_level("WARNING", logger="recon.preprocess.signal"):
        out = prepare_pair(psf, raw)
    assert 0.1 < out.info["raw_levels"]["below_dark_fraction"] < 0.5
    assert "below the dark level 159" in caplog.text and "--dark LEVEL" in caplog.text


def test_one_dark_colour_channel_is_a_colour_not_a_fault():
    rng = np.random.default_rng(5)
    psf, raw = _camera_pair(rng, dark=100.0)
    def dark_frame():
        return np.rint(rng.normal(100, 4, raw.shape)).astype(np.uint16)

    rgb = np.stack([raw, dark_frame(), dark_frame()], axis=-1)  # a red scene
    prepared = prepare_pair(psf, rgb, dark=100.0)
    assert prepared.raw.shape[-1] == 3
    grey = np.stack([dark_frame() for _ in range(3)], axis=-1)
    with pytest.raises(RawSignalError, match="no signal"):
        prepare_pair(psf, grey, dark=100.0)


def test_noise_sigma_ignores_a_ramp():
    rng = np.random.default_rng(6)
    ramp = np.add.outer(np.arange(64.0), 3 * np.arange(64.0))
    assert noise_sigma(ramp) == 0.0
    assert noise_sigma(ramp + rng.normal(0, 2, ramp.shape)) == pytest.approx(2, rel=0.15)


def test_an_integer_psf_bounds_the_raws_range():
    check_pair_ranges(np.ones((4, 4), np.uint8), np.full((4, 4), 255.0))
    with pytest.raises(RawSignalError, match="above the full scale 255"):
        check_pair_ranges(np.ones((4, 4), np.uint8), np.full((4, 4), 300.0))
    check_pair_ranges(np.ones((4, 4), np.uint8), np.full((4, 4), 300.0),
                      allow_mixed_ranges=True)


def test_3d_and_the_psf_grid_check_the_raw_too():
    rng = np.random.default_rng(7)
    psf, raw = _camera_pair(rng)
    stack = np.stack([psf, np.roll(psf, 3, 1)]).astype(np.float32)
    ok = reconstruct_volume(stack, [1.0, 2.0], raw, method="fista", iterations=2, tv=0.0)
    assert ok.info["raw_levels"]["floor"] > 3000
    with pytest.raises(RawSignalError, match="below"):
        reconstruct_volume(stack, [1.0, 2.0], raw.astype(np.float32) - 3168, method="fista",
                           iterations=2, tv=0.0)
    from recon import reconstruct_grid
    from recon.spatial import PsfGrid

    centre = (psf.astype(np.float64) - 3168).clip(0, None)
    grid = PsfGrid(np.stack([centre] * 4), np.array(
        [[-8.0, -8.0], [-8.0, 8.0], [8.0, -8.0], [8.0, 8.0]]), (2, 2))
    with pytest.raises(RawSignalError, match="below the dark level 3168 .from the dark value"):
        reconstruct_grid(grid, raw.astype(np.float32) - 3168, dark=3168.0, iterations=2,
                         model="convolution")
