"""``python -m instrument.cli``: the ``diffuserlab`` command."""

import sys

from . import main

sys.exit(main())
