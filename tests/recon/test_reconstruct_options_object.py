"""``reconstruct(model, raw, options)``: the options object as the third argument is
the same call as its keywords (issue 66: callers no longer unpack it), and keywords
beside it replace its fields where they are given."""

import numpy as np
import pytest

import recon
from recon.errors import ReconInputError
from recon.options import ReconOptions
from recon.spatial import PsfGrid


@pytest.fixture(scope="module")
def problem():
    psf = np.zeros((24, 32))
    psf[10:13, 14:17] = 1.0
    scene = np.zeros((24, 32))
    scene[8, 9] = scene[15, 20] = 50.0
    raw = np.real(np.fft.ifft2(np.fft.fft2(scene) * np.fft.fft2(np.fft.ifftshift(psf))))
    return psf, raw


def _options(**given):
    return ReconOptions.validated(given, front="python")


def test_the_object_is_its_keywords(problem):
    psf, raw = problem
    options = _options(method="admm", tv=1e-4, iterations=15, dark="none")
    by_object = recon.reconstruct(psf, raw, options)
    by_keywords = recon.reconstruct(psf, raw, **options.keywords("image"))
    np.testing.assert_array_equal(by_object.image, by_keywords.image)
    assert by_object.info.iterations == 15 and by_object.info.method == "admm"


def test_a_grid_takes_the_object_and_its_own_objects_beside(problem):
    psf, raw = problem
    grid = PsfGrid(psf[None], np.zeros((1, 2)), (1, 1))
    options = _options(iterations=8)
    by_object = recon.reconstruct(grid, raw + 5.0, options, tolerance=None)
    by_keywords = recon.reconstruct(grid, raw + 5.0, **options.keywords("grid"))
    np.testing.assert_array_equal(by_object.image, by_keywords.image)
    assert by_object.info.kind == "grid" and by_object.info.iterations == 8


def test_keywords_beside_the_object_replace_its_fields(problem):
    """A dark level the caller resolved, or l1=0.0 (given, though equal to the unset
    default's value), replaces the object's field; a keyword left at its declared
    default leaves the field as the object has it."""
    psf, raw = problem
    options = _options(method="fista", tv=0.0, iterations=12, dark="none", l1=1e-3)
    psf3, raw3 = 100.0 * psf + 3.0, raw + 3.0  # both with a dark level of 3 DN
    beside = recon.reconstruct(psf3, raw3, options, dark=3.0, l1=0.0)
    keywords = {**options.keywords("image"), "dark": 3.0, "l1": 0.0}
    np.testing.assert_array_equal(beside.image, recon.reconstruct(psf3, raw3,
                                                                  **keywords).image)
    assert beside.info.dark_level == 3.0 and beside.info.l1 == 0.0
    kept = recon.reconstruct(psf, raw, options, iterations=200)  # the default: not given
    assert kept.info.iterations == 12


def test_an_option_the_kind_does_not_take_is_refused_as_before(problem):
    psf, raw = problem
    with pytest.raises(ReconInputError, match="takes no option 'depths_mm'"):
        recon.reconstruct(psf, raw, _options(method="wiener"), depths_mm=[1.0])
