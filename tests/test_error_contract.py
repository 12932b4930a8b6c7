"""The error contract: every exception the project defines derives from
diffuserlab.errors.DiffuserLabError, and user-fixable input errors from InputError
(so every command reports them the same way, exit status 2)."""

import importlib
import inspect
import pkgutil

import pytest

from diffuserlab.errors import DiffuserLabError, InputError

PACKAGES = ("diffuserlab", "recon", "drivers", "instrument", "calibration_routines", "gui")
#: Private exceptions of the protocol emulators stand for a device's own firmware
#: errors and never leave the emulator.
SKIP_MODULE_PREFIXES = ("drivers.emulators.",)
#: Optional modules whose imports need a display or a library not installed here, and
#: the operator's-day driver (a test harness: its StepFailed is a failed test step).
OPTIONAL = ("drivers.slm_window_app", "drivers.aravis_support", "soak.operator_day",
            "soak.driver")


def _our_exceptions():
    found = {}
    for package in PACKAGES:
        pkg = importlib.import_module(package)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{package}."):
            if (info.name.startswith(SKIP_MODULE_PREFIXES) or info.name in OPTIONAL
                    or info.name.endswith(".__main__")):
                continue
            try:
                module = importlib.import_module(info.name)
            except ImportError:
                continue
            for name, obj in vars(module).items():
                # Warnings are not errors; KeyboardInterrupt subclasses (a signal
                # handled like Ctrl-C) are control flow, not failures.
                # Private classes (``_Cancelled``) are control flow inside a module.
                if (inspect.isclass(obj) and issubclass(obj, Exception)
                        and not issubclass(obj, Warning) and obj.__module__ == info.name
                        and not name.startswith("_")):
                    found[f"{info.name}.{name}"] = obj
    return found


EXCEPTIONS = _our_exceptions()


def test_exceptions_were_found():
    assert len(EXCEPTIONS) > 20
    assert "recon.errors.ReconInputError" in EXCEPTIONS


@pytest.mark.parametrize("name", sorted(EXCEPTIONS))
def test_derives_from_the_root(name):
    assert issubclass(EXCEPTIONS[name], DiffuserLabError), (
        f"{name} must derive from diffuserlab.errors.DiffuserLabError (InputError for a "
        "problem the user can fix)")


@pytest.mark.parametrize("name", ["recon.errors.ReconInputError",
                                  "instrument.config.problems.BenchConfigError",
                                  "instrument.acquisition.plan.PlanError",
                                  "instrument.runs.run_integrity.RunStoreError"])
def test_input_errors_are_input_errors(name):
    assert issubclass(EXCEPTIONS[name], InputError)


def test_kept_error_drops_the_tracebacks_of_the_whole_chain():
    from diffuserlab.errors import kept_error

    def fail():
        try:
            raise KeyError("inner")
        except KeyError as inner:
            raise RuntimeError("outer") from inner

    try:
        fail()
    except RuntimeError as exc:
        caught, kept = exc, kept_error(exc)
    assert kept is caught and str(kept) == "outer" and isinstance(kept.__cause__, KeyError)
    assert kept.__traceback__ is None and kept.__cause__.__traceback__ is None
    assert kept.__context__.__traceback__ is None
