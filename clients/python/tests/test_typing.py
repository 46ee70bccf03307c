"""The package is typed (``py.typed``) and ``mypy`` finds nothing with the strict
configuration of pyproject.toml."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1]


def test_the_package_says_it_is_typed() -> None:
    assert (PACKAGE / "src" / "vamos" / "py.typed").is_file()
    assert '"py.typed"' in (PACKAGE / "pyproject.toml").read_text()


def test_mypy_is_clean() -> None:
    pytest.importorskip("mypy", reason="mypy is in the test extra")
    run = subprocess.run([sys.executable, "-m", "mypy", "--no-incremental"], cwd=PACKAGE, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.startswith("Success: no issues found")
