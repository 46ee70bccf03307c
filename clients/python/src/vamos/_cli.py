"""The console scripts' entry points: ``--version`` everywhere, and a one-line message
naming the extra to install when a command needs one that is missing (no traceback).

``vamos-client`` needs only the package's own dependencies; ``vamos-sim`` needs the
``sim`` extra and ``vamos-train`` the ``train`` extra. The extras' modules are imported
only by the command that needs them, so a missing one is found either when the command's
module loads or when its work starts; both end here, with exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Callable, Optional, Sequence

from vamos import __version__

#: The distribution's name on the package index (``pip install 'vamos-client[sim]'``).
DISTRIBUTION = "vamos-client"

#: The top-level modules each extra brings, as imported.
EXTRA_MODULES: dict[str, frozenset[str]] = {
    "sim": frozenset({"pybullet", "pybullet_utils", "numpy", "tqdm", "mcap", "mcap_ros2"}),
    "train": frozenset({"torch", "numpy", "tqdm", "onnx", "onnxruntime"}),
    # The client's dependencies are the package's own; this only catches a broken install.
    "": frozenset({"grpc", "google", "httpx", "mcap", "mcap_ros2"}),
}


def add_version(parser: argparse.ArgumentParser) -> None:
    """``--version``: prints ``PROG VERSION`` and exits 0."""
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                        help="print the version and exit")


def missing_extra_message(prog: str, extra: str, module: str) -> str:
    """The one line printed when ``module`` of ``extra`` is not installed."""
    target = f"{DISTRIBUTION}[{extra}]" if extra else DISTRIBUTION
    return (f"{prog}: error: this command needs the '{extra or 'base'}' dependencies (module {module!r} is not "
            f"installed): pip install '{target}'")


def run(prog: str, extra: str, module: str, argv: Optional[Sequence[str]] = None) -> int:
    """Imports ``module`` and runs its ``main(argv)``; a missing module of ``extra`` is
    reported in one line on stderr (exit status 2)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args == ["--version"]:
        # Answered before anything heavy is imported, so it works without the extra.
        print(f"{prog} {__version__}")
        return 0
    try:
        main: Callable[[list[str]], int] = importlib.import_module(module).main
        return main(args)
    except ModuleNotFoundError as e:
        root = (e.name or "").split(".")[0]
        if root not in EXTRA_MODULES[extra]:
            raise
        print(missing_extra_message(prog, extra, root), file=sys.stderr)
        return 2


def client() -> int:
    """``vamos-client``."""
    return run("vamos-client", "", "vamos.client.cli")


def sim() -> int:
    """``vamos-sim``."""
    return run("vamos-sim", "sim", "vamos.sim.cli")


def train() -> int:
    """``vamos-train``."""
    return run("vamos-train", "train", "vamos.train.cli")
