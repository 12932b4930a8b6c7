"""3D automatic weight and planes (recon.auto.volume) on the small bead problem."""

from __future__ import annotations

import numpy as np

import recon
from tests.instrument.cli.test_recon3d import BEADS, DEPTHS, bead_problem


def test_auto_keeps_the_bead_planes_and_finds_the_beads():
    stack, raw = bead_problem()
    rec = recon.reconstruct_volume(stack, DEPTHS, raw, iterations=60, dark="none")
    auto = rec.info["auto"]
    bead_planes = sorted({z for z, _, _ in BEADS})
    assert set(bead_planes) <= set(auto["planes_kept"])
    assert auto["weight"] in [c["weight"] for c in auto["candidates"]]
    assert "cross-validation" in auto["reason"]
    dropped = sorted(set(range(len(DEPTHS))) - set(auto["planes_kept"]))
    assert np.all(rec.volume[dropped] == 0)
    z, i, j = np.unravel_index(np.argmax(rec.volume), rec.volume.shape)
    assert (int(z), int(i), int(j)) in BEADS
    assert rec.metrics()["auto"]["planes_kept"] == auto["planes_kept"]


def test_planes_without_signal_are_dropped():
    stack, raw = bead_problem()
    # the measurement of the beads of the first plane alone: the others hold nothing
    from recon.volume import VolumeConvolutionOperator, normalize_psf_stack

    h, _ = normalize_psf_stack(stack)
    op = VolumeConvolutionOperator(h)
    x = np.zeros(op.shape_in, np.float32)
    z0 = BEADS[0][0]
    for z, i, j in BEADS:
        if z == z0:
            x[(z, *(s.start + k for s, k in zip(op.crop, (i, j), strict=True)))] = 1.0
    b = op.forward(x) + np.random.default_rng(0).normal(0, 1e-3, op.shape_out)
    rec = recon.reconstruct_volume(stack, DEPTHS, b.astype(np.float32), iterations=60,
                                   dark="none")
    kept = rec.info["auto"]["planes_kept"]
    assert z0 in kept and len(kept) < len(DEPTHS), kept
