"""Automatic regularisation, stopping and method choice: model no more than a scene needs.

* :mod:`recon.auto.noise` - the Poisson-Gaussian noise model fitted to one frame;
* :mod:`recon.auto.weight` - the TV / l1 weight by hold-out cross-validation along a
  warm-started continuation path, and automatic stopping;
* :mod:`recon.auto.choice` - the method for ``method="auto"`` and the no-signal check;
* :mod:`recon.auto.prior` - the prior (TV, wavelet, DnCNN) by the same held-out
  procedure, for ``prior="auto"``.

:func:`solve_channel` is what :func:`recon.reconstruct` runs per colour channel.
"""

from __future__ import annotations

import numbers
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ReconInputError
from ..options import ReconOptions, l1_given, weight_arg
from ..priors import AUTO_PRIORS, PRIORS, prior_of  # moved there (a light module for the parsers)
from ..solvers import SOLVERS, SolveResult
from .choice import NoSignalError, check_signal, choose_method
from .noise import NoiseModel, estimate_noise
from .prior import PRIOR_RULES, choose_prior, prior_plan_of
from .weight import MODEL_ERROR, AutoWeight, Stopping, admm_auto

__all__ = ["AUTO", "AutoWeight", "ChannelProblem", "NoSignalError", "NoiseModel", "Stopping",
           "estimate_noise",
           "noise_energy_of", "parse_weight", "prior_path", "solve_channel", "weight_arg",
           "weight_path"]

#: The value that asks for an automatic choice (``method``, ``tv``, ``l1``).
AUTO = "auto"
#: The declared default prior (:class:`recon.options.ReconOptions`): isotropic TV, the
#: prior of ADMM; a method without it (FISTA, GD, Wiener) keeps its own TV under it.
DEFAULT_PRIOR = ReconOptions.spec("prior").default


def parse_weight(value, name: str):
    """``"auto"`` or a finite real weight >= 0 (``None`` means ``"auto"``); no strings
    but ``"auto"`` (the command line converts with :func:`weight_arg`).

    Raises
    ------
    ReconInputError
        Anything else, naming ``name`` and the accepted values.
    """
    if value is None or (isinstance(value, str) and value.strip().lower() == AUTO):
        return AUTO
    if isinstance(value, bool | str) or not isinstance(value, numbers.Real):
        raise ReconInputError(f"{name} weight must be a finite number >= 0 or "
                              f"'auto', got {value!r}")
    w = float(value)
    if not (np.isfinite(w) and w >= 0):
        raise ReconInputError(f"{name} weight must be a finite number >= 0 or "
                              f"'auto', got {value!r}")
    return w


def weight_path(backend, op, b: np.ndarray, **kwargs) -> tuple[SolveResult | None, AutoWeight]:
    """:func:`recon.auto.weight.admm_auto` on ``backend`` (None or NumPy: on the host).

    On a device the measurement is moved there after a memory check, the path and the
    final solve run on the generic ADMM with every iterate kept there, and the
    result's ``x`` comes back as a NumPy array (``params["device"]`` names the device).

    Parameters
    ----------
    backend : Backend or None
    op : ConvolutionOperator
        Scaled forward model (a device: the 2D convolution only).
    b : ndarray, float32, ``op.shape_out``
        Scaled measurement on the host.
    **kwargs
        Passed to :func:`~recon.auto.weight.admm_auto`.

    Returns
    -------
    result, choice
        As :func:`~recon.auto.weight.admm_auto`.

    Raises
    ------
    ReconInputError
        The path does not fit in the device's free memory (says how much it needs).
    """
    if backend is None or backend.is_numpy:
        return admm_auto(op, b, **kwargs)
    from ..backend import to_device, to_numpy
    from ..solvers.device import check_device_memory
    from ..solvers.xp_admm import memory_bytes

    p0, p1 = op.padded_shape
    # the solve's arrays, and up to 8 planes more: the path's kept estimates, the final
    # solve's best iterate, the held-out masks and weights
    check_device_memory(backend, memory_bytes((p0, p1)) + 8 * 4 * p0 * p1,
                        f"automatic 2D ADMM at {op.sensor_shape[0]} x {op.sensor_shape[1]}")
    res, chosen = admm_auto(op, to_device(b, backend), **kwargs)
    if res is not None:
        res.x = to_numpy(res.x)
        res.params["device"] = backend.label
    return res, chosen


def noise_energy_of(op, raw: np.ndarray, raw_scale: float) -> tuple[NoiseModel, float]:
    """The noise model fitted to one channel's frame and E||n||^2 of the scaled,
    weighted measurement (``b = raw * weights / raw_scale``).

    A frame too small for the noise fit (< 8 x 8) gets no noise model (zero energy:
    no signal check, and stopping on the model error alone).

    Returns
    -------
    noise : NoiseModel
    energy : float
        sum(w^2 var(raw / raw_scale)), in the scaled problem's units.
    """
    w2 = np.square(op.sensor_weights, dtype=np.float64)
    noise = (estimate_noise(raw) if min(np.shape(raw)[:2]) >= 8
             else NoiseModel(0.0, 0.0, []))
    scaled = noise.scaled(raw_scale)
    return noise, float(np.sum(w2 * scaled.variance(np.asarray(raw) / raw_scale)))


@dataclass(frozen=True)
class ChannelProblem:
    """One colour channel's prepared problem, in the solvers' scaling
    (:func:`recon.planar.scaled_problem`): what :func:`solve_channel` solves.

    Attributes
    ----------
    op : ConvolutionOperator or SpatialConvolutionOperator
        Scaled forward model (unit-sum PSF, erasure weights folded in).
    b : ndarray, float32, ``op.shape_out``
        Scaled, weighted measurement (``raw * weights / raw_scale``).
    raw : ndarray, ``op.shape_out``
        The channel's dark-subtracted measurement before scaling, DN (the noise model
        is fitted to it).
    raw_scale : float
        ``b = raw * weights / raw_scale``, DN.
    """

    op: Any
    b: np.ndarray
    raw: np.ndarray
    raw_scale: float


def solve_channel(problem: ChannelProblem, options: ReconOptions, *,
                  fft_pair_s: float | None = None, auto_stop: bool = True, solvers=None,
                  plan_of=None, final_solve: int | None = None, backend=None,
                  **solver_options) -> tuple[SolveResult, dict]:
    """Solve one channel with automatic choices where asked, fixed ones elsewhere.

    Parameters
    ----------
    problem : recon.auto.ChannelProblem
        The scaled forward model and measurement, and the raw channel they came from.
    options : recon.options.ReconOptions
        The reconstruction's options (:meth:`ReconOptions.from_defaults
        <diffuserlab.options.Options.from_defaults>` for a library call); this layer
        reads ``method`` (``"auto"`` or a key of ``solvers``), ``iterations`` (the
        maximum: automatic stopping ends earlier when the fit settles), ``tv`` and
        ``l1`` (``"auto"`` chooses by hold-out cross-validation, the other weight held
        fixed along the way; with ``l1="auto"`` an automatic ``tv`` is 0, one weight
        is chosen at a time; ``tv`` None is ``"auto"``, ``l1`` not given is 0),
        ``seconds`` (time budget, ``method="auto"`` only) and ``prior``
        (``"tv-iso"``, the declared default, ``"tv"``, ``"tgv"``, ``"wavelet"``,
        ``"dncnn"``, ``"auto"`` or a :class:`recon.priors.Prior`: the image prior of
        ADMM, ``tv`` its weight; FISTA and GD keep their own anisotropic TV under the
        default; another prior than TV named needs ADMM, a method that resolves to
        Wiener ignores it and the record says so; ``"auto"`` runs every prior's
        weight path and keeps the simplest that predicts the held-out pixels within
        one standard error of the best, :func:`recon.auto.prior.choose_prior`,
        ``tv`` then ``"auto"``).
    fft_pair_s : float, optional
        Measured FFT floor (needed with ``seconds``).
    auto_stop : bool
        Stop a fixed-weight solve when its fit settles (:class:`Stopping`); False
        runs exactly ``iterations``.
    solvers : dict, optional
        The methods by name (:class:`recon.solvers.SolverSpec`); default
        :data:`recon.solvers.SOLVERS`. A spatially varying model passes its own
        (:data:`recon.spatial.api.GRID_SOLVERS`).
    plan_of : callable, optional
        The automatic weight's ADMM plan for ``op`` (see
        :func:`recon.auto.weight.admm_auto`).
    final_solve : int, optional
        None (default): with an automatic weight and ADMM, the result is the weight
        path's own solve. A count: the path (sized by ``iterations``) only chooses the
        weight, and ``solvers``' method then solves at it for at most this many
        iterations (a method other than ADMM always solves after its path, for at most
        this many or ``iterations``).
    backend : Backend, optional
        Where the automatic weight's path and final solve run
        (:func:`recon.auto.weight.admm_auto` on the generic ADMM, iterates kept on the
        device between its solves; the result's ``x`` comes back to the host); None
        or :data:`recon.backend.NUMPY`: the NumPy path. ``solvers`` should then be the
        same device's (``recon.solvers.device.device_solvers``).
    **solver_options
        Passed to a fixed method's solver.

    Returns
    -------
    result : SolveResult
        ``params['iterations_used']`` for the iterative methods.
    record : dict
        JSON-ready: ``noise`` (the fitted model), ``snr_db``, ``method`` (chosen and
        why), ``weight`` (the :class:`AutoWeight` record when a weight was chosen),
        ``tv``, ``l1``, ``iterations_used``; ``prior`` with a prior other than TV
        (its settings; for ``"auto"`` the :class:`~recon.auto.prior.PriorChoice`).

    Raises
    ------
    NoSignalError
        ``method="auto"`` on a frame that holds only noise.
    ReconInputError
        Invalid weights or budget, ``seconds`` with a fixed method, a weight path
        that does not fit in the device's free memory, an unknown prior, a prior other
        than TV with a method other than ADMM or with ``l1="auto"``, or
        ``prior="auto"`` with a fixed ``tv``.
    """
    op, b, raw, raw_scale = problem.op, problem.b, problem.raw, problem.raw_scale
    method, iterations, seconds = options.method, options.iterations, options.seconds
    l1 = l1_given(options.l1)
    tv, l1 = parse_weight(options.tv, "tv"), parse_weight(0.0 if l1 is None else l1, "l1")
    prior, options = options.prior, solver_options
    prior_name = AUTO if prior == AUTO else prior_of(prior).name
    t0 = time.perf_counter()
    noise, noise_energy = noise_energy_of(op, raw, raw_scale)
    b_norm = float(np.linalg.norm(b))
    record = {"noise": noise.as_dict(), "noise_energy_scaled": noise_energy,
              "model_error": MODEL_ERROR}
    if l1 == AUTO and tv == AUTO:
        tv = 0.0
    if method == AUTO:
        record["snr_db"] = check_signal(b_norm ** 2, noise_energy)
        choice = choose_method(iterations, seconds=seconds, fft_pair_s=fft_pair_s,
                               snr_db=record["snr_db"])
        record["method"] = choice.as_dict()
        method, iterations = choice.method, choice.iterations
    elif seconds is not None:
        raise ReconInputError("a time budget (seconds) needs method 'auto'; drop it or use "
                              "method='auto'")
    solvers = SOLVERS if solvers is None else solvers
    if method not in solvers:
        raise ReconInputError(f"method {method!r} does not serve this forward model; use one "
                              f"of {', '.join(solvers)}")
    spec = solvers[method]
    if method != "admm" and prior_name == DEFAULT_PRIOR:
        # the declared default (isotropic TV) is ADMM's prior; the other methods keep
        # their own TV (FISTA and GD: anisotropic; Wiener: none), as before it was
        prior, prior_name = "tv", "tv"
    if not spec.iterative:
        res = spec.solve(op, b, **options)
        record.update(tv=0.0, l1=0.0, iterations_used=1)
        if prior_name != "tv":
            record["prior"] = {"prior": None, "reason": f"{method} has no prior"}
        return res, record
    if prior_name != "tv":
        _check_prior(prior_name, method, tv, l1)
    named = prior_of(prior) if prior_name not in ("tv", AUTO) else None
    target = 0.5 * (noise_energy + (MODEL_ERROR * b_norm) ** 2)
    auto_reg = "tv" if tv == AUTO else "l1" if l1 == AUTO else None
    fixed = float(l1 if auto_reg == "tv" else tv) if auto_reg is not None else 0.0
    # the time budget left to the weight path (the noise fit and the choice took some)
    path_s = None if seconds is None else max(1e-3, seconds - (time.perf_counter() - t0))
    # a named prior's weight path: its plans and its rule; its solve: the prior keyword
    path_kw = ({"plan_of": plan_of} if named is None else
               {"plan_of": prior_plan_of(named, _like(b, backend)),
                "rule": PRIOR_RULES[named.name]})
    solve_kw = {} if named is None else {"prior": named}
    if prior_name == AUTO:  # every prior's path, then the simplest within one SE
        res, chosen, pchoice = choose_prior(prior_path(
            op, b, iterations=iterations, noise_energy=noise_energy, fixed=fixed,
            backend=backend, seconds=None if path_s is None else path_s / len(AUTO_PRIORS)))
        record.update(prior=pchoice.as_dict(), weight=chosen.as_dict())
        tv = chosen.weight
    elif auto_reg is not None and method == "admm" and not options and final_solve is None:
        res, chosen = weight_path(backend, op, b, iterations=iterations,
                                  noise_energy=noise_energy, regulariser=auto_reg,
                                  fixed=fixed, seconds=path_s, **path_kw)
        if named is not None:
            chosen.regulariser = named.name
        record["weight"] = chosen.as_dict()
        tv, l1 = ((chosen.weight, 0.0 if l1 == AUTO else l1) if auto_reg == "tv"
                  else (tv, chosen.weight))
    else:
        if auto_reg is not None:
            _, chosen = weight_path(backend, op, b, iterations=iterations,
                                    noise_energy=noise_energy, regulariser=auto_reg,
                                    path_only=True, fixed=fixed, seconds=path_s, **path_kw)
            if named is not None:
                chosen.regulariser = named.name
            record["weight"] = dict(chosen.as_dict(), chosen_by="ADMM path, used by "
                                    + method)
            if auto_reg == "tv":
                tv, l1 = chosen.weight, (0.0 if l1 == AUTO else l1)
            else:
                tv, l1 = (0.0 if tv == AUTO else tv), chosen.weight
        stop = Stopping().hook(target, b_norm) if auto_stop else None
        extra = {"l1": l1} if l1 else {}
        if auto_reg is not None and final_solve is not None:
            iterations = int(final_solve)
        res = spec.solve(op, b, iterations=iterations, tv=tv, stop=stop, **extra, **options,
                         **solve_kw)
    if named is not None:
        record["prior"] = named.record()
        res.params.setdefault("prior", named.record())
    record.update(tv=float(tv), l1=float(l1),
                  iterations_used=int(res.params.get("iterations_used", iterations)))
    return res, record


def prior_path(op, b: np.ndarray, *, iterations: int, noise_energy: float, fixed: float = 0.0,
               backend=None, seconds: float | None = None):
    """``path(name, rule) -> (result, AutoWeight)``: one prior's automatic weight on this
    measurement (:func:`weight_path` with the prior's plans,
    :func:`~recon.auto.prior.prior_plan_of`), the argument of
    :func:`~recon.auto.prior.choose_prior`.

    Parameters
    ----------
    op, b, iterations, noise_energy, backend
        As :func:`weight_path` / :func:`~recon.auto.weight.admm_auto`.
    fixed : float
        The l1 weight held fixed.
    seconds : float, optional
        Each prior's path's wall-clock budget, s.

    Returns
    -------
    callable
        ``path(name, rule)``: :func:`weight_path` with ``regulariser="tv"`` (the u
        split's weight), the plans of :func:`~recon.auto.prior.prior_plan_of` for prior
        ``name`` and the :class:`~recon.auto.weight.PathRule` ``rule``; it returns
        ``(result, AutoWeight)`` and raises what :func:`weight_path` raises.
    """
    like = _like(b, backend)

    def path(name: str, rule):
        return weight_path(backend, op, b, iterations=iterations, noise_energy=noise_energy,
                           regulariser="tv", plan_of=prior_plan_of(name, like), fixed=fixed,
                           rule=rule, seconds=seconds)

    return path


def _check_prior(name: str, method: str, tv, l1) -> None:
    """What a prior other than TV (``name``, or ``"auto"``) asks of the solve.

    Raises
    ------
    ReconInputError
        A method other than ADMM, an automatic l1 weight, or ``"auto"`` with a fixed
        ``tv`` (the message names the fix).
    """
    if method != "admm":
        raise ReconInputError(f"the {name} prior runs in ADMM; use method admm or auto, or "
                              "prior tv with this method")
    if l1 == AUTO:
        raise ReconInputError("an automatic l1 weight is chosen with TV only; give a fixed l1 "
                              "or prior tv")
    if name == AUTO and tv != AUTO:
        raise ReconInputError(f"prior auto chooses each prior's weight as well; leave tv at "
                              f"auto (got {tv!r}) or name one of {', '.join(PRIORS)}")


def _like(b: np.ndarray, backend):
    """An array of the backend the weight path runs on (``b`` itself on the host)."""
    if backend is None or backend.is_numpy:
        return b
    from ..backend import to_device

    return to_device(np.zeros((1, 1), np.float32), backend)
