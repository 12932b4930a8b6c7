"""The conformance suites live in a helper module; let pytest rewrite its asserts.

The unit locks of the USB drivers (:class:`drivers.device_access.DeviceLock`) go to a
directory of this test process, not the machine's ``/run/lock``: every emulated
LightCrafter has the same serial number, and test processes running side by side
(pytest-xdist workers, other checkouts) would otherwise refuse each other's units.
"""

import atexit
import os
import shutil
import tempfile

import pytest

from drivers.device_access import LOCK_DIR_ENV

pytest.register_assert_rewrite("tests.drivers.conformance")

os.environ[LOCK_DIR_ENV] = _LOCKS = tempfile.mkdtemp(prefix="diffuserlab-locks-")
atexit.register(shutil.rmtree, _LOCKS, ignore_errors=True)
