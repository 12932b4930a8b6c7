"""A scene calibration's recipe (early_stop.json) is read once per product, is part of its
run's integrity record, is validated when read, and is no default when its PSF explains
little (issue 64, "Data"; instrument.runs.run_recipe, recon.early_stop)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from instrument.cli import main
from instrument.runs.runstore import RunStore
from recon.early_stop import FILE, TRUSTED_RESIDUAL, EarlyStop

from .test_early_stop_run import calibrated  # noqa: F401  (the module's fixture)


@pytest.fixture
def cal_copy(calibrated, tmp_path):  # noqa: F811
    """A copy of the calibration run, free to damage."""
    tmp, run = calibrated
    copy = tmp_path / "cal.zarr"
    shutil.copytree(run, copy)
    return tmp, copy


def _edit(run, **changes):
    path = run / FILE
    d = json.loads(path.read_text())
    d.update(changes)
    path.write_text(json.dumps(d))


def _video(tmp, out, n=6):
    from instrument.acquisition.recorder import VIDEO_COORDS

    held = np.load(tmp / "held.npy")
    frames = np.stack([held * (800.0 + 50 * i) for i in range(n)])
    video = out / "video.zarr"
    store = RunStore.create(video, plan_name="video", plan_params={"frames": n},
                            points=[{}], frame_tags=[["video"] * n],
                            frame_shape=frames.shape[1:], frame_dtype=np.uint16,
                            coord_names=list(VIDEO_COORDS))
    rows = np.zeros((n, len(VIDEO_COORDS)))
    rows[:, 0] = np.arange(n)
    store.write_frames(0, np.round(frames + 10).astype(np.uint16), rows)
    return video, np.round(frames + 10).astype(np.uint16)


def test_a_recipe_edited_while_recon_run_works_changes_no_frame(cal_copy, tmp_path,
                                                                 monkeypatch):
    """The recipe is edited after the first frame is solved (a hook in the worker, one
    thread: every later frame comes after the edit); every frame is still solved with
    the recipe read at the start, and the product records that one."""
    from dask.distributed import LocalCluster

    import instrument.processing.batch as batch
    import recon
    from instrument.processing.reconstruct_files import resolve_dark
    from recon.options import ReconOptions

    tmp, cal = cal_copy
    first = EarlyStop.load(cal)
    other = next(c for c in first.candidates if c != first.iterations)
    video, raws = _video(tmp, tmp_path)
    log, original = tmp_path / "solved.txt", batch.reconstruct_stored_frame

    def solve_then_edit(*args, **kwargs):  # runs in the worker (a copy: state in a file)
        out = original(*args, **kwargs)
        if not log.exists():
            _edit(cal, iterations=other)  # between two frames of one product
        with log.open("a") as fh:
            fh.write(f"{out[0]}\n")
        return out

    monkeypatch.setattr(batch, "reconstruct_stored_frame", solve_then_edit)
    psf, dark, source = batch.batch_psf(str(cal), RunStore.open(video).attrs, depth_mm=20,
                                        dark="10")
    options = ReconOptions.validated({"early_stop": str(cal)})
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=":0") as cluster:
        out = batch.reconstruct_run(video, psf, options, dark=dark, psf_source=source,
                                    scheduler=cluster.scheduler_address)
    solved = [int(v) for v in log.read_text().split()]
    assert out["reconstructed"] == len(raws) and len(solved) == len(raws)
    assert EarlyStop.load(cal).iterations == other  # the file did change meanwhile
    images, attrs = RunStore.open(video).product("recon_recipe")
    assert attrs["calibration"]["iterations"] == first.iterations
    assert attrs["iterations"] == first.iterations
    base = RunStore.open(cal).product("psf_stack")[0][0]
    with_level, level = resolve_dark("10", base, calibrated=True)
    kept = tmp_path / "first.json"  # the recipe as it was when the batch started
    kept.write_text(json.dumps(first.to_dict()))
    for i in solved[1:]:  # each frame after the edit: solved with the first recipe
        one = recon.reconstruct(with_level, raws[i], early_stop=str(kept), dark=level)
        np.testing.assert_allclose(images[i], one.image, rtol=1e-4,
                                   atol=1e-5 * one.image.max())


@pytest.mark.parametrize("damage", ["edited", "deleted", "copied"])
def test_runs_verify_covers_the_recipe(cal_copy, calibrated, damage, tmp_path,  # noqa: F811
                                       capsys):
    """Tampering, deletion, or another run's recipe copied in: runs verify exits 1 with
    a line naming the file; recon --psf RUN and recon-run refuse the recipe (exit 2),
    naming --early-stop off, never falling back to another method in silence."""
    tmp, cal = cal_copy
    assert main(["runs", "verify", str(cal)]) == 0
    if damage == "edited":
        _edit(cal, iterations=EarlyStop.load(cal).candidates[0])
    elif damage == "deleted":
        (cal / FILE).unlink()
    else:  # another calibration's recipe (another PSF) copied in
        d = json.loads((cal / FILE).read_text())
        d["psf_sha256"] = "0" * 64
        (cal / FILE).write_text(json.dumps(d))
    capsys.readouterr()
    assert main(["runs", "verify", str(cal)]) == 1
    out = capsys.readouterr().out
    assert f"{cal / FILE}" in out and ("missing" if damage == "deleted" else "changed") in out
    assert main(["recon", "--psf", str(cal), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--out", str(tmp_path / "r.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--early-stop off" in err and FILE in err
    assert not (tmp_path / "r.png").exists()
    video, _ = _video(tmp, tmp_path, n=2)
    assert main(["recon-run", str(video), "--psf", str(cal), "--depth", "20", "--dark", "10",
                 "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--early-stop off" in err and "recon_recipe" not in RunStore.open(video).products()
    assert main(["recon", "--psf", str(cal), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--early-stop", "off",
                 "--out", str(tmp_path / "off.png")]) == 0


def test_a_recipe_in_a_run_that_wrote_none_is_damage(calibrated, tmp_path, capsys):  # noqa: F811
    tmp, cal = calibrated
    run = tmp_path / "plain.zarr"
    assert main(["runs", "import-psf", str(tmp / "held.npy"), "--out", str(run),
                 "--depths", "20"]) == 0
    shutil.copy(cal / FILE, run / FILE)
    capsys.readouterr()
    assert main(["runs", "verify", str(run)]) == 1
    assert "not written by this run" in capsys.readouterr().out


@pytest.mark.parametrize(("field", "value"), [
    ("iterations", 2.7), ("iterations", 1e9), ("psf_threshold", 0.99),
    ("denoise_weight", 1e6), ("iterations", "many")])
def test_a_recipe_outside_its_candidates_is_refused(calibrated, tmp_path, field, value,  # noqa: F811
                                                    capsys):
    """A recipe file (given by --early-stop as a file) whose value is outside its lists
    is refused in one line naming the field, the value and what is allowed."""
    tmp, cal = calibrated
    d = json.loads((cal / FILE).read_text())
    d[field] = value
    path = tmp_path / "recipe.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=f"{field} {value!r} is not allowed; allowed: "):
        EarlyStop.load(path)
    capsys.readouterr()
    assert main(["recon", "--psf", str(cal), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--early-stop", str(path),
                 "--out", str(tmp_path / "r.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and field in err and "allowed" in err


def test_the_recipes_own_psf_with_a_dark_level_is_refused_for_the_real_reason(
        calibrated, tmp_path, capsys):  # noqa: F811
    """The recipe's PSF as a plain file (dark-subtracted) with --dark 10: the level would
    be subtracted from it again; not "fitted for another PSF"."""
    tmp, cal = calibrated
    psf = tmp_path / "psf.npy"
    np.save(psf, RunStore.open(cal).product("psf_stack")[0][0])
    capsys.readouterr()
    assert main(["recon", "--psf", str(psf), "--raw", str(tmp / "held.npy"), "--dark", "10",
                 "--early-stop", str(cal), "--out", str(tmp_path / "r.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "another PSF" not in err and "subtracted from it again" in err
    assert "--dark none" in err


def test_an_untrusted_recipe_is_recorded_and_is_no_default(cal_copy, tmp_path, caplog):
    """A calibration whose held-out residual is above the bar records its recipe as not
    trusted (with a warning); recon --psf RUN then does not use it (one line: why and
    how to force it), --early-stop RUN still does."""
    from instrument.runs.run_recipe import write_run_recipe

    tmp, cal = cal_copy
    store = RunStore.open(cal, "r+")
    record = write_run_recipe(store, EarlyStop.load(cal), TRUSTED_RESIDUAL + 0.1)
    assert record["trusted"] is False and record["held_out_residual"] == pytest.approx(
        TRUSTED_RESIDUAL + 0.1)
    store.update_attrs(summary={**store.attrs["summary"], "early_stop": record})
    assert main(["runs", "verify", str(cal)]) == 0
    assert EarlyStop.load(cal).trusted is False
    caplog.clear()
    plain = tmp_path / "plain.json"
    assert main(["recon", "--psf", str(cal), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--out", str(tmp_path / "plain.png"),
                 "--metrics-json", str(plain)]) == 0
    [line] = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert "not trusted" in line and f"--early-stop {cal}" in line
    assert json.loads(plain.read_text())["calibration"] is None
    forced = tmp_path / "forced.json"
    assert main(["recon", "--psf", str(cal), "--depth", "20", "--raw", str(tmp / "held.npy"),
                 "--dark", "none", "--early-stop", str(cal),
                 "--out", str(tmp_path / "forced.png"), "--metrics-json", str(forced)]) == 0
    assert json.loads(forced.read_text())["calibration"]["iterations"] > 0


def test_a_calibration_that_explains_nothing_records_an_untrusted_recipe(tmp_path, caplog):
    """Swapped names (each scene paired with another's measurement): the calibration
    completes, warns, and its recipe is recorded as not trusted."""

    rng = np.random.default_rng(1)
    (tmp_path / "s").mkdir()
    (tmp_path / "m").mkdir()
    for i in range(4):
        np.save(tmp_path / "s" / f"p{i}.npy", rng.random((24, 32)).astype(np.float32))
        np.save(tmp_path / "m" / f"p{i}.npy", rng.random((24, 32)).astype(np.float32))
    run = tmp_path / "bad.zarr"
    assert main(["calibrate", "psf-from-scenes", "--scenes", str(tmp_path / "s"),
                 "--measurements", str(tmp_path / "m"), "--z-mm", "20",
                 "--out", str(run)]) == 0
    summary = RunStore.open(run).attrs["summary"]
    assert summary["held_out_mean"] > TRUSTED_RESIDUAL
    assert summary["early_stop"]["trusted"] is False
    assert any("not trusted" in r.getMessage() for r in caplog.records)
    assert EarlyStop.load(run).trusted is False
