"""Video recording on the bench (instrument.acquisition.video) and ``diffuserlab capture video``:
every frame the camera delivers is stored in order with no index gap, a recording
stopped early keeps what it has (and no empty slots), a forced loss is exit 1 with
the indices, and bad options are one line."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from instrument.acquisition.video import record_video, video_frame_count
from instrument.cli import main
from instrument.devices.video_scenes import BeadFlowScene
from instrument.devices.virtual_bench import VirtualBench
from instrument.runs.runstore import RunStore, RunStoreError


@pytest.fixture
def bench():
    vb = VirtualBench(seed=0, realtime=True).open()
    vb.led_array.all_off()
    vb.set_scene(BeadFlowScene(seed=0, time_step_s=0.5))
    vb.prerender()
    yield vb
    vb.close()


def test_record_video_stores_every_frame_in_order(bench, tmp_path):
    progress = []
    summary = record_video(bench, tmp_path / "v.zarr", frames=30, fps=20.0, shard_frames=8,
                           on_progress=progress.append, progress_every_s=0.5)
    assert summary["status"] == "complete" and summary["recorded"] == 30
    assert summary["index_gaps"] == [] and summary["lost_by_recorder"] == 0
    assert summary["write_mb_s"] == pytest.approx(
        30 * 256 * 320 * 2 / 1e6 / summary["elapsed_s"])  # every frame's bytes counted
    assert progress and progress[-1]["acquired"] >= progress[0]["acquired"]
    store = RunStore.open(tmp_path / "v.zarr")
    assert store.n_frames == 30 and store.done().all() and store.verify() == []
    assert store.attrs["summary"]["recording"]["recorded"] == 30
    assert store.attrs["camera"]["frame_rate_hz"] == pytest.approx(20.0)
    table = store.coords_table()
    assert np.all(np.diff(table["frame_index"]) == 1)
    # frames arrive on the wall clock at the set rate (device timestamps 1/20 s apart)
    assert np.median(np.diff(table["device_timestamp_s"])) == pytest.approx(0.05, rel=0.05)
    assert np.all(np.diff(table["host_timestamp_s"]) > 0)
    # the scene moves: distant frames differ far beyond the frame-to-frame noise
    a, b, c = (store.frame(i).image.astype(float) for i in (0, 1, 29))
    assert np.abs(c - a).mean() > 1.5 * np.abs(b - a).mean()


class _LiveThatWillNotStop:
    """A live reconstruction whose frame outlasts the stop's wait (a loaded machine)."""

    def __init__(self) -> None:
        self.offered = 0

    def start(self) -> None:
        pass

    def offer(self, frame) -> None:
        self.offered += 1

    def stats(self) -> dict:
        return {"offered": self.offered}

    def stop(self, timeout_s: float = 60.0) -> None:
        from instrument.acquisition.live import LiveReconstructionError

        raise LiveReconstructionError("live reconstruction thread(s) live-recon still "
                                      f"running after {timeout_s:g} s")


def test_a_live_view_that_does_not_stop_still_lets_the_recording_close(bench, tmp_path):
    """A live view stopped beside a recording waits for its frame; when it outlasts the
    wait, the recording is closed all the same (it was left open, its summary unwritten,
    and the error rose as a bug) and the summary says why the live view lingered."""
    live = _LiveThatWillNotStop()
    summary = record_video(bench, tmp_path / "v.zarr", frames=6, fps=20.0, live=live)
    assert summary["status"] == "complete" and summary["recorded"] == 6
    assert "still running" in summary["live_error"] and live.offered == 6
    store = RunStore.open(tmp_path / "v.zarr")
    assert store.done().all() and store.attrs["summary"]["recording"]["recorded"] == 6


def test_stopped_recording_keeps_its_frames_and_no_empty_slot(bench, tmp_path):
    stop = threading.Event()
    seen = []

    def progress(p):
        seen.append(p)
        if p["delivered"] >= 10:
            stop.set()

    summary = record_video(bench, tmp_path / "v.zarr", seconds=10.0, fps=20.0,
                           shard_frames=4, stop=stop, on_progress=progress,
                           progress_every_s=0.0)
    assert summary["status"] == "stopped" and summary["frames_requested"] == 200
    store = RunStore.open(tmp_path / "v.zarr")
    assert store.status == "stopped" and 10 <= store.n_frames < 200
    assert store.n_frames == summary["recorded"] and store.done().all()
    assert store.verify() == []


def test_frame_count_from_frames_or_seconds():
    assert video_frame_count(frames=7, seconds=None, rate_hz=20.0) == 7
    assert video_frame_count(frames=None, seconds=2.0, rate_hz=20.0) == 40
    assert video_frame_count(frames=None, seconds=0.01, rate_hz=20.0) == 1
    for kwargs, words in (({"frames": None, "seconds": None}, "not both"),
                          ({"frames": 3, "seconds": 1.0}, "not both"),
                          ({"frames": 0, "seconds": None}, "--frames 0"),
                          ({"frames": None, "seconds": -1.0}, "--seconds -1")):
        with pytest.raises(RunStoreError, match=words):
            video_frame_count(rate_hz=20.0, **kwargs)


def test_capture_video_cli_records_what_it_claims(tmp_path, capsys):
    out = tmp_path / "v.zarr"
    assert main(["capture", "video", "--simulate", "--frames", "24", "--fps", "20",
                 "--shard-frames", "8", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1] == f"complete: 24 frames in {out} (24 requested)"
    assert "recorded 24" in lines[-2] and "recorder 0" in lines[-2]
    store = RunStore.open(out)
    assert store.n_frames == 24 and store.verify() == []
    assert store.attrs["simulated"]["scene"] == "beads-flow"
    assert np.all(np.diff(store.coords_table()["frame_index"]) == 1)
    # the same --out again is refused, naming it; --overwrite replaces the run
    assert main(["capture", "video", "--simulate", "--frames", "4", "--out", str(out)]) == 2
    assert "v.zarr exists; pass --overwrite" in capsys.readouterr().err
    assert main(["capture", "video", "--simulate", "--frames", "4", "--out", str(out),
                 "--overwrite"]) == 0
    assert RunStore.open(out).n_frames == 4


def test_capture_video_with_a_forced_loss_exits_1_naming_the_frames(tmp_path, capsys,
                                                                     monkeypatch):
    import time

    real = RunStore.write_frames

    def slow(self, start, images, rows):  # a disk far slower than the camera
        time.sleep(0.4)
        real(self, start, images, rows)

    monkeypatch.setattr(RunStore, "write_frames", slow)
    out = tmp_path / "v.zarr"
    assert main(["capture", "video", "--simulate", "--frames", "30", "--fps", "30",
                 "--shard-frames", "2", "--queue-frames", "2", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "frame(s) lost" in err
    store = RunStore.open(out)
    lost = store.attrs["summary"]["recording"]["lost_by_recorder"]
    assert lost > 0 and store.n_frames == 30 - lost and store.verify() == []
    gaps = store.attrs["summary"]["recording"]["index_gaps"]
    missing = {i for a, b in gaps for i in range(a, b + 1)}
    lost_ranges = store.attrs["summary"]["recording"]["lost_indices"]
    assert missing <= {i for a, b in lost_ranges for i in range(a, b + 1)}
    assert str(sorted(missing)[0]) in err


def test_capture_video_with_live_reconstruction(tmp_path, capsys):
    with VirtualBench(seed=0) as vb:
        h = vb.psf((0.0, 0.0, BeadFlowScene().z_mm))
        offset = vb.camera.dark_offset_dn
    np.save(tmp_path / "psf.npy", (h / h.max() * 4000.0 + offset).astype(np.float32))
    png = tmp_path / "live.png"
    assert main(["capture", "video", "--simulate", "--frames", "30", "--fps", "15",
                 "--out", str(tmp_path / "v.zarr"), "--live-recon", "wiener", "--psf",
                 str(tmp_path / "psf.npy"), "--preview-png", str(png),
                 "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "live: " in out and png.is_file()
    assert RunStore.open(tmp_path / "v.zarr").n_frames == 30


@pytest.mark.parametrize("argv, words", [
    (["--frames", "0"], "--frames 0"),
    (["--frames", "3", "--live-recon", "wiener"], "--live-recon needs the PSF"),
    (["--frames", "3", "--psf", "x.npy"], "go with --live-recon"),
    (["--frames", "3", "--shard-frames", "0"], "--shard-frames 0"),
    (["--frames", "3", "--compressor", "gzip"], "unknown frame compressor 'gzip'"),
    (["--seconds", "0"], "--seconds 0"),
])
def test_capture_video_refuses_bad_options_in_one_line(tmp_path, capsys, argv, words):
    out = tmp_path / "v.zarr"
    assert main(["capture", "video", "--simulate", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("diffuserlab: error:") and "\n" not in err and words in err
    assert not out.exists()


def test_camera_lost_mid_recording_keeps_the_frames_and_says_so(bench, tmp_path):
    from drivers.errors import DeviceDisconnectedError

    def progress(p):
        if p["recorded"] >= 8:
            bench.camera.faults.disconnect()

    with pytest.raises(DeviceDisconnectedError):
        record_video(bench, tmp_path / "v.zarr", frames=200, fps=20.0, shard_frames=4,
                     on_progress=progress, progress_every_s=0.0)
    store = RunStore.open(tmp_path / "v.zarr")
    assert store.status == "failed" and "DeviceDisconnectedError" in store.attrs["error"]
    assert store.done().sum() >= 8 and store.verify() == []
    assert store.lock_owner() is None
