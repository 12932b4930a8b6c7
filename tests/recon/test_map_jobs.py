"""Independent jobs on one FFT thread each (recon.fft.map_jobs), and the calibration's
held-out PSFs and recipe solves run through it with the results of the jobs run one
by one. Concurrency is shown by a barrier two jobs must pass together (no clock)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import recon.fft as rfft
from recon.analysis.early_stop import fit_early_stop
from recon.analysis.psf_from_scenes import leave_one_out
from recon.fft import fft_workers, limited_threads, map_jobs

from .test_psf_from_scenes import NAMES, SENSOR, caustic_psf, measure

HANG_GUARD_S = 60.0  # a barrier not passed by then: the jobs ran one by one


@pytest.fixture
def two_workers(monkeypatch):
    """The caller's FFT workers are 2 on any machine."""
    monkeypatch.setattr(rfft, "WORKERS", 2)


def test_jobs_run_at_once_each_on_one_fft_thread_results_in_order(two_workers):
    barrier = threading.Barrier(2, timeout=HANG_GUARD_S)
    caller = threading.get_ident()

    def job(x):
        barrier.wait()  # both jobs in flight at once, or BrokenBarrierError
        return x * 10, fft_workers(), threading.get_ident()

    ended = []
    out = map_jobs(job, [1, 2], on_done=lambda i, r: ended.append((i, threading.get_ident())))
    assert [r[0] for r in out] == [10, 20]
    assert [r[1] for r in out] == [1, 1]  # each job's FFTs on one thread
    assert caller not in {r[2] for r in out} and out[0][2] != out[1][2]
    assert sorted(i for i, _ in ended) == [0, 1]
    assert {t for _, t in ended} == {caller}  # progress in the caller's thread
    assert fft_workers() == 2  # the caller's own count is left as it was


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_blas_runs_on_one_thread_while_the_jobs_run_and_is_restored(two_workers):
    """OpenBLAS's idle threads spin: in the calibration they doubled the CPU time of
    the PSF estimates; its thread count is process-wide, so it is 1 while jobs run."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert before and set(before) == {2}
        inside = map_jobs(lambda _: _blas_threads(), [0, 1])
        assert inside == [[1] * len(before)] * 2
        assert _blas_threads() == before


def test_each_job_is_reported_as_it_ends_not_with_the_last(two_workers):
    release = threading.Event()  # set by the report of job 0, awaited by job 1

    def job(x):
        return release.wait(HANG_GUARD_S) if x == 1 else True

    out = map_jobs(job, [0, 1], on_done=lambda i, _: release.set() if i == 0 else None)
    assert out == [True, True]


def test_a_thread_capped_at_one_worker_runs_its_jobs_itself(two_workers):
    caller = threading.get_ident()
    with limited_threads(1):
        out = map_jobs(lambda x: (x, threading.get_ident()), [1, 2, 3])
    assert out == [(1, caller), (2, caller), (3, caller)]


def test_the_first_error_is_raised_and_jobs_not_started_are_cancelled(two_workers):
    started = []

    def job(x):
        started.append(x)
        if x == 0:
            raise ValueError("job 0 failed")
        return x

    with pytest.raises(ValueError, match="job 0 failed"):
        map_jobs(job, [0] + [1] * 50)
    assert len(started) < 51  # the queue behind the failure was not run


@pytest.fixture(scope="module")
def pairs():
    from recon.scenes import load_scene

    psf = caustic_psf()
    scenes = [load_scene(n, SENSOR) for n in NAMES[:4]]
    return psf, scenes, [measure(psf, x, 0.01, k) for k, x in enumerate(scenes)]


def test_held_out_psfs_and_recipe_errors_equal_those_run_one_by_one(pairs, two_workers,
                                                                     monkeypatch):
    import recon.analysis.early_stop as es
    import recon.analysis.psf_from_scenes as pfs

    psf, scenes, measurements = pairs
    where = []  # (what, thread, FFT workers) of each estimate and solve

    def spy(module, name):
        real = getattr(module, name)

        def wrapped(*args, **kwargs):
            where.append((name, threading.get_ident(), fft_workers()))
            return real(*args, **kwargs)
        monkeypatch.setattr(module, name, wrapped)

    spy(pfs, "estimate_psf_from_scenes")
    spy(es, "solve_checkpoints")
    runs = []
    for capped in (True, False):
        order = []
        if capped:
            with limited_threads(1):  # map_jobs runs them in turn
                loo = leave_one_out(scenes, measurements, iterations=30, on_estimate=order.append)
                fit = fit_early_stop(scenes, measurements, loo.psfs, psf, candidates=(5, 20),
                                     thresholds=(0.0, 0.05), weights=(0.0, 0.1))
        else:
            solves = []
            loo = leave_one_out(scenes, measurements, iterations=30, on_estimate=order.append)
            fit = fit_early_stop(scenes, measurements, loo.psfs, psf, candidates=(5, 20),
                                 thresholds=(0.0, 0.05), weights=(0.0, 0.1),
                                 on_solve=lambda d, t, seen=solves: seen.append((d, t)))
            assert solves == [(d, 8) for d in range(1, 9)]  # counted in the order they end
        assert sorted(order) == [0, 1, 2, 3]
        runs.append((loo, fit))
        threads = {t for _, t, _ in where}
        assert [n for _, _, n in where] == [1] * 12  # 4 estimates, 8 solves
        # capped: all in this thread; else all on the pools' threads (each pool's
        # threads end with it, so their idents may be reused: not counted)
        assert (threads == {threading.get_ident()}) if capped else (
            threading.get_ident() not in threads)
        where.clear()
    (a, fa), (b, fb) = runs
    assert np.array_equal(a.residuals, b.residuals)
    assert all(np.array_equal(p, q) for p, q in zip(a.psfs, b.psfs, strict=True))
    np.testing.assert_allclose(fa.errors, fb.errors, rtol=1e-6)
    assert ((fa.iterations, fa.psf_threshold, fa.denoise_weight, fa.field_gain_db)
            == pytest.approx((fb.iterations, fb.psf_threshold, fb.denoise_weight,
                              fb.field_gain_db), rel=1e-6))


def test_the_recipe_estimates_the_psf_from_every_pair_beside_the_held_out_ones(pairs,
                                                                              two_workers):
    from recon.analysis.early_stop import fit_recipe
    from recon.analysis.psf_from_scenes import estimate_psf_from_scenes
    from recon.analysis.sensor_response import remove_sensor_response
    from recon.early_stop import psf_identity

    _, scenes, measurements = pairs
    options = dict(iterations=30, candidates=(5, 20), weights=(0.0, 0.1))
    lines = []
    b = fit_recipe(scenes, measurements, on_psf=lambda e: lines.append(("psf", e)),
                   on_estimate=lambda k: lines.append(("without", k)), **options)
    # the PSF from every pair, estimated with the sensor response the fit found
    given = estimate_psf_from_scenes(
        scenes, [remove_sensor_response(m, b.sensor_response) for m in measurements],
        iterations=30)
    a = fit_recipe(scenes, measurements, given.psf, **options)
    assert a.estimate is None and a.sensor_response is None
    assert np.array_equal(b.estimate.psf, given.psf)
    assert b.estimate.iterations_run == given.iterations_run
    assert [w for w, _ in lines].count("psf") == 1 and lines[[w for w, _ in lines].index(
        "psf")][1] is b.estimate
    assert sorted(k for w, k in lines if w == "without") == [0, 1, 2, 3]
    assert all(np.array_equal(p, q) for p, q in zip(a.held_out.psfs, b.held_out.psfs,
                                                    strict=True))
    np.testing.assert_allclose(a.fit.errors, b.fit.errors, rtol=1e-6)
    assert a.fit.psf_sha256 == b.fit.psf_sha256 == psf_identity(given.psf)
