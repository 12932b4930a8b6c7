"""Each reconstruction option's default is stated once, in its declaration.

:class:`recon.options.ReconOptions` (and :class:`recon.options.LiveOptions` for the
live reconstructor) declare every parameter's default; the layers below the front
door (the kinds' paths, the automatic choices, the solvers, the live reconstructor,
and in ``instrument`` the live workers and the demo session) take theirs from there.
This scan finds every function and method of those layers with a parameter named
after a declared option and checks that its default *is* the declared one (by value),
and for the counts and choices that had drifted (``iterations`` 200 at the front door,
100 in the solvers, 5 restated in four live signatures) that the default names the
declaration instead of restating a literal.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import textwrap

import recon
from recon.options import LiveOptions, ReconOptions

#: Packages and modules of recon that are no reconstruction layer (hologram design,
#: optics models, analyses, simulated measurements): their ``iterations``, ``seed`` or
#: ``model`` are their own quantities.
NOT_RECONSTRUCTION = ("recon.cgh", "recon.optics", "recon.analysis", "recon.simulate",
                      "recon.scenes", "recon.sample", "recon.priors")
#: The live layers: their method and iterations per frame are LiveOptions'.
LIVE_MODULES = ("recon.live", "recon.xp_live", "instrument.acquisition.live",
                "instrument.acquisition.live_process")

#: (function's qualified name, parameter): why its default is not the declared one.
OWN_DEFAULTS = {
    ("measure_models", "iterations"): "the model choice's own scoring solve (a study)",
    ("measure_models", "l1"): "the model choice's own scoring solve (a study)",
    ("blind_calibration", "l1"): "the blind calibration's sparse scene, not the image's",
    ("two_point_resolution", "l1"): "a resolution study's fixed weight",
    ("prepare_pair", "dark"): "None: the resolved spelling of the estimate (below the "
                              "front door's 'auto')",
    ("check_psf_signal", "dark"): "as prepare_pair",
    ("set_method", "iterations"): "None: the live worker keeps its current count",
    ("LiveReconstructor.__init__", "tv"): "None: a fixed weight, recon.planar.DEFAULT_TV's "
                                          "(the live solve chooses none)",
}
#: A solver takes fixed weights (0: no such term) and the built-in TV split (None); the
#: automatic choices ("auto", the declared default) are made above it.
SOLVER_SPELLINGS = {"tv": (0.0,), "l1": (0.0,), "prior": (None,)}
#: The options whose defaults had been restated as literals: they must name the
#: declaration (``_D["iterations"]``, ``DEFAULT_ITERATIONS``), not repeat its value.
NAMED = ("iterations", "method", "device")


def _modules():
    names = [m.name for m in pkgutil.walk_packages(recon.__path__, "recon.")]
    names += ["instrument.acquisition.live", "instrument.acquisition.live_process",
              "instrument.acquisition.demo"]
    for name in sorted(names):
        if name.startswith(NOT_RECONSTRUCTION) or name.rsplit(".", 1)[-1].startswith("_"):
            continue
        yield importlib.import_module(name)


def _functions(module):
    """Every function and method defined in ``module`` (qualname, object)."""
    for name, obj in vars(module).items():
        if inspect.isfunction(obj) and obj.__module__ == module.__name__:
            yield name, obj
        elif inspect.isclass(obj) and obj.__module__ == module.__name__:
            for attr, member in vars(obj).items():
                if isinstance(member, staticmethod | classmethod):
                    member = member.__func__
                if inspect.isfunction(member):
                    yield f"{name}.{attr}", member


def _declared(module_name: str) -> dict:
    defaults = dict(ReconOptions.defaults())
    if module_name in LIVE_MODULES:
        defaults.update(LiveOptions.defaults())
    return defaults


def _literal_defaults(func) -> dict:
    """``{parameter: True}`` for each default written as a literal constant."""
    try:
        source = textwrap.dedent(inspect.getsource(func))
    except (OSError, TypeError):
        return {}
    node = ast.parse(source).body[0]
    args = node.args
    positional = args.posonlyargs + args.args
    pairs = list(zip(positional[len(positional) - len(args.defaults):], args.defaults, strict=True))
    pairs += [(a, d) for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True)
              if d is not None]
    return {a.arg: isinstance(d, ast.Constant) for a, d in pairs}


def _offences():
    wrong, restated = [], []
    for module in _modules():
        declared = _declared(module.__name__)
        for qualname, func in _functions(module):
            if func.__code__.co_filename == "<string>":
                continue  # a dataclass's __init__: record fields, not parameters
            params = inspect.signature(func).parameters
            literal = None
            for name, param in params.items():
                if name not in declared or param.default is inspect.Parameter.empty:
                    continue
                short = qualname.rsplit(".", 1)[-1]
                if (short, name) in OWN_DEFAULTS or (qualname, name) in OWN_DEFAULTS:
                    continue
                value, want = param.default, declared[name]
                where = f"{module.__name__}.{qualname}({name}={value!r})"
                if not (value == want or value in SOLVER_SPELLINGS.get(name, ())):
                    wrong.append(f"{where}: declared {want!r}")
                    continue
                if name in NAMED:
                    literal = _literal_defaults(func) if literal is None else literal
                    if literal.get(name):
                        restated.append(where)
    return wrong, restated


def test_every_layer_defaults_to_the_declared_value():
    """A parameter named after a declared option defaults to the declaration's value
    in every reconstruction layer (solvers: 200 iterations like the front door, not
    100), except the table of quantities that only share the name."""
    wrong, _ = _offences()
    assert not wrong, "\n".join(wrong)


def test_the_counts_and_choices_name_their_declaration():
    """``iterations``, ``method`` and ``device`` defaults are the
    declared objects, not literals restating them (the live reconstructor's 5
    iterations per frame is LiveOptions', in recon.live and instrument's workers)."""
    _, restated = _offences()
    assert not restated, "\n".join(restated)


def test_the_scan_sees_the_layers_it_guards():
    """The scan reaches the solvers, the kinds' paths and the live workers (a test
    that found no function would pass whatever the defaults)."""
    seen = {f"{m.__name__}.{q}" for m in _modules() for q, _ in _functions(m)}
    for name in ("recon.solvers.gradient.fista", "recon.solvers.admm.admm",
                 "recon.volume.fista.fista3d", "recon.planar.reconstruct_image",
                 "recon.live.LiveReconstructor.admm",
                 "instrument.acquisition.live.LiveReconstruction.__init__",
                 "instrument.acquisition.live_process.LiveReconstructionProcess.__init__",
                 "instrument.acquisition.demo.run_demo"):
        assert name in seen, name


def test_the_solvers_shared_default_is_the_declaration():
    """The iterative solvers' one default (their signatures name it) is the declared
    ``iterations``: one number to change."""
    from recon.solvers.common import DEFAULT_ITERATIONS

    assert DEFAULT_ITERATIONS == ReconOptions.defaults()["iterations"]


#: The layers that decide and the most parameters each takes (the options object and
#: the prepared problem, and their own objects: a mask, a colour pattern, plans).
DECIDING = {"recon.planar.reconstruct_image": 8, "recon.auto.solve_channel": 9,
            "recon.volume.api.reconstruct_stack": 7, "recon.spatial.api.reconstruct_psf_grid": 7}


def test_the_deciding_layers_take_the_options_object():
    """The kinds' paths and each channel's solve take the options (ReconOptions)
    instead of loose keywords: no parameter named after a declared option, and a short
    signature (they took 19, 16, 15 and 16)."""
    for dotted, most in DECIDING.items():
        module, name = dotted.rsplit(".", 1)
        params = inspect.signature(getattr(importlib.import_module(module), name)).parameters
        loose = sorted(set(params) & set(ReconOptions.defaults()))
        assert not loose, f"{dotted} takes {loose} loose; read them from its options"
        assert "options" in params and len(params) <= most, (dotted, list(params))


def test_the_automatic_weight_takes_its_tuning_as_one_object():
    """admm_auto keeps plain keywords for what a caller chooses (iterations, noise,
    which weight, plans, budget) and takes the path's rarely changed settings as one
    PathTuning (it took 16 parameters)."""
    from recon.auto.weight import admm_auto

    params = inspect.signature(admm_auto).parameters
    assert "tuning" in params and len(params) <= 11, list(params)


#: The live layers' constructors and the options object each takes: the method and
#: iterations per frame are LiveOptions', the binning, dark level and device the
#: reconstructor's ReconOptions; their other parameters are no declared option (the
#: PSF, the reconstructor, worker settings), save the live solve's fixed TV weight.
LIVE_TAKERS = {"recon.live.LiveReconstructor": ("options", {"tv"}),
               "instrument.acquisition.live.LiveReconstruction": ("live", set()),
               "instrument.acquisition.live_process.LiveReconstructionProcess": ("live", set())}


def test_the_live_layers_take_the_options_objects():
    """The live reconstructor and both live workers take the options objects (one
    declaration of method, iterations, binning, dark level and device with their
    defaults) instead of restating them as keywords."""
    declared = set(ReconOptions.defaults()) | set(LiveOptions.defaults())
    for dotted, (taker, own) in LIVE_TAKERS.items():
        module, name = dotted.rsplit(".", 1)
        params = inspect.signature(getattr(importlib.import_module(module), name)).parameters
        loose = sorted(set(params) & declared - own)
        assert not loose, f"{dotted} takes {loose} loose; read them from its options"
        assert params[taker].default is None, (dotted, taker)


def test_no_live_signature_restates_a_live_default():
    """No function or method of the live layers defaults a parameter named after a
    LiveOptions field (``iterations=5`` per frame, ``method="wiener"``), by literal or
    by name: the declaration is the one place (``set_method``'s None keeps the current
    count)."""
    live = set(LiveOptions.defaults())
    restated = []
    for module in (importlib.import_module(m) for m in LIVE_MODULES):
        for qualname, func in _functions(module):
            for name, param in inspect.signature(func).parameters.items():
                if (name in live and param.default is not inspect.Parameter.empty
                        and param.default is not None):
                    restated.append(f"{module.__name__}.{qualname}({name}={param.default!r})")
    assert not restated, "\n".join(restated)


#: Quantities that only shared the name ``iterations`` with the declared option, and
#: the names of their own they have now (issue 66's house bar): (module, qualified
#: name) -> the parameter's name.
OWN_NAMES = {("recon.operators", "LinearOperator.lipschitz"): "power_iterations",
             ("recon.xp_operators", "_XpCropped.lipschitz"): "power_iterations",
             ("recon.spatial.blind", "_PsfModel.lipschitz"): "power_iterations",
             ("recon.priors.tgv", "TgvPrior.__init__"): "inner_iterations",
             ("calibration_routines.slm_lut_analysis", "combine_passes"): "refinements",
             ("recon.cgh.optimize", "optimize_hologram"): "steps",
             ("recon.cgh.evaluation", "evaluate_images"): "steps",
             ("recon.cgh.evaluate", "run_evaluation"): "steps",
             ("instrument.benchmarks.hologram", "run_benchmark"): "steps",
             ("calibration_routines.mask_alignment.hologram_check", "hologram_check"): "steps"}


def test_other_quantities_are_not_called_iterations():
    """Power iterations, TGV's inner loop, the LUT fit's refinements and the hologram
    optimiser's steps are no reconstruction's iterations: a parameter of their own name,
    none called ``iterations``."""
    for (module, qualname), own in OWN_NAMES.items():
        obj = importlib.import_module(module)
        for bit in qualname.split("."):
            obj = getattr(obj, bit)
        params = inspect.signature(obj).parameters
        assert own in params and "iterations" not in params, (module, qualname, list(params))


#: Helpers that every caller gives a binning: the declared default (1) is not restated
#: in their signatures (issue 66's house bar), so a caller that forgot it is refused.
BINNING_GIVEN = (("recon.preprocess.pair", "check_psf_signal"),
                 ("recon.volume.api", "prepare_volume_problem"),
                 ("recon.volume.memory_plan", "memory_plan"),
                 ("recon.spatial.api", "grid_model"),
                 ("recon.analysis.reports", "prepare_stack"),
                 ("instrument.processing.batch", "check_dark_level"),
                 ("instrument.processing.batch_grid", "prepare_grid_batch"),
                 ("instrument.processing.planes", "select_planes"))


def test_helpers_given_a_binning_restate_no_default():
    for module, name in BINNING_GIVEN:
        param = inspect.signature(getattr(importlib.import_module(module), name)
                                  ).parameters["bin_factor"]
        assert param.default is inspect.Parameter.empty, (module, name, param.default)
