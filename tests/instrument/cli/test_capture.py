"""`diffuserlab capture live` on the real-time virtual bench: status lines with the
counters, a preview PNG that shows the flowing beads, and one-line refusals."""

from __future__ import annotations

import numpy as np
import pytest

from instrument.cli import main
from instrument.devices.video_scenes import BeadFlowScene
from instrument.devices.virtual_bench import VirtualBench
from recon.io import load_image


@pytest.fixture(scope="module")
def psf_path(tmp_path_factory):
    """The on-axis PSF at the bead scene's depth as the camera would record it (with
    the camera's dark offset), as a plain image."""
    d = tmp_path_factory.mktemp("capture")
    with VirtualBench(seed=0) as vb:
        h = vb.psf((0.0, 0.0, BeadFlowScene().z_mm))
        offset = vb.camera.dark_offset_dn
    np.save(d / "psf.npy", (h / h.max() * 4000.0 + offset).astype(np.float32))
    return d / "psf.npy"


@pytest.mark.parametrize("method", ["wiener", "admm:3"])
def test_capture_live_reports_counters_and_writes_a_preview_of_the_beads(
        psf_path, tmp_path, capsys, monkeypatch, method):
    """Stopped as an operator's Ctrl-C once 30 frames came and 10 were reconstructed
    (an event, whatever the machine's load; --seconds is only the hang guard)."""
    import instrument.cli.capture as capture

    status_line, asked = capture._status, []

    def status_then_stop(t_s, ring, live):
        line = status_line(t_s, ring, live)
        if not asked and ring.counters()["acquired"] >= 30 \
                and live.stats()["reconstructed"] >= 10:
            asked.append(line)
            raise KeyboardInterrupt  # where the loop takes an operator's Ctrl-C
        return line

    monkeypatch.setattr(capture, "_status", status_then_stop)
    png = tmp_path / "live.png"
    assert main(["capture", "live", "--simulate", "--psf", str(psf_path), "--method", method,
                 "--seconds", "300", "--preview-png", str(png), "--threads", "1"]) == 0
    assert asked, "the live reconstruction did not reach 10 results in 300 s"
    out = capsys.readouterr().out.splitlines()
    assert "stopped (Ctrl-C)" in out
    status = [line for line in out if "camera: " in line and "acquired" in line]
    assert status and "errors 0" in status[-1]
    acquired = int(status[-1].split("acquired ")[1].split(",")[0])
    reconstructed = int(status[-1].split("reconstructed ")[1].split(",")[0])
    skipped = int(status[-1].split("skipped ")[1].split(",")[0])
    assert acquired >= 30 and reconstructed >= 10
    fps = float(status[-1].split("camera: ")[1].split(" fps")[0])
    assert fps > 0  # the camera's measured rate is shown (its value: benchmark live)
    assert reconstructed + skipped <= acquired
    image = load_image(png).astype(np.float64)
    # a handful of beads on a dark field: a tiny fraction of the pixels holds most of
    # the energy (a failed reconstruction spreads it over streaks or is all zero)
    energy = np.sort(image.ravel() ** 2)[::-1]
    assert energy.sum() > 0
    # (measured: 0.26-0.37 Wiener, 0.97 ADMM; 0.11 for the streaks of a wrong dark level)
    assert energy[: energy.size // 200].sum() > 0.2 * energy.sum()


@pytest.mark.parametrize("argv, words", [
    (["--method", "admm:0"], "--method 'admm:0'"),
    (["--seconds", "0"], "--seconds 0"),
    (["--dark", "nope.zarr"], "--dark nope.zarr"),
    (["--threads", "7"], "threads=7"),
])
def test_capture_live_refuses_bad_options_in_one_line(psf_path, capsys, argv, words):
    assert main(["capture", "live", "--simulate", "--psf", str(psf_path), "--seconds", "1",
                 *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err and words in err


def test_capture_live_refuses_a_psf_of_another_shape(tmp_path, capsys):
    np.save(tmp_path / "small.npy", np.ones((32, 32), np.float32))
    assert main(["capture", "live", "--simulate", "--psf", str(tmp_path / "small.npy"),
                 "--seconds", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is 32x32 but the camera delivers 256x320" in err and "\n" not in err


@pytest.mark.parametrize("command", [["live", "--seconds", "1"],
                                     ["video", "--frames", "4", "--live-recon", "wiener"]])
def test_a_dark_frame_of_another_shape_is_refused_before_the_bench_opens(
        psf_path, tmp_path, capsys, monkeypatch, command):
    """Before: 'internal error (a bug): ValueError: operands could not be broadcast'
    after the bench had opened and streamed (capture live after 17 s)."""
    import instrument.cli.capture as capture

    def no_bench(*_args, **_kw):
        raise AssertionError("the bench was opened before the dark frame was checked")

    monkeypatch.setattr(capture, "_open", no_bench)
    dark = tmp_path / "dark.npy"
    np.save(dark, np.full((32, 40), 100.0, np.float32))
    out = ["--out", str(tmp_path / "v.zarr")] if command[0] == "video" else []
    assert main(["capture", command[0], "--simulate", "--psf", str(psf_path), "--dark",
                 str(dark), *command[1:], *out]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err, err
    assert "dark frame is 32x40" in err and "256x320" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dark.npy"]
