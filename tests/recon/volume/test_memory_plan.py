"""Which plan of a 3D solve fits ``memory_limit_bytes`` (recon.volume.memory_plan).

A limit is the most the process's resident set may reach: every plan's estimate is
the process's resident set now plus the plan's arrays. A limit below every plan's
estimate is refused before any solver work, in one line that names the smallest
plan's estimate, the smallest limit that would do and what lowers it (a fixed weight,
more binning, fewer planes); a limit between two plans runs the first plan within it
(the in-memory solver, streamed 3D FISTA a chunk of planes at a time, or one plane at
a time), and that plan's estimate is within the limit. The process's resident set is
fixed here (:data:`BASELINE`) so that the limits are exact; that the measured peak
stays within the limit is ``diffuserlab benchmark memory-limit``'s check.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import recon
import recon.volume.api as volume_api
import recon.volume.memory_plan as memory_plan_module
from recon.errors import ReconInputError
from recon.volume.memory_plan import PLANS, memory_plan, plan_estimates
from tests.instrument.cli.test_recon3d import DEPTHS, bead_problem

#: The process's resident set the tests give the plans, bytes.
BASELINE = 200_000_000


def fix_baseline(monkeypatch) -> None:
    """Make :func:`recon.reconstruct`'s plans start from :data:`BASELINE`."""
    monkeypatch.setattr(volume_api, "process_baseline_bytes", lambda: BASELINE)


def bead_plans(auto, method: str = "admm") -> list[dict]:
    """:func:`plan_estimates` of :func:`bead_problem` as ``reconstruct`` plans it."""
    stack, _ = bead_problem()
    return plan_estimates(method, auto, stack.shape[1:], stack.shape[0],
                          baseline_bytes=BASELINE,
                          stack_bytes=stack.astype(np.float32).nbytes)


def bead_limit(plan: str, auto, method: str = "admm") -> int:
    """The limit that is exactly the estimate of ``plan`` for the bead problem."""
    return next(p["estimate_bytes"] for p in bead_plans(auto, method) if p["plan"] == plan)


class Spy:
    """Records every call of the solver's entry points (none may run on a refusal)."""

    def __init__(self, monkeypatch):
        self.calls = []
        for name in ("solve_streamed", "VolumeConvolutionOperator", "auto_volume"):
            monkeypatch.setattr(volume_api, name, self._record(name))
        monkeypatch.setitem(volume_api.SOLVERS, "admm", self._record("admm3d"))
        monkeypatch.setitem(volume_api.SOLVERS, "fista", self._record("fista3d"))

    def _record(self, name):
        def call(*args, **kwargs):
            self.calls.append(name)
            raise AssertionError(f"{name} ran")
        return call


def test_the_plans_shrink_in_the_order_they_are_preferred():
    for shape, n_z in (((48, 48), 5), ((1024, 1024), 32)):
        for auto in (None, "tv"):
            plans = plan_estimates("admm", auto, shape, n_z, baseline_bytes=BASELINE,
                                   stack_bytes=4 * n_z * shape[0] * shape[1])
            assert [p["plan"] for p in plans] == list(PLANS)
            sizes = [p["estimate_bytes"] for p in plans]
            assert sizes == sorted(sizes, reverse=True) and len(set(sizes)) == 3
            assert [p["chunk_bytes"] is None for p in plans] == [True, False, False]
    # 4096 x 4096 padded: a chunk is one plane already, so there is no third plan
    assert len(plan_estimates("fista", None, (2048, 2048), 8)) == 2


def test_a_limit_below_every_plan_is_refused_before_any_work(monkeypatch):
    fix_baseline(monkeypatch)
    spy = Spy(monkeypatch)
    stack, raw = bead_problem()
    plans = bead_plans("tv")
    smallest = min(p["estimate_bytes"] for p in plans)
    assert smallest == plans[-1]["estimate_bytes"]  # one plane at a time
    lines = []
    with pytest.raises(ReconInputError) as err:
        recon.reconstruct_volume(stack, DEPTHS, raw, iterations=5,
                                 memory_limit_bytes=smallest - 1, announce=lines.append)
    msg = str(err.value)
    assert spy.calls == [] and lines == []
    assert "\n" not in msg and "is below every plan of this 3D solve" in msg
    assert f"is estimated at {smallest / 1e9:.2f} GB" in msg
    assert "streamed 3D FISTA one plane at a time" in msg
    assert f"give --memory-limit {math.ceil(smallest / 1e7) / 100:.2f}GB or more" in msg
    fixed = min(p["estimate_bytes"] for p in bead_plans(None))
    assert f"a fixed --tv weight ({fixed / 1e9:.2f} GB)" in msg
    assert "--bin 2 (" in msg


def test_the_smallest_limit_named_runs(monkeypatch):
    """The limit the refusal names (the smallest estimate rounded up to 10 MB) runs a
    plan within it."""
    fix_baseline(monkeypatch)
    stack, raw = bead_problem()
    with pytest.raises(ReconInputError) as err:
        recon.reconstruct_volume(stack, DEPTHS, raw, method="fista", tv=1e-4,
                                 iterations=5, memory_limit_bytes=1_000_000)
    named = str(err.value).split("give --memory-limit ")[1].split("GB")[0]
    limit = int(round(float(named) * 1e9))
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method="fista", tv=1e-4, iterations=5,
                                   memory_limit_bytes=limit)
    plan = rec.info.extra["memory_plan"]
    assert plan["estimate_bytes"] <= limit
    assert limit - 10_000_000 < min(p["estimate_bytes"] for p in plan["plans"]) <= limit


@pytest.mark.parametrize("which", [0, 1, 2])
def test_a_limit_between_plans_runs_the_first_that_fits(which, monkeypatch):
    fix_baseline(monkeypatch)
    chunks = []

    class CountingSlab(memory_plan_module.VolumeSlab):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            chunks.append(len(self._chunks))

    monkeypatch.setattr(memory_plan_module, "VolumeSlab", CountingSlab)
    stack, raw = bead_problem()
    plans = bead_plans(None, "fista")
    limit = plans[which]["estimate_bytes"]  # within it; the plans before are not
    assert all(p["estimate_bytes"] > limit for p in plans[:which])
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, method="fista", tv=1e-4, iterations=5,
                                   memory_limit_bytes=limit)
    plan = rec.info.extra["memory_plan"]
    assert plan["plan"] == PLANS[which] and plan["estimate_bytes"] <= limit
    if which == 0:
        assert not plan["streamed"] and chunks == [] and rec.info.method == "fista"
        assert "within the" in plan["reason"]
    else:
        assert rec.info.extra["memory"]["estimate_bytes"] == plan["estimate_bytes"]
        # the slab transforms every plane in one chunk, or one plane at a time
        assert chunks == [1 if which == 1 else len(DEPTHS)]


def test_every_limit_runs_a_plan_within_it_or_is_refused():
    plans = plan_estimates("admm", "tv", (1024, 1024), 32, baseline_bytes=600_000_000,
                           stack_bytes=134_217_728)
    edges = sorted(p["estimate_bytes"] for p in plans)
    for limit in [edges[0] - 1, *edges, *(e + 1 for e in edges), 10 * edges[-1]]:
        try:
            plan = memory_plan("admm", "tv", (1024, 1024), 32, limit, bin_factor=1,
                               baseline_bytes=600_000_000, stack_bytes=134_217_728)
        except ReconInputError:
            assert limit < edges[0]
            continue
        assert plan["estimate_bytes"] <= limit and plan["fits"]
        # the first plan within the limit: every plan preferred to it is over it
        order = [p["plan"] for p in plans]
        assert all(p["estimate_bytes"] > limit for p in plans[:order.index(plan["plan"])])


def test_the_refusal_names_the_most_planes_that_fit():
    """The issue's case: 32 planes of 1024 x 1024, automatic weight, 1.5 GB."""
    kw = {"baseline_bytes": 600_000_000, "stack_bytes": 134_217_728}
    with pytest.raises(ReconInputError) as err:
        memory_plan("admm", "tv", (1024, 1024), 32, 1_500_000_000, bin_factor=1, **kw)
    msg = str(err.value)
    most = int(msg.split("at most ")[1].split(" of the 32 planes")[0])

    def smallest(n_z):
        return min(p["estimate_bytes"] for p in plan_estimates(
            "admm", "tv", (1024, 1024), n_z, baseline_bytes=kw["baseline_bytes"],
            stack_bytes=kw["stack_bytes"] * n_z // 32))

    assert smallest(most) <= 1_500_000_000 < smallest(most + 1)
    assert msg.startswith("--memory-limit 1.50 GB is below every plan")


def test_what_is_available_chooses_but_never_refuses(monkeypatch):
    monkeypatch.setattr(memory_plan_module, "available_memory_bytes", lambda: 1_000)
    plan = memory_plan("admm", True, (64, 64), 5, None, bin_factor=1, baseline_bytes=BASELINE)
    assert plan["limit_source"] == "available" and not plan["fits"]
    assert plan["plan"] == PLANS[2] and "no plan fits what is available" in plan["reason"]
    monkeypatch.setattr(memory_plan_module, "available_memory_bytes", lambda: 10**12)
    plan = memory_plan("fista", False, (64, 64), 5, None, bin_factor=1, baseline_bytes=BASELINE)
    assert plan["plan"] == PLANS[0] and plan["fits"] and "less than the" in plan["reason"]


def test_sharded_slabs_are_never_refused_here():
    plan = memory_plan("admm", "tv", (1024, 1024), 32, 1_000_000, bin_factor=1,
                       baseline_bytes=BASELINE, sharded=True)
    assert plan["streamed"] and "sharded over the dask workers" in plan["reason"]


def test_a_prior_other_than_tv_has_only_the_in_memory_plan():
    with pytest.raises(ReconInputError) as err:
        memory_plan("admm", None, (64, 64), 5, BASELINE + 1, bin_factor=1, baseline_bytes=BASELINE,
                    streamable=False)
    assert "the smallest, the in-memory 3D ADMM" in str(err.value)


def test_a_bad_limit_is_refused():
    with pytest.raises(ReconInputError, match="--memory-limit 16GB"):
        memory_plan("fista", False, (64, 64), 5, 0, bin_factor=1)
