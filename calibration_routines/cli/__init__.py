"""The ``diffuserlab`` commands of the calibration layer: ``calibrate`` and ``align``.

Registered through the entry-point group ``diffuserlab.commands`` (pyproject.toml:
``calibration_routines.cli.calibrate:add_subcommands`` and
``calibration_routines.cli.align:add_subcommands``), so the instrument layer never
imports this one. Each module's parsers carry ``handler=run``, dispatched by
:func:`instrument.cli.main`; :mod:`.common` holds what both share (the bench
arguments, opening the bench, the operator prompt).
"""
