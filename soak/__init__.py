"""The soak suite: the operator's window measured in a real X session (not installed).

Beside ``tests/``: the tests check what the software does; these modules drive the real
``diffuserlab gui`` for minutes or an hour and measure how it holds up. They run from a
checkout (the repository's root on the path, as for ``benchmarks/``); pytest does not
collect them, and their own tests are in ``tests/gui/`` (``test_daymonitor``,
``test_live_soak``, ``test_operator_day_*``, ``test_screenshots``).

- :mod:`soak.operator_day`: the operator's day in the real window, stepped on the
  window's event loop by :mod:`soak.driver` (X input by :mod:`soak.xinput`);
- :mod:`soak.soak`: the day repeated for an hour under Xvfb, with :mod:`soak.daymonitor`
  (memory, threads, stalls; the kernel's per-thread figures from :mod:`soak.kernelstats`);
- :mod:`soak.benchmark`: the responsiveness of the event loop under load;
- :mod:`soak.live_soak`: an hour of live ADMM measured from outside the window;
- :mod:`soak.screenshots`: the documentation's screenshots;
- :mod:`soak.device_jobs`: the bench jobs the tests and the day add to the window's bench.

Run from the repository's root::

    python -m soak.benchmark [--seconds 20] [--method admm:5]
    python -m soak.benchmark soak [--minutes 60] [--emulated]
    python -m soak.live_soak [--minutes 60]
    python -m soak.screenshots OUT_DIR
"""
