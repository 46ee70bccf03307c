"""``python -m vamos.train``: same as the ``vamos-train`` command."""

from vamos.train.cli import main

raise SystemExit(main())
