"""``python -m vamos.client``: the ``vamos-client`` command."""

from vamos._cli import client

raise SystemExit(client())
