"""``recon.reconstruct(model, raw)``: one call, one result, one orientation for a PSF,
a PSF stack and a PSF grid."""

from __future__ import annotations

import dataclasses
import inspect
import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import recon
import recon.api  # its module, not only the names recon re-exports lazily
from diffuserlab.jsonio import json_text
from recon.errors import ReconInputError
from recon.operators import ConvolutionOperator, padded_grid
from recon.options import ReconOptions
from recon.planar import reconstruct_image
from recon.spatial import PsfGrid
from recon.spatial.api import reconstruct_psf_grid
from recon.volume.api import reconstruct_stack

SENSOR = (40, 48)
#: Two points of the object, padded-grid coordinates, off-centre and of unequal
#: brightness: a flip of either axis moves them.
POINTS = ((34, 38, 1.0), (46, 62, 0.6))


def _psf():
    rng = np.random.default_rng(0)
    h = np.zeros(SENSOR, np.float32)
    h[rng.integers(12, 28, 12), rng.integers(14, 34, 12)] = 1.0
    return gaussian_filter(h, 0.7) + 1e-4


def _raw(psf, amplitude=400.0):
    """A measurement of POINTS through the convolution model (Eq. 3.4)."""
    padded, _, _ = padded_grid(SENSOR)
    x = np.zeros(padded, np.float32)
    for r, c, a in POINTS:
        x[r, c] = a
    op = ConvolutionOperator((psf / psf.sum()).astype(np.float32))
    return amplitude * op.forward(x)


def _truth():
    """Where POINTS land in the sensor field of view on the model grid."""
    _, (top, left), _ = padded_grid(SENSOR)
    return {(r - top, c - left) for r, c, _ in POINTS}


def _brightest(image, n=2):
    top = np.argsort(image.ravel())[-n:]
    return {tuple(int(v) for v in np.unravel_index(i, image.shape)) for i in top}


def _grid(psf):
    """A 3 x 3 grid whose registered PSFs are all ``psf``: the local model is then the
    convolution model, so it must put the points where the single PSF does."""
    shifts = [(dy, dx) for dy in (-8, 0, 8) for dx in (-10, 0, 10)]
    return PsfGrid(np.stack([psf] * 9), np.array(shifts, float), (3, 3))


def _models(psf):
    return {"image": psf,
            "volume": recon.PsfStack(np.stack([psf, np.roll(psf, 7, axis=1)]), [2.0, 3.0]),
            "grid": _grid(psf)}


# -- dispatch and defaults ------------------------------------------------------------

@pytest.mark.parametrize("kind", ["image", "volume", "grid"])
def test_the_model_kind_picks_the_path_with_the_same_defaults(kind, monkeypatch):
    """Each kind reaches its own path, with method, weight and dark level automatic."""
    psf = _psf()
    seen = {}
    engines = {"image": ("recon.planar", "reconstruct_image"),
               "volume": ("recon.volume.api", "reconstruct_stack"),
               "grid": ("recon.spatial.api", "reconstruct_psf_grid")}
    module, name = engines[kind]

    def engine(*args, **kw):  # the 2D path takes the options object (ReconOptions)
        chosen = [a for a in args if isinstance(a, ReconOptions)]
        seen.update(chosen[0].model_dump() if chosen else kw)
        return "called"

    monkeypatch.setattr(f"{module}.{name}", engine)
    assert recon.reconstruct(_models(psf)[kind], _raw(psf)) == "called"
    assert recon.api.model_kind(_models(psf)[kind]) == kind
    assert (seen["method"], seen["tv"], seen["iterations"], seen["bin_factor"]) == (
        "auto", "auto", 200, 1)
    assert seen["dark"] == "auto"


def test_the_three_paths_declare_the_same_defaults():
    """The kinds' own functions take the options object the front door passes, and
    without one the declared defaults, the front door's."""
    door = inspect.signature(recon.reconstruct).parameters
    for engine in (reconstruct_image, reconstruct_stack, reconstruct_psf_grid):
        assert inspect.signature(engine).parameters["options"].default is None
    defaults = ReconOptions.from_defaults()
    for name in ("method", "iterations", "tv", "bin_factor", "dark"):
        assert getattr(defaults, name) == door[name].default, name


def test_a_list_of_grids_is_a_grid_model_and_aliases_reach_the_front_door():
    psf = _psf()
    assert recon.api.model_kind([_grid(psf), _grid(psf)]) == "grid"
    vol = recon.reconstruct_volume(np.stack([psf, psf[::-1]]), [1.0, 2.0], _raw(psf),
                                   method="fista", tv=0.0, iterations=3, dark="none")
    assert vol.info.kind == "volume" and vol.volume.shape == (2, *SENSOR)
    with pytest.raises(ReconInputError, match="PsfGrid"):
        recon.reconstruct_grid(psf, _raw(psf))


@pytest.mark.parametrize("model, words", [
    ("psf.tif", "model is str"),
    (np.zeros(5), r"an array of shape \(5,\)"),
    (np.zeros((2, 3, 4, 5)), r"an array of shape \(2, 3, 4, 5\)"),
    ([], "model is list"),
])
def test_a_bad_model_names_what_is_accepted(model, words):
    with pytest.raises(ReconInputError, match=words) as err:
        recon.reconstruct(model, np.ones(SENSOR))
    text = str(err.value)
    assert "a PSF array" in text and "PsfStack" in text and "PsfGrid" in text


@pytest.mark.parametrize("kind, option", [("image", "empty_planes"), ("volume", "erase"),
                                          ("grid", "empty_planes"), ("volume", "model")])
def test_an_option_of_another_kind_is_refused_by_name(kind, option):
    psf = _psf()
    with pytest.raises(ReconInputError, match=f"takes no option '{option}'"):
        recon.reconstruct(_models(psf)[kind], _raw(psf), **{option: 1})


# -- dark level ------------------------------------------------------------------------

def _quick(kind):
    return {"image": {"method": "fista", "tv": 0.0, "iterations": 4},
            "volume": {"method": "fista", "tv": 0.0, "iterations": 4},
            "grid": {"method": "fista", "background": "none", "l1": 0.0, "iterations": 4}}[kind]


@pytest.mark.parametrize("kind", ["image", "volume", "grid"])
def test_dark_means_the_same_for_every_model_kind(kind):
    """None and "none" subtract nothing; a number is a level in DN; an array is a dark
    frame; anything else is refused with the vocabulary."""
    psf = _psf()
    model = _models(1000.0 * psf + 7.0)[kind] if kind != "grid" else _grid(psf)
    raw = _raw(psf) + 7.0
    rec_none = recon.reconstruct(model, raw, dark=None, **_quick(kind))
    rec_word = recon.reconstruct(model, raw, dark="none", **_quick(kind))
    assert np.array_equal(rec_none.image, rec_word.image)
    assert rec_none.info.dark_mode == "none" and rec_none.info.dark_level is None
    level = recon.reconstruct(model, raw, dark=7.0, **_quick(kind)).info
    assert level.dark_level == 7.0 and "value given" in level.dark_source
    frame = recon.reconstruct(model, raw, dark=np.full(SENSOR, 7.0), **_quick(kind)).info
    assert frame.dark_mode == "frame" and frame.dark_level == pytest.approx(7.0)
    assert recon.reconstruct(model, raw, **_quick(kind)).info.dark_mode in (
        "psf_region", "auto")
    with pytest.raises(ReconInputError, match="'auto', 'none'"):
        recon.reconstruct(model, raw, dark="bright", **_quick(kind))


def test_a_grid_subtracts_the_dark_level_from_the_frame_only():
    """The grid's PSFs are dark-subtracted: a frame with an offset and its level given
    equals the frame without the offset."""
    psf = _psf()
    raw = _raw(psf)
    a = recon.reconstruct(_grid(psf), raw + 9.0, dark=9.0, **_quick("grid"))
    b = recon.reconstruct(_grid(psf), raw, dark="none", **_quick("grid"))
    np.testing.assert_allclose(a.image, b.image, rtol=1e-4, atol=1e-4 * b.image.max())


# -- the result ------------------------------------------------------------------------

def test_info_is_a_frozen_typed_record_that_still_reads_like_the_former_dict():
    psf = _psf()
    rec = recon.reconstruct(psf, _raw(psf), iterations=30, dark="none")
    info = rec.info
    names = {f.name for f in dataclasses.fields(info)}
    assert {"kind", "method", "method_reason", "iterations", "iterations_used", "tv", "l1",
            "auto", "dark_mode", "dark_level", "dark_source", "bin_factor", "raw_scale",
            "seconds_total", "histories"} <= names
    assert info.kind == "image" and info.method == "admm" and info.method_reason != "given"
    assert info.iterations == 30 and 1 <= info.iterations_used
    assert info.tv == info.auto[0]["weight"]["weight"] > 0  # the automatic weight
    assert info["method"] == info.method and info["raw_levels"] == info.extra["raw_levels"]
    assert "erased_fraction" in info and info.get("nothing", 3) == 3
    assert info.histories[0] is rec.results[0].history
    with pytest.raises(dataclasses.FrozenInstanceError):
        info.method = "wiener"
    json.loads(json_text(info.as_dict()))  # JSON-ready
    metrics = rec.metrics(1e-3)  # the CLI's keys
    for key in ("method", "iterations", "iterations_used", "tv", "l1", "auto", "shape",
                "bin_factor", "seconds_per_iteration", "ratio_to_fft_floor", "dark"):
        assert key in metrics


@pytest.mark.parametrize("kind", ["image", "volume", "grid"])
def test_repr_is_one_short_line_and_metrics_serve_every_kind(kind):
    psf = _psf()
    rec = recon.reconstruct(_models(psf)[kind], _raw(psf), dark="none", **_quick(kind))
    text = repr(rec)
    assert len(text) < 160 and "\n" not in text and "array" not in text
    assert f"kind='{kind}'" in text and "float32" in text and "method='fista'" in text
    assert "iterations=" in text and "seconds=" in text
    m = rec.metrics(1e-3)
    assert m["method"] == "fista" and m["iterations"] == 4 and m["shape"] == list(
        rec.image.shape)
    json.loads(json_text(m))


@pytest.mark.parametrize("kind", ["image", "volume", "grid"])
def test_upright_flips_the_lateral_axes_only(kind):
    psf = _psf()
    rec = recon.reconstruct(_models(psf)[kind], _raw(psf), dark="none", **_quick(kind))
    up = rec.upright()
    assert np.shares_memory(up, rec.image)  # a view
    if rec.image.ndim == 3:
        np.testing.assert_array_equal(up, rec.image[:, ::-1, ::-1])
    else:
        np.testing.assert_array_equal(up, rec.image[::-1, ::-1])


# -- one orientation -------------------------------------------------------------------

def test_one_psf_a_stack_and_a_grid_put_the_points_at_the_same_pixels():
    """The same two points through the same PSF: the 2D image, the stack's first plane
    and the grid's image all hold them where the model grid puts them (Eq. 3.3), so
    every product is in one orientation and ``upright()`` turns them alike."""
    psf = _psf()
    raw = _raw(psf)
    truth = _truth()
    image = recon.reconstruct(psf, raw, "fista", tv=0.0, iterations=150, dark="none")
    stack = recon.reconstruct(recon.PsfStack(psf[None], [2.0]), raw, "fista", tv=0.0,
                              iterations=150, dark="none")
    grid = recon.reconstruct(_grid(psf), raw, "fista", background="none", l1=0.0,
                             iterations=150, dark="none")
    assert _brightest(image.image) == truth
    assert _brightest(stack.image[0]) == truth
    assert _brightest(grid.image) == truth
    flipped = {(SENSOR[0] - 1 - r, SENSOR[1] - 1 - c) for r, c in truth}
    for rec in (image, grid):
        assert _brightest(rec.upright()) == flipped
    assert _brightest(stack.upright()[0]) == flipped
