"""The studies that measure DiffuserLab, beside the package (not installed).

A lab installs the package to run a bench; these are how the defaults were chosen
and are checked: the reconstruction accuracy and method studies (accuracy against
seconds, stability, erasure, the automatic weights on the scene suites, failure
maps, spatially varying models, blind calibration, mask designs, the 3D studies and
the external 3D comparison). They may import every layer of the package;
``lint-imports`` keeps the package from importing them. The operator's window measured
in a real X session (the operator's day, the soak, responsiveness, screenshots) is the
soak suite beside ``tests/``, ``soak/``. What an operator runs to qualify a machine stays a
``diffuserlab benchmark`` command (:mod:`instrument.benchmarks`).

Run from the repository's root::

    python -m benchmarks [--quick] [--out out/benchmark] [--only NAME] [--overwrite]
    python -m benchmarks.design [--quick] [--out out/benchmark-design] [--overwrite]
"""
