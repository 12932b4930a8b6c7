"""``python -m instrument.cli``: the ``diffuserlab`` command."""

import sys

from . import main, startup_signals

status = main()
startup_signals.forget_unhandled_interrupt()  # the chosen status, not exit -2 (its docstring)
sys.exit(status)
