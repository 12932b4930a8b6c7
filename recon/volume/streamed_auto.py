"""The automatic weight of streamed 3D FISTA: the held-out path of :mod:`recon.auto` over
plane slabs, in memory that is a stated function of the problem (Kuo 2020, Ch. 4).

The in-memory automatic weight (:func:`recon.auto.volume.auto_volume`) runs
:func:`recon.auto.weight.admm_auto` on whole padded volumes. Here the same function,
with the same rule (:data:`recon.auto.volume.VOLUME_RULES`: 10 % of the sensor pixels
held out in 8 x 8 blocks, the weights 1e-3 .. 1e-6 in steps of 2.7x, each solved from
the previous weight's state until its held-out error settles, at most 3.5x a fixed
run's iterations, the one-standard-error rule bounded to twice the minimum's weight,
then the chosen weight run on from its own state), drives streamed 3D FISTA
(:func:`recon.volume.streamed.slab_fista`) through the plan interface it takes
(:class:`StreamedFistaPlan`):

* the held-out pixels leave the data term on the sensor: the fits' sensor weights
  are ``w keep`` and their measurement ``b keep`` -- sensor-sized images in the loop,
  which is where :func:`~recon.volume.streamed.slab_fista` applies the weights (to
  the summed image and the residual), so no slab ever sees the mask; a candidate is
  scored on the held-out pixels from the prediction ``A x`` (one forward model per
  window of 10 iterations);
* a FISTA state is the slabs' ``x`` and ``y`` and the momentum sequence ``t``; a
  window continues it iterate for iterate, across weights too (the warm start);
* the path's copies -- the kept estimate of the candidate being solved, the best
  candidate's, and the best weight's state ``x``, ``y`` that the chosen weight runs
  on from -- are kept by the slabs themselves, beside the planes they copy
  (:meth:`recon.volume.slab.VolumeSlab.save`; in a dask worker, in that worker), and
  dropped when the path lets go of them; only their names cross. At most
  :func:`path_copies` exist at once (4 with the volume's rule), which
  :func:`recon.volume.streamed.streamed_memory_bytes` adds to the estimate with the
  path's sensor images.

The result is the chosen weight's kept estimate on the fit pixels, as in memory (the
held-out blocks hide no object pixel of a lensless PSF; where they would,
:func:`recon.auto.holdout.holdout_coverage` below one half, the chosen weight is
solved again on every pixel, :func:`~recon.auto.weight.admm_auto`). Unlike
:func:`~recon.auto.volume.auto_volume`, the planes are not tested for signal: that
test needs every plane's own prediction, a volume of sensor images; every plane is
kept and the record says so.
"""

from __future__ import annotations

import itertools
import math
import weakref

import numpy as np

from ..auto.noise import NoiseModel
from ..auto.volume import VOLUME_RULES, weighted_variance
from ..auto.weight import PathRule, PathTuning, admm_auto, weight_grid
from ..errors import ReconInputError
from ..operators import checked_sensor_weights
from ..solvers.common import SolveResult
from .streamed import final_objective, gather_estimate, slab_fista

__all__ = ["SlabIterate", "SlabModel", "SlabPath", "StreamedFistaPlan", "StreamedState",
           "auto_streamed", "path_copies"]


def path_copies(rule: PathRule) -> int:
    """Copies of the iterates the path of :func:`recon.auto.weight.admm_auto` holds at
    once with ``rule`` (what :func:`recon.volume.streamed.streamed_memory_bytes`
    counts).

    The kept estimates of the candidates the rule may still choose (the held-out
    minimum's and those of the larger weights within ``rule.max_above_minimum`` of
    it: one when the path's step is larger), the candidate being solved's, and the
    best weight's state (``x`` and ``y``). The path drops a copy before it makes the
    one that replaces it.

    Returns
    -------
    int
        4 for :data:`recon.auto.volume.VOLUME_RULES` (steps of 2.7x, bound 2x).
    """
    grid = weight_grid(rule.start, rule.end, rule.factor)
    step = grid[0] / grid[1] if len(grid) > 1 else math.inf
    choosable = 1 + int(math.floor(math.log(rule.max_above_minimum) / math.log(step) + 1e-9))
    return choosable + 1 + 2


class SlabPath:
    """The slabs of one streamed solve as the automatic weight's path uses them.

    Holds the group, which FISTA state the slabs' ``x`` and ``y`` are now (``live``),
    and the names of the copies to drop: a copy (:class:`SlabIterate`) that nothing
    refers to any more is dropped from the slabs before the next copy is made or the
    next solve runs (its name queued by a finaliser, so that no message leaves from a
    garbage collection).

    Parameters
    ----------
    group : recon.volume.streamed.LocalSlabs or instrument.processing.volume_shards.ShardedSlabs
        The slabs, in depth order.

    Attributes
    ----------
    group
    live : StreamedState or None
    power_max : float
        ``max_f sum_z |H_z(f)|^2`` over every slab (the Lipschitz bound before the
        sensor weights).
    """

    def __init__(self, group):
        self.group = group
        self.live = None
        self._drop: list[str] = []
        self._names = itertools.count()
        power = None
        for p in group.call("power_spectrum"):
            power = p if power is None else power + p
        self.power_max = float(power.max())

    def call(self, method: str, *args) -> list:
        """``method(*args)`` on every slab, after dropping the copies let go of."""
        self.flush()
        return self.group.call(method, [args] * len(self.group))

    def flush(self) -> None:
        """Drop from the slabs the copies nothing refers to any more."""
        if self._drop:
            names = tuple(self._drop)
            self._drop.clear()  # in place: the finalisers append to this list
            self.group.call("release", [(names,)] * len(self.group))

    def save(self, source: str = "x", state: bool = False) -> SlabIterate:
        """A new copy in the slabs of ``source`` (``"x"`` or a copy's name), or of the
        state ``x``, ``y`` (``state``)."""
        name = f"path{next(self._names)}"
        self.call("save", name, source, state)
        return SlabIterate(self, name, owned=True)

    def prediction(self, which: str = "x") -> np.ndarray:
        """``C sum_z h_z * v_z`` of the iterate ``which``, unweighted (float32, sensor
        shape)."""
        parts = self.call("forward", which)
        out = parts[0]
        for p in parts[1:]:
            out = out + p
        return out

    def activate(self, state: StreamedState) -> None:
        """Make ``state`` the slabs' ``x`` and ``y``: restore its copy (then dropped)."""
        if self.live is state:
            return
        if state.saved is None:
            raise RuntimeError("a FISTA state of the streamed path was neither the slabs' "
                               "iterates nor saved")
        self.call("restore", state.saved.name)
        state.saved = None
        state.drop_prediction()
        self.live = state


class SlabIterate:
    """An iterate held by the slabs: their ``x``, or a copy they keep under ``name``.

    ``copy()`` makes a new copy in the slabs (what the path's ``PathArrays.copy``,
    ``recon.auto.xp_path``, calls on its iterates); an owned copy is dropped from the
    slabs once this handle is gone.

    Parameters
    ----------
    path : SlabPath
    name : str
        ``"x"`` (the slabs' own iterate) or a copy's name.
    owned : bool
        A copy this handle owns (dropped with it).
    """

    def __init__(self, path: SlabPath, name: str, owned: bool = False):
        self.path, self.name = path, name
        if owned:
            weakref.finalize(self, path._drop.append, name)

    def copy(self) -> SlabIterate:
        """A copy of this iterate, kept by the slabs."""
        return self.path.save(self.name)


class StreamedState:
    """FISTA's state for :func:`recon.auto.weight.admm_auto`: the slabs' ``x`` and ``y``
    (while ``path.live`` is this state) or a copy of them (``saved``), and ``t``.

    Attributes
    ----------
    t : float
        FISTA's momentum sequence.
    saved : SlabIterate or None
        The copy of ``x`` and ``y`` (a state that is not the slabs' own).
    mu : tuple
        Empty: FISTA has no penalties (the path records the state's).
    """

    mu = ()

    def __init__(self, path: SlabPath, t: float = 1.0, saved: SlabIterate | None = None):
        self.path, self.t, self.saved = path, float(t), saved
        self._mx = None

    @property
    def mx(self) -> np.ndarray:
        """The prediction of ``x``, unweighted (float32, sensor shape; made once per
        run, for the held-out score)."""
        if self.path.live is not self:
            raise RuntimeError("the prediction of a saved FISTA state was asked for")
        if self._mx is None:
            self._mx = self.path.prediction("x")
        return self._mx

    def drop_prediction(self) -> None:
        """Forget the prediction (the iterate moved)."""
        self._mx = None

    def __deepcopy__(self, memo) -> StreamedState:
        """A copy kept by the slabs (the path's warm state to return to)."""
        source = "x" if self.path.live is self else self.saved.name
        return StreamedState(self.path, self.t, self.path.save(source, state=True))


class SlabModel:
    """What :func:`recon.auto.weight.admm_auto` asks of the forward model, for slabs.

    Parameters
    ----------
    path : SlabPath
    sensor_weights : ndarray, float32, sensor shape

    Attributes
    ----------
    sensor_shape, shape_out : (rows, cols)
    sensor_weights : ndarray, float32
    crop : (slice, slice)
        The whole sensor: the states' predictions (``StreamedState.mx``) are sensor
        images already.
    """

    def __init__(self, path: SlabPath, sensor_weights: np.ndarray):
        self.path = path
        self.sensor_weights = sensor_weights
        self.sensor_shape = self.shape_out = tuple(sensor_weights.shape)
        self.crop = (slice(None), slice(None))

    def with_weights(self, sensor_weights: np.ndarray) -> SlabModel:
        """The same slabs with other sensor weights (the fit pixels')."""
        return SlabModel(self.path, np.ascontiguousarray(sensor_weights, np.float32))

    def coverage(self, keep: np.ndarray) -> float:
        """:func:`recon.auto.holdout.holdout_coverage` computed plane by plane in the slabs
        (two passes: the largest ``A^T w``, then the smallest ratio).

        Parameters
        ----------
        keep : ndarray of bool, sensor shape

        Returns
        -------
        float
        """
        w = self.sensor_weights
        peak = max(self.path.call("coverage", w))
        ratio = min(self.path.call("coverage", w, (w * keep).astype(np.float32), peak))
        return ratio if math.isfinite(ratio) else 0.0


class StreamedFistaPlan:
    """Streamed 3D FISTA with the plan interface of :func:`recon.auto.weight.admm_auto`
    (``zeros``, ``warm``, ``run``, ``objective``) on a model's slabs and sensor weights;
    the class is the path's ``plan_of``.

    Parameters
    ----------
    model : SlabModel
        The slabs, and the sensor weights of the fits (the fit pixels' or all).

    Attributes
    ----------
    lipschitz : float
        ``path.power_max * max(w)^2``, the step's bound (as
        :func:`~recon.volume.streamed.slab_fista` computes it).
    """

    def __init__(self, model: SlabModel):
        self.path = model.path
        self.weights = model.sensor_weights
        self.lipschitz = self.path.power_max * float(self.weights.max()) ** 2

    def zeros(self, mu=None, use_tv: bool = True) -> StreamedState:
        """The cold start: the slabs' ``x`` and ``y`` zero (``mu``, ``use_tv``: unused)."""
        self.path.call("reset")
        state = StreamedState(self.path)
        self.path.live = state
        return state

    def warm(self, x: SlabIterate | None, mu=None, use_tv: bool = True) -> StreamedState:
        """A fresh start (``t`` 1) at the kept estimate ``x``: ``x`` and ``y`` set to it."""
        if x is None:
            return self.zeros()
        self.path.call("restore", x.name)
        state = StreamedState(self.path)
        self.path.live = state
        return state

    def run(self, b: np.ndarray, state: StreamedState, *, iterations: int, tv: float,
            l1: float = 0.0, final: bool = True) -> SolveResult:
        """:func:`~recon.volume.streamed.slab_fista` from ``state`` (continued in place).

        Returns
        -------
        SolveResult
            ``x`` the slabs' ``x`` (:class:`SlabIterate`).
        """
        self.path.activate(state)
        state.drop_prediction()
        self.path.flush()
        res = slab_fista(self.path.group, b, sensor_weights=self.weights,
                         iterations=iterations, tv=tv, l1=l1, nonneg=True,
                         lipschitz=self.lipschitz, t=state.t, final=final, gather=False)
        state.t = res.params["t"]
        res.x = SlabIterate(self.path, "x")
        return res

    def objective(self, b: np.ndarray, x: SlabIterate, *, tv: float, l1: float,
                  b_norm: float) -> tuple[float, float]:
        """Objective and relative data residual of the estimate ``x`` held by the slabs
        (:func:`recon.volume.streamed.final_objective`)."""
        self.path.flush()
        final, data_sq = final_objective(self.path.group, b, self.weights, tv, l1, x.name)
        return final, math.sqrt(data_sq) / b_norm


def auto_streamed(group, b: np.ndarray, *, noise: NoiseModel, iterations: int,
                  regulariser: str = "tv", other: float = 0.0, seed: int = 0,
                  sensor_weights=None) -> tuple[SolveResult, dict]:
    """Streamed 3D FISTA with its TV or l1 weight chosen by the held-out path.

    Parameters
    ----------
    group : recon.volume.streamed.LocalSlabs or instrument.processing.volume_shards.ShardedSlabs
        The slabs (normalised stack), fresh: their iterates zero.
    b : ndarray, float32, sensor shape
        Scaled measurement (pre-weighted).
    noise : NoiseModel
        The frame's noise model in the units of ``b`` (:meth:`NoiseModel.scaled`).
    iterations : int
        Iterations of the fixed-weight run this replaces (each candidate at most this
        many, the path with its run-on at most 3.5x as many).
    regulariser : {"tv", "l1"}
        The weight to choose; ``other`` is the fixed value of the other one.
    other : float
    seed : int
        Seed of the held-out blocks (:func:`recon.auto.holdout.holdout_split`).
    sensor_weights : ndarray, sensor shape, optional
        Default all ones.

    Returns
    -------
    result : SolveResult
        ``x`` the estimate (float32, (n_z, L0, L1) on the slabs' grid, brought into
        this process: with one slab here, the slab's own copy), on the fit pixels;
        ``history`` spans the path; ``params`` with ``auto`` (the
        :class:`recon.auto.weight.AutoWeight` record) and ``iterations_used``.
    record : dict
        JSON-ready, as :func:`recon.auto.volume.auto_volume`'s: ``regulariser``,
        ``weight``, ``weight_choice`` (the path: every candidate's held-out error,
        iterations, status and remaining bound; the stop reason; the budget),
        ``planes_kept`` (every plane), ``planes_dropped`` (none), ``planes`` (None: not
        tested), ``solver`` and ``reason``.

    Raises
    ------
    ReconInputError
        Unknown regulariser, bad weights or measurement.
    recon.errors.DivergenceError
        The solver diverged.
    """
    if regulariser not in VOLUME_RULES:
        raise ReconInputError(f"regulariser {regulariser!r}: use 'tv' or 'l1'")
    b = np.ascontiguousarray(b, np.float32)
    w = checked_sensor_weights(sensor_weights, b.shape)
    path = SlabPath(group)
    model = SlabModel(path, w)
    energy = float(weighted_variance(w, noise, b).sum())
    result, choice = admm_auto(model, b, iterations=iterations, noise_energy=energy,
                               regulariser=regulariser, fixed=other,
                               tuning=PathTuning(seed=seed),
                               rule=VOLUME_RULES[regulariser],
                               plan_of=StreamedFistaPlan)
    result.x = gather_estimate(group, result.x.name)
    path.flush()
    path.live = None  # no cycle (state -> path -> state): the slabs go with the last name
    n_z = result.x.shape[0]
    solver = ("streamed 3D FISTA (the path's solves and the result), the held-out pixels "
              "masked from the data term on the sensor")
    record = {"regulariser": regulariser, "weight": choice.weight,
              "weight_choice": choice.as_dict(), "planes": None,
              "planes_kept": list(range(n_z)), "planes_dropped": [], "solver": solver,
              "reason": f"{choice.reason}. Solver: {solver}. Planes: every plane kept, "
                        "not tested for signal (the per-plane held-out test needs each "
                        "plane's prediction, a volume of sensor images; the in-memory "
                        "path runs it)"}
    return result, record
