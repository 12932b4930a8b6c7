"""The acquisition benchmarks run end to end on small sizes and report what they claim
(no speed asserted: figures are for the benchmark output)."""

from __future__ import annotations

from instrument.benchmarks.acquisition import (
    batch_table,
    recording_table,
    run_batch_benchmark,
    run_recording_benchmark,
)


def test_recording_benchmark_reports_every_compressor(tmp_path):
    r = run_recording_benchmark(seconds=2.0, fps=10.0, sensor_shape=(256, 320),
                                compressors=("none", "blosc-lz4"), shard_frames=4,
                                directory=tmp_path)
    assert set(r["runs"]) == {"none", "blosc-lz4"}
    for run in r["runs"].values():
        assert run["recorded"] + run["lost"] >= run["requested"] - run["lost"]
        assert run["recorded"] == run["requested"] == 20
        # 4 files per 4-frame shard (frames, coords, crc32, done) plus the metadata: at
        # most half the 4 files per frame of an unsharded run
        assert 1000 <= run["files_per_1000_frames"] <= 2000
    assert r["runs"]["none"]["compression_ratio"] < r["runs"]["blosc-lz4"]["compression_ratio"]
    assert "blosc-lz4" in recording_table(r)


def test_batch_benchmark_equals_the_loop_and_draws_its_chart(tmp_path):
    r = run_batch_benchmark(frames=3, iterations=3, sensor_shape=(256, 320), workers=(1,),
                            chart=tmp_path / "batch.png")
    # the loop's frames to float32 rounding (bit for bit unless a worker sums in
    # another order)
    assert r["batch"][1]["max_rel_diff_to_loop"] < 1e-5 and r["loop_fps"] > 0
    assert (tmp_path / "batch.png").stat().st_size > 1000
    assert "steady / loop" in batch_table(r)
