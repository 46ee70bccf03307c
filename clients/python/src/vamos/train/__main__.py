"""``python -m vamos.train``: the ``vamos-train`` command."""

from vamos._cli import train

raise SystemExit(train())
