"""The conformance suites live in a helper module; let pytest rewrite its asserts."""

import pytest

pytest.register_assert_rewrite("tests.drivers.conformance")
