"""The Examples sections of the public docstrings run as doctests (they are what a
reader copies first, so they must stay true)."""

import doctest
import importlib

import pytest

#: Modules whose docstrings carry Examples (keep in step with the API reference).
MODULES = ("diffuserlab.jsonio", "instrument.atomic", "recon.operators",
           "recon.metrics", "recon.live", "benchmarks.report", "recon.api", "recon.solvers.admm",
           "recon.solvers.gradient", "instrument.acquisition.shared_slot", "recon.priors.base",
           "recon.priors.wavelet", "recon.priors.dncnn", "recon.priors.tv_iso",
           "recon.priors.tgv")


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [t for t in finder.find(module) if t.examples]
    assert tests, f"{name} has no docstring Examples"
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
