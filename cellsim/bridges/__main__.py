"""``python -m cellsim.bridges CONFIG``: the bridge daemon (as ``cellsim bridge CONFIG``)."""

import sys

from cellsim.cli import bridge_main

sys.exit(bridge_main())
