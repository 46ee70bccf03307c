"""``python -m vamos.sim``: the ``vamos-sim`` command."""

from vamos._cli import sim

raise SystemExit(sim())
