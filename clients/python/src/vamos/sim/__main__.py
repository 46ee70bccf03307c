"""``python -m vamos.sim``: the ``vamos-sim`` command."""

import sys

from vamos.sim.cli import main

sys.exit(main())
