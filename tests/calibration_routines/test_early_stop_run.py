"""calibrate psf-from-scenes writes a reconstruction recipe that recon uses by default with
the run's PSF (or named by --early-stop), and refuses with another PSF
(recon.analysis.early_stop)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from instrument.cli import main
from instrument.runs.runstore import RunStore
from recon.analysis.early_stop import CANDIDATES, THRESHOLDS, WEIGHTS
from recon.early_stop import EarlyStop, psf_identity
from recon.operators import ConvolutionOperator

ROWS, COLS = 24, 32


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """Four synthetic pairs as .npy files, calibrated by the command; a fifth raw."""
    tmp = tmp_path_factory.mktemp("early_stop_run")
    rng = np.random.default_rng(5)
    h = np.zeros((ROWS, COLS), np.float32)
    for _ in range(12):
        h[rng.integers(2, ROWS - 2), rng.integers(2, COLS - 2)] = rng.random() + 0.5
    padded = np.pad(gaussian_filter(h, 0.7), ((ROWS // 2, ROWS // 2), (COLS // 2, COLS // 2)))
    (tmp / "scenes").mkdir()
    (tmp / "raw").mkdir()
    for i in range(5):
        x = (np.clip(gaussian_filter(rng.random((ROWS, COLS)), 1.5) * 4 - 1.5, 0, None)
             + 0.05).astype(np.float32)
        b = ConvolutionOperator(x).forward(padded)
        b = (b + 0.03 * b.std() * rng.standard_normal(b.shape)).astype(np.float32)
        where = "held" if i == 4 else "raw"
        np.save(tmp / ("held_scene.npy" if i == 4 else f"scenes/p{i}.npy"), x)
        np.save(tmp / (f"{where}.npy" if i == 4 else f"raw/p{i}.npy"), b)
    run = tmp / "cal.zarr"
    code = main(["calibrate", "psf-from-scenes", "--scenes", str(tmp / "scenes"),
                 "--measurements", str(tmp / "raw"), "--z-mm", "20", "--out", str(run)])
    assert code == 0
    return tmp, run


def test_the_calibration_run_holds_the_fit_for_its_psf(calibrated):
    _, run = calibrated
    fit = EarlyStop.load(run)
    psf = RunStore.open(run).product("psf_stack")[0][0]
    assert fit.psf_sha256 == psf_identity(psf)
    assert fit.iterations in CANDIDATES and fit.errors.shape == (
        len(THRESHOLDS), len(CANDIDATES), len(WEIGHTS), 4)
    assert fit.psf_threshold in THRESHOLDS and fit.denoise_weight in WEIGHTS
    assert fit.pairs == ("p0", "p1", "p2", "p3")
    summary = RunStore.open(run).attrs["summary"]
    assert summary["early_stop"]["iterations"] == fit.iterations
    assert summary["early_stop"]["psf_threshold"] == fit.psf_threshold


def test_recon_runs_the_fitted_count_and_refuses_another_psf(calibrated, capsys):
    tmp, run = calibrated
    fit = EarlyStop.load(run / "early_stop.json")
    metrics = tmp / "m.json"
    assert main(["recon", "--psf", str(run), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--early-stop", str(run), "--out", str(tmp / "rec.png"),
                 "--metrics-json", str(metrics)]) == 0
    m = json.loads(metrics.read_text())
    assert (m["method"], m["iterations_used"], m["tv"]) == ("fista", fit.iterations, 0.0)
    other = RunStore.open(run).product("psf_stack")[0][0][::-1].copy()
    np.save(tmp / "other_psf.npy", other)
    capsys.readouterr()
    assert main(["recon", "--psf", str(tmp / "other_psf.npy"), "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--early-stop", str(run),
                 "--out", str(tmp / "rec2.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "fitted for another PSF" in err and "Traceback" not in err
    assert not (tmp / "rec2.png").exists()


def _recon(tmp, run, name, *extra):
    metrics = tmp / f"{name}.json"
    assert main(["recon", "--psf", str(run), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", *extra, "--out", str(tmp / f"{name}.png"),
                 "--metrics-json", str(metrics)]) == 0
    return json.loads(metrics.read_text())


def test_the_runs_recipe_is_the_default_unless_declined_or_a_method_is_named(calibrated,
                                                                          capsys):
    tmp, run = calibrated
    fit = EarlyStop.load(run)
    capsys.readouterr()
    plain = _recon(tmp, run, "plain")
    assert "scene-calibration recipe" in capsys.readouterr().out
    assert (plain["method"], plain["iterations_used"]) == ("fista", fit.iterations)
    assert plain["calibration"]["psf_sha256"] == fit.psf_sha256
    assert plain["calibration"]["denoise_weight"] == fit.denoise_weight
    off = _recon(tmp, run, "off", "--early-stop", "off")
    named = _recon(tmp, run, "named", "--method", "admm")
    for m in (off, named):
        assert m["method"] == "admm" and m["calibration"] is None


def test_recon_run_uses_the_recipe_on_every_frame(calibrated, capsys):
    """recon-run --psf RUN reconstructs a run's frames with the run's recipe (product
    recon_recipe, the recipe recorded), each frame as recon would; --early-stop off
    declines it."""
    import recon
    from instrument.acquisition.recorder import VIDEO_COORDS
    from instrument.processing.reconstruct_files import resolve_dark

    tmp, cal = calibrated
    held = np.load(tmp / "held.npy")
    frames = np.stack([held * s for s in (800.0, 1000.0, 1200.0)])
    video = tmp / "video.zarr"
    store = RunStore.create(video, plan_name="video", plan_params={"frames": 3}, points=[{}],
                            frame_tags=[["video"] * 3], frame_shape=frames.shape[1:],
                            frame_dtype=np.uint16, coord_names=list(VIDEO_COORDS))
    rows = np.zeros((3, len(VIDEO_COORDS)))
    rows[:, 0] = np.arange(3)
    store.write_frames(0, np.round(frames + 10).astype(np.uint16), rows)
    capsys.readouterr()
    assert main(["recon-run", str(video), "--psf", str(cal), "--depth", "20", "--dark", "10",
                 "--workers", "1"]) == 0
    assert "scene-calibration recipe" in capsys.readouterr().out
    images, attrs = RunStore.open(video).product("recon_recipe")
    fit = EarlyStop.load(cal)
    assert attrs["calibration"]["psf_sha256"] == fit.psf_sha256
    psf = RunStore.open(cal).product("psf_stack")[0][0]
    with_level, level = resolve_dark("10", psf, calibrated=True)  # as the commands do
    one = recon.reconstruct(with_level, np.round(frames[1] + 10).astype(np.uint16),
                            early_stop=str(cal), dark=level)
    np.testing.assert_allclose(images[1], one.image, rtol=1e-4, atol=1e-5 * one.image.max())
    assert main(["recon-run", str(video), "--psf", str(cal), "--depth", "20", "--dark", "10",
                 "--workers", "1", "--early-stop", "off", "--method", "wiener"]) == 0
    assert "calibration" not in RunStore.open(video).product("recon_wiener")[1]


def test_the_windows_batch_form_takes_the_recipe_as_recon_run_does(calibrated):
    """The Batch form (gui.jobs.batch_options) gives recon-run's default: a scene-
    calibrated PSF run's recipe, unless the form declines it or names a method."""
    pytest.importorskip("PySide6")
    from gui.jobs import batch_options

    tmp, cal = calibrated
    form = {"--psf": str(cal), "--depth": "20", "--dark": "10", "--workers": "1"}
    recon, own = batch_options(form)
    assert recon.early_stop == str(cal / "early_stop.json") and own.psf == str(cal)
    assert batch_options({**form, "--early-stop": "off"})[0].early_stop == "off"
    assert batch_options({**form, "--method": "admm"})[0].early_stop is None
    np.save(tmp / "plain_psf.npy", RunStore.open(cal).product("psf_stack")[0][0])
    assert batch_options({**form, "--psf": str(tmp / "plain_psf.npy")})[0].early_stop is None


def test_the_napari_widget_takes_the_recipe_as_recon_does(calibrated):
    """napari's Reconstruct widget with a scene-calibrated run: the run's recipe, the
    image recon gives; a method named declines it."""
    pytest.importorskip("napari")
    from napari.layers import Image

    import recon
    from gui.napari_plugin.widget import reconstruct_layer

    tmp, cal = calibrated
    held = np.load(tmp / "held.npy")
    layer = Image(held, name="held")
    data, kwargs, _ = reconstruct_layer(layer, cal, depth_mm=20, dark="none")
    assert kwargs["metadata"]["early_stop"] == str(cal / "early_stop.json")
    psf = RunStore.open(cal).product("psf_stack")[0][0]
    one = recon.reconstruct(psf, held, early_stop=str(cal), dark=None)
    np.testing.assert_allclose(data, one.image, rtol=1e-4, atol=1e-5 * one.image.max())
    _, named, _ = reconstruct_layer(layer, cal, depth_mm=20, dark="none", method="admm",
                                    iterations=20)
    assert "early_stop" not in named["metadata"] and named["metadata"]["method"] == "admm"
