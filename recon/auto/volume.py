"""Automatic 3D weight, and which planes show signal (Kuo 2020, Ch. 4; the 2D machinery
of :mod:`recon.auto.weight`).

The weight: the 2D machinery itself (:func:`recon.auto.weight.admm_auto`) on the
volume model through :class:`recon.volume.VolumeAdmmPlan` -- a warm-started 3D ADMM
path from :data:`VOLUME_RULES` ``start`` down to ``end``, 10 % of the sensor pixels
held out in 8 x 8 blocks, the largest weight within one standard error of the
held-out minimum but at most twice its weight, each weight solved until its held-out
error settles (:data:`VOLUME_RULES`), then the chosen weight run on from its own
solve's state on the fit pixels (:mod:`recon.auto.path`). 3D FISTA takes the
weight the path chose and solves on the same fit pixels.

The planes: every plane is kept. Dimness is not emptiness -- a far plane of a
fluorescent sample collects less light and may hold a dim object -- and nothing is
decided relative to the brightest plane. Each plane is tested against the held-out
pixels and the frame's noise model (:func:`recon.auto.planes.plane_tests`), and the
record lists each plane's energy, its evidence and those without evidence. With
``empty_planes="drop"`` those that show no signal, alone or together, are set to
zero, and the record says which, why, and what the held-out error and the data
residual did; nothing is re-solved, so no plane's light moves to another.
"""

from __future__ import annotations

import numpy as np

from ..backend import to_device, to_numpy
from ..errors import ReconInputError
from .holdout import HOLDOUT, holdout_split
from .noise import NoiseModel
from .planes import plane_tests, planes_record
from .weight import PathRule, PathTuning, admm_auto

__all__ = ["EMPTY_PLANES", "VOLUME_RULES", "auto_volume", "weighted_variance"]

#: The 3D path and rule per regulariser (normalised stack, ``sum_z (sum h_z)^2 = 1``,
#: measurement / max): the 2D machinery and rule (each weight solved until its
#: held-out error settles, steps of 2.8x, at most 3.5x a fixed run's iterations; the
#: held-out minimum) over TV 1e-3 .. 1e-6. The span was measured with the former
#: path (fixed-length stages; ``benchmarks.volume_auto.rule_study``: 18
#: cases, beads and textured discs with far planes 3x, 10x and 30x dimmer,
#: 300-30000 e-, 6 planes at bin 8): a path over 1e-4 .. 1e-7 did worse, and the
#: beads' PSNR no longer changes below 1e-6. On the external 3D sample
#: (``recon.volume.sample``, bin 2) the held-out error is flat within one standard
#: error from 1.4e-4 down to 1e-6; the bound to twice the minimum's weight keeps the
#: choice off the flat blocks of the largest. l1: the same over the span of the 3D
#: accuracy benchmark's l1 grid (1e-5 .. 1e-3), one decade wider on each side; not
#: measured. Held-out blocks of 8 x 8 pixels, as measured (the 2D path's 32 x 32,
#: :data:`recon.auto.holdout.BLOCK`, were measured on 2D scenes only).
VOLUME_RULES = {"tv": PathRule(start=1e-3, end=1e-6, block=8),
                "l1": PathRule(start=1e-2, end=1e-6, block=8)}
#: What :func:`auto_volume` may do with planes that hold no signal.
EMPTY_PLANES = ("keep", "drop")


def weighted_variance(weights: np.ndarray, noise: NoiseModel, b: np.ndarray) -> np.ndarray:
    """Noise variance of each weighted sensor pixel, ``w^2 var(b)``.

    Parameters
    ----------
    weights : ndarray, float32, sensor shape
        Sensor weights ``w`` (Eq. 3.10).
    noise : NoiseModel
        The frame's noise model in the units of ``b``.
    b : ndarray, float32, sensor shape
        Scaled measurement.

    Returns
    -------
    ndarray, float64, sensor shape
        Its sum is the ``noise_energy`` of :func:`recon.auto.weight.admm_auto`.
    """
    return np.square(weights, dtype=np.float64) * noise.variance(b)


def auto_volume(method: str, op, b: np.ndarray, *, noise: NoiseModel, iterations: int,
                plan_of, fista, regulariser: str = "tv", other: float = 0.0,
                empty_planes: str = "keep", seed: int = 0, backend=None,
                device_plan=None) -> tuple[object, dict]:
    """Choose the 3D weight, solve, and test every plane for signal.

    Parameters
    ----------
    method : {"admm", "fista"}
        The 3D solver of the final solve (the path is 3D ADMM either way).
    op : VolumeConvolutionOperator
        Scaled forward model (normalised stack).
    b : ndarray, float32, ``op.shape_out``
        Scaled measurement.
    noise : NoiseModel
        The frame's noise model in the units of ``b`` (:meth:`NoiseModel.scaled`).
    iterations : int
        Iterations of the fixed-weight run this replaces (each path weight at most
        this many, the path with its run-on at most 3.5x as many,
        :func:`recon.auto.weight.path_budget`).
    plan_of : callable
        The volume's ADMM plan, :meth:`recon.volume.VolumeAdmmPlan.of` (passed in:
        ``recon.volume`` imports this package, not the other way round).
    fista : callable
        3D FISTA, :func:`recon.volume.fista3d` (the final solve of ``method="fista"``).
    regulariser : {"tv", "l1"}
        The weight to choose; ``other`` is the fixed value of the other one.
    empty_planes : {"keep", "drop"}
        Keep every plane (default), or set those that show no signal to zero
        (:func:`recon.auto.planes.planes_record`); reported either way.
    seed : int
        Seed of the held-out pixels.
    backend : Backend, optional
        Where the path and the final solve run: None or NumPy the host; another
        backend its device (the measurement moved there, the iterates kept there
        between the path's solves, ``x`` brought back for the plane tests, which run
        on the host).
    device_plan : type, optional
        With a device ``backend``: the generic plan class with
        ``maker(like, plan_of)`` (``recon.volume.xp_admm3d.XpVolumeAdmmPlan``).

    Returns
    -------
    result : SolveResult
        On all planes (``x`` of ``op.shape_in``; dropped planes are zero).
    record : dict
        JSON-ready: ``regulariser``, ``weight``, ``weight_choice`` (the
        :class:`recon.auto.weight.AutoWeight` record: path, rule, final solve),
        ``planes`` (per plane: index, depth, energy, held-out t, removal's effect,
        shows signal), ``planes_kept``, ``planes_dropped``, ``drop`` (the planes
        without evidence, whether they were dropped, the held-out error and
        relative residual with every plane and without them), ``reason``.

    Raises
    ------
    ReconInputError
        Unknown method, regulariser or ``empty_planes``.
    recon.errors.DivergenceError
        The solver diverged.
    """
    if method not in ("admm", "fista"):
        raise ReconInputError(f"3D automatic weight: method {method!r}; use admm or fista")
    if empty_planes not in EMPTY_PLANES:
        raise ReconInputError(f"empty_planes {empty_planes!r}: use one of "
                              f"{', '.join(EMPTY_PLANES)}")
    if regulariser not in VOLUME_RULES:
        raise ReconInputError(f"regulariser {regulariser!r}: use 'tv' or 'l1'")
    variance = weighted_variance(op.sensor_weights, noise, b)
    noise_energy = float(variance.sum())
    common = {"iterations": iterations, "noise_energy": noise_energy,
              "regulariser": regulariser, "plan_of": plan_of, "fixed": other,
              "rule": VOLUME_RULES[regulariser], "tuning": PathTuning(seed=seed)}
    keep, held = holdout_split(op, HOLDOUT, seed, VOLUME_RULES[regulariser].block)
    on_device = backend is not None and not backend.is_numpy
    b_solve = b
    if on_device:  # the measurement and the path's plans on the device
        b_solve = to_device(b, backend)
        common["plan_of"] = device_plan.maker(b_solve, plan_of)
    if method == "admm":
        result, choice = admm_auto(op, b_solve, **common)
    else:
        _, choice = admm_auto(op, b_solve, path_only=True, **common)
        tv, l1 = ((choice.weight, other) if regulariser == "tv" else (other, choice.weight))
        b_fit = np.ascontiguousarray(b * keep, np.float32)
        result = fista(op.with_weights(op.sensor_weights * keep),
                       to_device(b_fit, backend) if on_device else b_fit,
                       iterations=iterations, tv=tv, l1=l1, nonneg=True)
        choice.final_pixels = "fit (FISTA at the path's weight)"
        choice.final_iterations = iterations
        result.params["iterations_used"] = choice.path_iterations + iterations
    if on_device:  # the plane tests run on the host
        result.x = to_numpy(result.x)
        result.params["device"] = backend.label
    tests = plane_tests(op, result.x, b, variance, held)
    planes, kept, drop = planes_record(op, result.x, b, tests, held, empty_planes)
    if drop["planes"] and drop["applied"]:
        result.x[drop["planes"]] = 0.0
    record = {"regulariser": regulariser, "weight": choice.weight,
              "weight_choice": choice.as_dict(), "planes": planes, "planes_kept": kept,
              "planes_dropped": drop["planes"] if drop["applied"] else [], "drop": drop,
              "reason": f"{choice.reason}. Planes: {drop['reason']}"}
    return result, record
