"""The package is typed (``py.typed``) and ``mypy`` finds nothing with the strict
configuration of pyproject.toml."""

from __future__ import annotations

import os
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


def test_mypy_is_clean_on_the_ros_package() -> None:
    """clients/ros2/vamos_bridge's Python (rclpy and the message packages are untyped
    where ROS is not installed), with the same configuration."""
    pytest.importorskip("mypy", reason="mypy is in the test extra")
    bridge = PACKAGE.parent / "ros2" / "vamos_bridge" / "vamos_bridge"
    run = subprocess.run([sys.executable, "-m", "mypy", "--no-incremental", str(bridge)], cwd=PACKAGE,
                         capture_output=True, text=True, timeout=600,
                         env={**os.environ, "MYPYPATH": str(PACKAGE / "src")})
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.startswith("Success: no issues found in 6 source files")
