"""``scripts/compare_suites.py``: two runs of the test suite compared test by test, from
the JUnit XML that pytest itself writes (docs/architecture.md, "The test suite before
and after the move")."""

from __future__ import annotations

import subprocess
import sys

from scripts.compare_suites import compare, main, outcomes

_TESTS = '''
import pytest

def test_a():
    pass

@pytest.mark.parametrize("k", [1, 2])
def test_b(k):
    assert k == 1 or {flip}

def test_c():
    pytest.skip("no camera")

class TestD:
    def test_e(self):
        pass

@pytest.fixture
def broken():
    yield
    raise RuntimeError("teardown")

def test_f(broken):
    pass
{extra}
'''


def _report(tmp_path, name: str, flip: bool, extra: str = "") -> str:
    """Run pytest on a small test module in ``tmp_path/name/tests/`` and return the path
    of its JUnit XML report."""
    root = tmp_path / name
    (root / "tests").mkdir(parents=True)
    (root / "tests" / "test_mod.py").write_text(_TESTS.format(flip=flip, extra=extra))
    xml = root / "report.xml"
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                    "-p", "no:randomly", f"--junitxml={xml}", "tests"], cwd=root,
                   capture_output=True, text=True, timeout=600)
    return str(xml)


def test_outcomes_read_from_pytests_own_report(tmp_path):
    got = outcomes(_report(tmp_path, "one", flip=False))
    assert got == {"tests/test_mod.py::test_a": "passed",
                   "tests/test_mod.py::test_b[1]": "passed",
                   "tests/test_mod.py::test_b[2]": "failed",
                   "tests/test_mod.py::test_c": "skipped",
                   "tests/test_mod.py::TestD::test_e": "passed",
                   "tests/test_mod.py::test_f": "error"}  # passed, then its teardown failed


def test_a_changed_outcome_and_tests_on_one_side(tmp_path, capsys):
    before = _report(tmp_path, "before", flip=False)
    after = _report(tmp_path, "after", flip=True, extra="\ndef test_new():\n    pass\n")
    res = compare(outcomes(before), outcomes(after))
    assert res["changed"] == [("tests/test_mod.py::test_b[2]", "failed", "passed")]
    assert res["only_after"] == ["tests/test_mod.py::test_new"]
    assert res["only_before"] == [] and res["same"] == 5
    assert main([before, after]) == 1
    out = capsys.readouterr().out
    assert "test_b[2]: failed -> passed" in out and "only after: 1" in out
    assert main([before, before]) == 0
    assert main([before, str(tmp_path / "missing.xml")]) == 2
