"""Properties of the array entry points of :mod:`recon.io` (round trips through
:func:`instrument.writer.files.save_image`,
demosaicing, the viewing flip) and :mod:`recon.analysis.reports` (the numbers of
``diffuserlab analyze``): documented shapes and values for valid random arrays, and a
one-line :class:`~recon.errors.ReconInputError` naming the argument for invalid ones."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from instrument.writer.files import save_image
from recon.analysis import reports
from recon.errors import ReconInputError
from recon.io import BAYER_PATTERNS, demosaic_bayer, load_image, scene_view

from .test_properties_common import (
    DTYPES,
    FAST,
    NOT_POSITIVE,
    assert_call_refused,
    assert_refused,
    bad_arrays,
    case_id,
    not_counts,
    random_array,
)

STACK = random_array((3, 24, 24), np.float64, 8)
DEPTHS = [30.0, 10.0, 20.0]


@st.composite
def saved_images(draw):
    shape = (draw(st.integers(1, 24)), draw(st.integers(1, 24)))
    shape += draw(st.sampled_from([(), (3,), (4,)]))
    return random_array(shape, draw(st.sampled_from(DTYPES)), draw(st.integers(0, 2**16)))


@FAST
@given(image=saved_images(), ext=st.sampled_from([".npy", ".tif", ".TIFF"]))
def test_data_files_round_trip(tmp_path_factory, image, ext):
    """``.npy`` keeps the array, TIFF the float32 values (the documented data product)."""
    path = tmp_path_factory.mktemp("io") / f"image{ext}"
    save_image(path, image)
    back = load_image(path)
    if ext == ".npy":
        assert back.dtype == image.dtype
        np.testing.assert_array_equal(back, image)
    else:
        assert back.dtype == np.float32
        np.testing.assert_array_equal(back, image.astype(np.float32))


@pytest.mark.parametrize("ext", [".npy", ".tif", ".png"])
@FAST
@given(name=st.sampled_from(["1-D", "4-D", "complex", "object", "empty", "str", "ragged"]))
def test_save_refuses_what_is_not_an_image(tmp_path_factory, ext, name):
    path = tmp_path_factory.mktemp("io") / f"bad{ext}"
    with pytest.raises(ReconInputError) as info:
        save_image(path, bad_arrays()[name])
    assert_refused(info, str(path))
    assert not path.exists()


@FAST
@given(h=st.integers(3, 32), w=st.integers(3, 32), pattern=st.sampled_from(BAYER_PATTERNS),
       dtype=st.sampled_from([np.uint8, np.uint16]), seed=st.integers(0, 1000))
def test_demosaic_keeps_size_dtype_and_flat_fields(h, w, pattern, dtype, seed):
    level = int(random_array((), dtype, seed))
    rgb = demosaic_bayer(np.full((h, w), level, dtype), pattern.lower())
    assert rgb.shape == (h, w, 3) and rgb.dtype == dtype
    np.testing.assert_array_equal(rgb, level)  # a flat mosaic is grey


@FAST
@given(raw=st.one_of(st.sampled_from(["complex", "object", "1-D", "str", "ragged"]).map(
    lambda n: bad_arrays()[n]), st.sampled_from([np.ones((8, 8)), np.ones((8, 8, 3), np.uint8)]),
    st.tuples(st.integers(1, 2), st.integers(1, 9)).map(lambda s: np.ones(s, np.uint8)),
    st.tuples(st.integers(1, 9), st.integers(1, 2)).map(lambda s: np.ones(s, np.uint16))))
def test_demosaic_refuses_bad_mosaics(raw):
    with pytest.raises(ReconInputError) as info:
        demosaic_bayer(raw, "RGGB")
    assert_refused(info)


@FAST
@given(image=saved_images())
def test_scene_view_is_an_involution(image):
    view = scene_view(image)
    assert view.shape == image.shape and view.dtype == image.dtype
    np.testing.assert_array_equal(view[::-1, ::-1], image)
    np.testing.assert_array_equal(scene_view(view), image)


@FAST
@given(image=st.sampled_from([np.float64(1.0), np.ones(4), "abc", None]))
def test_scene_view_refuses_what_has_no_rows_and_columns(image):
    with pytest.raises(ReconInputError) as info:
        scene_view(image)
    assert_refused(info, "axes")


# ------------------------------------------------------------------ analysis.reports


@FAST
@given(n_z=st.integers(1, 4), h=st.integers(4, 24), w=st.integers(4, 24),
       bin_factor=st.integers(1, 3), seed=st.integers(0, 1000),
       dtype=st.sampled_from(DTYPES))
def test_prepare_stack_sorts_and_bins(n_z, h, w, bin_factor, seed, dtype):
    stack = random_array((n_z, h, w), dtype, seed)
    depths = list(np.random.default_rng(seed).permutation(n_z) * 10.0 + 5.0)
    out, z = reports.prepare_stack(stack, depths, bin_factor=bin_factor)
    assert list(z) == sorted(depths) and z.dtype == np.float64
    assert out.shape == (n_z, h // bin_factor, w // bin_factor)
    order = np.argsort(depths)
    if bin_factor == 1:
        np.testing.assert_array_equal(out, stack[order])
    else:  # block means keep the flux of the kept block
        kept = stack[order][:, : out.shape[1] * bin_factor, : out.shape[2] * bin_factor]
        np.testing.assert_allclose(out.sum(axis=(1, 2), dtype=np.float64) * bin_factor**2,
                                   kept.sum(axis=(1, 2), dtype=np.float64), rtol=1e-5)


@pytest.mark.parametrize("function", ["prepare_stack", "resolution_per_depth",
                                      "axial_condition", "field_of_view"])
@FAST
@given(name=st.sampled_from(sorted(bad_arrays((3, 24, 24)))) | st.just("2-D"),
       depths=st.sampled_from(["ok", "short", "nan", "str"]))
def test_stack_reports_refuse_bad_stacks_and_depths(function, name, depths):
    stack = STACK[0] if name == "2-D" else bad_arrays((3, 24, 24))[name]
    z = {"ok": DEPTHS, "short": DEPTHS[:2], "nan": [1.0, math.nan, 3.0],
         "str": ["a", "b", "c"]}[depths]
    if depths != "ok":
        stack = STACK  # one problem at a time: the depths
    call = {
        "prepare_stack": lambda: reports.prepare_stack(stack, z, bin_factor=1),
        "resolution_per_depth": lambda: reports.resolution_per_depth(stack, z, pitch_mm=0.01,
                                                                      d_mm=1.0),
        "axial_condition": lambda: reports.axial_condition(stack, z, [1], 2),
        "field_of_view": lambda: reports.field_of_view(stack, z, pitch_mm=0.01, d_mm=1.0,
                                                       alpha_c_deg=30.0),
    }[function]
    with pytest.raises(ReconInputError) as info:
        call()
    assert_refused(info, "PSF stack" if depths == "ok" else "depth")


@pytest.mark.parametrize(("call", "name", "values"), [
    (lambda v: reports.prepare_stack(STACK, DEPTHS, bin_factor=v), "--bin", not_counts(1)),
    (lambda v: reports.prepare_stack(STACK, DEPTHS, bin_factor=1, remove_background=v),
     "--remove-background", not_counts(0)),
    (lambda v: reports.resolution_per_depth(STACK, DEPTHS, pitch_mm=v, d_mm=1.0), "pitch_mm",
     NOT_POSITIVE),
    (lambda v: reports.resolution_per_depth(STACK, DEPTHS, pitch_mm=0.01, d_mm=v), "--d-mm",
     NOT_POSITIVE),
    (lambda v: reports.resolution_per_depth(STACK, DEPTHS, pitch_mm=0.01, d_mm=1.0, level=v),
     "--level", NOT_POSITIVE | st.floats(1.0 + 1e-9, 1e9)),
    (lambda v: reports.lateral_condition(STACK[0], [2.0], v), "--k-max", not_counts(2)),
    (lambda v: reports.lateral_condition(STACK[0], [v], 3), "--separations-px",
     st.sampled_from([0.0, -1.0, math.nan, math.inf, "x"])),
    (lambda v: reports.axial_condition(STACK, DEPTHS, [v], 2), "--separations-planes",
     st.sampled_from([0, -1, 1.5, math.nan, "x"])),
    (lambda v: reports.axial_condition(STACK, DEPTHS, [1], v), "--k-max", not_counts(2)),
    (lambda v: reports.distinguishability(STACK[0], [2.0], iterations=v), "--iterations",
     not_counts(1)),
    (lambda v: reports.field_of_view(STACK, DEPTHS, pitch_mm=0.01, d_mm=1.0, alpha_c_deg=30.0,
                                     support_energy=v), "--support-energy",
     NOT_POSITIVE | st.floats(1.0 + 1e-9, 1e9)),
    (lambda v: reports.support_width_px(STACK[0], 0, v), "--support-energy",
     NOT_POSITIVE | st.floats(1.0 + 1e-9, 1e9)),
    (lambda v: reports.energy_kept(STACK[0], v, 2.0, "line", "x"), "--k-max", not_counts(1)),
], ids=case_id)
@FAST
@given(data=st.data())
def test_report_numbers_are_refused_naming_them(call, name, values, data):
    assert_call_refused(call, data.draw(values), name)


@FAST
@given(h=st.integers(4, 32), w=st.integers(4, 32), seed=st.integers(0, 1000),
       energy=st.floats(0.01, 1.0), axis=st.sampled_from([0, 1]))
def test_support_width_is_within_the_frame_and_grows_with_energy(h, w, seed, energy, axis):
    psf = random_array((h, w), np.float64, seed)
    width = reports.support_width_px(psf, axis, energy)
    full = reports.support_width_px(psf, axis, 1.0)
    assert 1 <= width <= full <= (w if axis == 0 else h) + 1
