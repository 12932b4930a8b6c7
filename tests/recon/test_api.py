"""The notebook API: real data, colour, erasures, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

import recon
from recon.auto.weight import path_budget
from recon.errors import ReconInputError
from tests.real_data import check_hand_image, sample_paths


@pytest.fixture(scope="module")
def real_pair():
    psf_path, raw_path = sample_paths()
    return tifffile.imread(psf_path), tifffile.imread(raw_path)


@pytest.mark.parametrize("method", ["admm", "fista"])
def test_reconstruct_real_hand(real_pair, method):
    psf, raw = real_pair
    result = recon.reconstruct(psf, raw, method=method, iterations=60, bin_factor=4)
    assert result.image.shape == (300, 400)
    assert result.operator.padded_shape == (600, 800)
    hist = result.results[0].history
    # the automatic weight's path and the chosen weight's run on share one budget
    assert len(hist.objective) == result.results[0].params["iterations_used"] <= path_budget(60)
    assert result.info["iterations_used"] == len(hist.objective) or method == "fista"
    # data residual fell by at least 20x from the zero image (relative residual 1)
    assert result.results[0].final_relative_residual < 0.05
    check_hand_image(result.image)


def test_wiener_preview_real(real_pair):
    psf, raw = real_pair
    result = recon.reconstruct(psf, raw, method="wiener", bin_factor=4)
    assert result.results[0].final_relative_residual < 0.1
    check_hand_image(np.maximum(result.image, 0))


def test_colour_channels_independent(real_pair):
    psf, raw = real_pair
    gray = recon.reconstruct(psf, raw, "fista", iterations=20, bin_factor=8)
    rgb_raw = np.stack([raw, raw // 2, raw // 4], axis=-1)
    rgb = recon.reconstruct(psf, rgb_raw, "fista", iterations=20, bin_factor=8)
    assert rgb.image.shape == gray.image.shape + (3,)
    assert len(rgb.results) == 3
    # channel 0 equals the grey reconstruction; the others scale with their raw
    np.testing.assert_allclose(
        rgb.image[..., 0], gray.image, rtol=1e-3, atol=1e-3 * gray.image.max()
    )
    ratio = rgb.image[..., 1].sum() / rgb.image[..., 0].sum()
    assert 0.45 < ratio < 0.55
    # one PSF per channel is also accepted
    per_channel = recon.reconstruct(np.stack([psf] * 3, -1), rgb_raw, "fista", iterations=5,
                                    bin_factor=8)
    assert per_channel.image.shape == rgb.image.shape


def test_an_rgb_image_takes_the_green_channel_s_automatic_weight(real_pair):
    """With an automatic weight an RGB image's weight is chosen once, by the green
    channel's hold-out path, and every channel solves at it on all pixels (a path per
    channel before: each chose and kept its own)."""
    from recon.planar import LEAD_CHANNEL

    psf, raw = real_pair
    rgb_raw = np.stack([raw, raw // 2, raw // 3], axis=-1)
    rec = recon.reconstruct(psf, rgb_raw, bin_factor=8, iterations=40)
    records = rec.info.auto
    lead = records[LEAD_CHANNEL]["weight"]
    assert lead["criterion"] == "holdout" and lead["chosen_by"].startswith("ADMM path")
    for c in (0, 2):
        shared = records[c]["weight"]
        assert shared["criterion"] == "shared" and shared["lead_channel"] == LEAD_CHANNEL
        assert shared["weight"] == lead["weight"] == records[c]["tv"]
        assert "path_iterations" not in shared  # no path of its own
        assert f"channel {LEAD_CHANNEL}" in shared["reason"]
    # the path is sized by the 40 iterations, each channel's solve by half of them
    assert lead["final_iterations"] == 20 == records[0]["weight"]["final_iterations"]
    assert lead["path_iterations"] > 20
    assert all(r["iterations_used"] <= 20 for r in records)
    # a fixed weight, and a grey image, are as before: nothing shared
    fixed = recon.reconstruct(psf, rgb_raw, "admm", tv=1e-3, bin_factor=8, iterations=10)
    assert all("weight" not in r for r in fixed.info.auto)
    grey = recon.reconstruct(psf, raw, bin_factor=8, iterations=40)
    assert grey.info.auto[0]["weight"]["criterion"] == "holdout"


def test_erasure_mask_folds_into_model(real_pair):
    psf, raw = real_pair
    result = recon.reconstruct(psf, raw, "admm", iterations=30, bin_factor=8, erase=0.8, seed=3)
    assert abs(result.info["erased_fraction"] - 0.8) < 0.02
    w = result.operator.sensor_weights
    assert set(np.unique(w)) <= {0.0, 1.0}
    # an explicit mask of the wrong shape is refused
    with pytest.raises(ReconInputError, match="erasure mask shape"):
        recon.reconstruct(psf, raw, "admm", iterations=5, bin_factor=8,
                          erasure_mask=np.ones((3, 3)))


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        (dict(method="nope"), "unknown method"),
        (dict(iterations=0), "iterations"),
        (dict(erase=1.5), "erased fraction"),
    ],
)
def test_bad_parameters(real_pair, kwargs, fragment):
    psf, raw = real_pair
    with pytest.raises(ReconInputError, match=fragment):
        recon.reconstruct(psf, raw, **{"bin_factor": 8, **kwargs})


def test_a_solver_added_to_the_table_is_reachable_by_name(monkeypatch):
    """One entry in recon.solvers.SOLVERS makes a solver usable by recon.reconstruct."""
    from recon.solvers import SOLVERS, SolverSpec, gradient_descent

    calls = []

    def landweber(op, b, *, iterations, tv, **options):
        calls.append((iterations, tv))
        return gradient_descent(op, b, iterations=iterations, tv=tv, momentum=0.0, **options)

    monkeypatch.setitem(SOLVERS, "landweber", SolverSpec(landweber, 0.0, True, "Landweber"))
    rng = np.random.default_rng(0)
    psf = rng.random((16, 20))
    raw = rng.random((16, 20)) + 0.1
    result = recon.reconstruct(psf, raw, method="landweber", iterations=3, tv=0.0, dark="none")
    assert calls == [(3, 0.0)] and result.info["iterations"] == 3
    with pytest.raises(ReconInputError, match="unknown method 'nope'"):
        recon.reconstruct(psf, raw, method="nope")
