"""A scene calibration's field response (recon.field_response, fitted by
recon.analysis.field_response): a smooth gain over the field, recovered from
reconstructions that a known field dims, kept only when it pays on held-out pairs,
stored in the recipe's file and applied by the recipe's reconstruction."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from recon.analysis.early_stop import gain_fitted_error
from recon.analysis.field_response import fit_field_response, held_out_field_gain_db
from recon.early_stop import EarlyStop, psf_identity
from recon.errors import ReconInputError
from recon.field_response import STEP_PX, apply_field_response, check_field_response, field_gain

ROWS, COLS = 120, 200


def _scenes(n, seed, support=True):
    """Textured RGB scenes, dark outside a centred rectangle when ``support``."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        x = gaussian_filter(rng.random((ROWS, COLS, 3)), (1.5, 1.5, 0)) + 0.1
        if support:
            x[:25], x[-25:], x[:, :40], x[:, -40:] = 0, 0, 0, 0
        out.append(x.astype(np.float32))
    return out


def _vignette():
    """A smooth falloff towards the edges: 1 in the centre, 0.5 in the corners."""
    r = np.linspace(-1, 1, ROWS)[:, None] ** 2 + np.linspace(-1, 1, COLS)[None, :] ** 2
    return (1 - 0.25 * r).astype(np.float32)


def _reconstructions(scenes, seed, vignette=True, leak=True):
    """What a shift-invariant model makes of them: the field dimmed by the vignette,
    a haze of light leaked over the whole field, noise."""
    rng = np.random.default_rng(seed)
    v = _vignette() if vignette else np.ones((ROWS, COLS), np.float32)
    out = []
    for x in scenes:
        haze = gaussian_filter(x, (8, 8, 0)).mean() * 0.3 if leak else 0.0
        out.append((x * v[..., None] + haze + 0.02 * rng.standard_normal(x.shape))
                   .astype(np.float32))
    return out


def _errors(scenes):
    """Each scene's gain-fitted error measure (what the recipe's fit scores with)."""
    return [lambda e, s=s: gain_fitted_error(e, s) for s in scenes]


def test_the_grid_interpolates_evenly_at_any_size():
    grid = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    full, half = field_gain(grid, (40, 60)), field_gain(grid, (20, 30))
    assert full.shape == (40, 60) and full.dtype == np.float32
    assert full[:, :10].min() == pytest.approx(1.0) and full[:, -10:].max() == pytest.approx(3.0)
    assert np.all(np.diff(full[0]) >= 0) and full[:, 30].mean() == pytest.approx(2.0, abs=0.05)
    assert np.allclose(full[1::2, 1::2], half, atol=0.06)  # a binned image, the same field
    assert np.array_equal(field_gain(np.full((3, 5), 0.7), (9, 11)), np.full((9, 11), 0.7,
                                                                             np.float32))


def test_apply_multiplies_every_channel_and_none_leaves_the_image():
    image = np.ones((20, 30, 3), np.float32)
    grid = np.array([[0.0, 2.0]])
    out = apply_field_response(image, grid)
    assert out.shape == image.shape and np.array_equal(out[..., 0], out[..., 2])
    assert out[:, 0].max() == 0.0 and out[:, -1].min() == pytest.approx(2.0)
    assert apply_field_response(image[..., 0], grid).shape == (20, 30)
    kept = apply_field_response(image, None)
    assert np.array_equal(kept, image) and kept is not image


def test_the_fit_recovers_the_vignette_and_the_dark_surround():
    scenes = _scenes(4, 1)
    grid = fit_field_response(_reconstructions(scenes, 2, leak=False), scenes)
    assert grid.shape == (round(ROWS / STEP_PX), round(COLS / STEP_PX))
    gain = field_gain(grid, (ROWS, COLS))
    inner = (slice(45, 75), slice(70, 130))  # away from the support's edges
    truth = 1 / _vignette()
    assert np.median(gain[inner] / truth[inner]) == pytest.approx(1.0, abs=0.1)
    with_haze = fit_field_response(_reconstructions(scenes, 2), scenes)
    edge = field_gain(with_haze, (ROWS, COLS))
    # light where no scene had any: 0 in the 40-px side bands, well down in the 25-px
    # top band (the smoothing reaches into it)
    assert np.median(edge[:, :20]) < 0.1 and np.median(edge[:5]) < 0.5 * np.median(edge[45:75])


def test_held_out_gain_pays_for_a_systematic_field_and_not_for_none():
    scenes = _scenes(4, 3)
    paid = held_out_field_gain_db(_reconstructions(scenes, 4), scenes, _errors(scenes))
    assert paid.shape == (4,) and paid.min() > 1.0
    flat = _scenes(4, 5, support=False)  # scenes filling the field, no vignette, no haze
    unpaid = held_out_field_gain_db(_reconstructions(flat, 6, vignette=False, leak=False),
                                    flat, _errors(flat))
    assert unpaid.mean() < 0.05
    imgs = _reconstructions(scenes, 4)
    k = 2  # the figure is each pair's error against the response fitted on the others
    grid = fit_field_response([imgs[j] for j in range(4) if j != k],
                              [scenes[j] for j in range(4) if j != k])
    expected = 20 * np.log10(gain_fitted_error(imgs[k], scenes[k])
                             / gain_fitted_error(apply_field_response(imgs[k], grid),
                                                 scenes[k]))
    assert paid[k] == pytest.approx(expected, rel=1e-9)


def test_bad_input_is_refused():
    with pytest.raises(ReconInputError, match="at least two"):
        held_out_field_gain_db(_scenes(1, 1), _scenes(1, 1), _errors(_scenes(1, 1)))
    with pytest.raises(ReconInputError, match="no calibration pair"):
        fit_field_response([], [])
    with pytest.raises(ReconInputError, match="scene's grid"):
        fit_field_response([np.ones((4, 5, 3))], [np.ones((4, 6, 3))])
    for bad in ([1.0, 2.0], [[1.0, -0.5]], [[np.nan]], [[]], "x"):
        with pytest.raises(ReconInputError, match="field_response"):
            check_field_response(bad)


def test_the_recipe_stores_and_applies_its_field_response(tmp_path):
    psf = np.ones((8, 8), np.float32)
    grid = np.array([[0.5, 1.0], [1.5, 2.0]])
    fit = EarlyStop(10, (10,), np.zeros((1, 1, 1, 2)), psf_identity(psf),
                    field_response=grid, field_gain_db=0.8)
    d = fit.to_dict()
    back = EarlyStop.from_dict(d)
    assert np.allclose(back.field_response, grid) and back.field_gain_db == 0.8
    assert "field response (+0.80 dB" in back.method and back.record()["field_response"]
    d_bad = dict(d, field_response=[[0.5, -1.0]])
    with pytest.raises(ReconInputError, match="field_response"):
        EarlyStop.from_dict(d_bad)
    with pytest.raises(ReconInputError, match="field_gain_db"):
        EarlyStop.from_dict(dict(d, field_gain_db="much"))
    plain = EarlyStop.from_dict({k: v for k, v in d.items()
                                 if k not in ("field_response", "field_gain_db")})
    assert plain.field_response is None and not plain.record()["field_response"]


def test_the_recipes_reconstruction_is_multiplied_by_its_field_response():
    from dataclasses import replace

    from recon.analysis.early_stop import reconstruct_early_stopped

    rng = np.random.default_rng(7)
    psf = gaussian_filter(rng.random((24, 32)), 1.0).astype(np.float32)
    raw = gaussian_filter(rng.random((24, 32)), 1.0).astype(np.float32)
    plain = EarlyStop(5, (5,), np.zeros((1, 1, 1, 2)), psf_identity(psf), denoise_weight=0.0)
    grid = np.array([[0.0, 1.0, 2.0]])
    shaped = replace(plain, field_response=grid, field_gain_db=1.0)
    a = reconstruct_early_stopped(psf, raw, plain, dark="none").image
    b = reconstruct_early_stopped(psf, raw, shaped, dark="none")
    assert np.allclose(b.image, apply_field_response(a, grid), rtol=1e-5, atol=1e-7)
    assert b.info.extra["calibration"]["field_response"] is True


def test_a_gain_where_the_images_hold_no_light_is_bounded():
    """Where every reconstruction is near zero but the scenes are lit, the gain is the
    ratio of two near-empty sums; it is capped at MAX_GAIN (it reached 268 on real
    pairs whose PSF was estimated with a sensor response)."""
    from recon.analysis.field_response import MAX_GAIN

    scenes = _scenes(3, 7, support=False)
    images = [s.copy() for s in scenes]
    for im in images:
        im[:, :90] *= 1e-4  # a band the reconstructions left dark
    grid = fit_field_response(images, scenes)
    assert grid.max() == pytest.approx(MAX_GAIN)
    assert np.median(field_gain(grid, scenes[0].shape)[:, 130:]) == pytest.approx(1.0, abs=0.05)
