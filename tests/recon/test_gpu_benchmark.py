"""``diffuserlab benchmark gpu`` on small cases: every backend present gets a row with
its figures, absent devices are listed as unmeasured with the reason."""

from __future__ import annotations

import pytest

from instrument.benchmarks.gpu import CASES, Case, _measure, format_table, run_gpu_benchmark
from recon.backend import torch_cpu

SMALL = (Case("2D ADMM 32x40", "admm2d", (32, 40)), Case("3D ADMM 16x20x3", "admm3d",
                                                        (16, 20, 3)),
         Case("live ADMM x5 32x40", "live", (32, 40)))


def test_the_issue_cases_are_the_default():
    assert [c.name for c in CASES] == [
        "2D ADMM 300x400", "2D ADMM 1200x1600", "3D ADMM 256x256x32", "3D ADMM 512x512x128",
        "hologram 960x540 16x", "live ADMM x5 1200x1600"]


def test_rows_for_every_backend_with_ratios_and_speedups():
    lines = []
    result = run_gpu_benchmark(iterations=3, cases=SMALL, log=lines.append)
    rows = result["rows"]
    assert len(lines) == len(rows) and len(rows) % len(SMALL) == 0
    for case in SMALL:
        mine = [r for r in rows if r["case"] == case.name]
        cpu = mine[0]
        assert cpu["backend"] == "cpu (numpy)" and cpu["speedup_vs_cpu"] == 1.0
        for r in mine:
            if r["seconds_per_iteration"] is None:
                assert r["note"].startswith(("unmeasured: ", "not run: "))
                continue
            assert r["seconds_per_iteration"] > 0 and r["fft_floor_seconds"] > 0
            per_iteration = r["seconds_per_iteration"] / (5 if "live" in case.name else 1)
            assert r["ratio_to_fft_floor"] == pytest.approx(
                per_iteration / r["fft_floor_seconds"])
            assert r["speedup_vs_cpu"] == pytest.approx(
                cpu["seconds_per_iteration"] / r["seconds_per_iteration"])
    torch_rows = [r for r in rows if r["backend"] == "cpu (torch, generic path)"]
    assert len(torch_rows) == len(SMALL)  # listed with or without PyTorch
    measured = [r["seconds_per_iteration"] is not None for r in torch_rows]
    assert measured == [torch_cpu() is not None] * len(SMALL), torch_rows
    assert "FFT floor" in format_table(result)


def test_the_hologram_runs_the_optimiser_on_every_backend(monkeypatch):
    import instrument.benchmarks.hologram as holo_bench

    ran = []
    real = holo_bench.optimize_hologram

    def spy(*args, **kwargs):
        res = real(*args, **kwargs)
        ran.append((res.params["device"], res.iterations))
        return res

    monkeypatch.setattr(holo_bench, "optimize_hologram", spy)
    case = Case("hologram 32x24 4x", "holo", (24, 32, 2))
    result = run_gpu_benchmark(iterations=6, cases=(case,), log=lambda line: None)
    rows = result["rows"]
    cpu = rows[0]
    assert cpu["backend"] == "cpu (numpy)" and cpu["speedup_vs_cpu"] == 1.0
    measured = [r for r in rows if r["seconds_per_iteration"] is not None]
    for r in measured:
        assert r["fft_floor_seconds"] > 0 and not r["note"]
        assert r["ratio_to_fft_floor"] == pytest.approx(
            r["seconds_per_iteration"] / r["fft_floor_seconds"])
        assert r["speedup_vs_cpu"] == pytest.approx(
            cpu["seconds_per_iteration"] / r["seconds_per_iteration"])
    # each measured backend ran the real optimiser (warm-up, then 3 timed iterations)
    timed = [device for device, iterations in ran if iterations == 3]
    assert len(timed) == len(measured)
    if torch_cpu() is not None:
        assert timed[:2] == ["cpu (numpy)", "cpu (torch)"]
        assert rows[1]["backend"] == "cpu (torch, generic path)" and rows[1] in measured
    assert all(r["note"].startswith("unmeasured: ") for r in rows if r not in measured)


def test_the_live_case_runs_the_warm_started_live_reconstructor_on_the_backend(monkeypatch):
    backend = torch_cpu()
    if backend is None:
        pytest.skip("PyTorch is not installed")
    import recon.xp_live as xp_live

    calls = []
    solve = xp_live.DeviceLive.admm

    def spy(self, b, state, **kwargs):
        calls.append((self.backend.label, type(state.x).__module__))
        return solve(self, b, state, **kwargs)

    monkeypatch.setattr(xp_live.DeviceLive, "admm", spy)
    out = _measure(Case("live ADMM x5 32x40", "live", (32, 40)), backend, 6)
    assert out["iterations_per_unit"] == 5 and out["seconds_per_iteration"] > 0
    assert calls == [(backend.label, "torch")] * 4  # one cold frame, three warm ones
