"""Every console script answers ``--version``, and every argument and sub-command of
every parser has help text."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest

import vamos
from vamos._cli import missing_extra_message, run

SRC = Path(__file__).resolve().parents[1] / "src"


def _walk(parser: argparse.ArgumentParser, path: str) -> Iterator[tuple[str, argparse.Action]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helped = {a.dest for a in action._choices_actions if a.help}
            for name, sub in action.choices.items():
                assert name in helped, f"{path} {name}: sub-command without help"
                yield from _walk(sub, f"{path} {name}")
        else:
            yield path, action


def _parsers() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    from vamos.client.cli import build_parser as client
    from vamos.train.cli import build_parser as train

    yield "vamos-client", client()
    yield "vamos-train", train()
    try:
        from vamos.sim.cli import build_parser as sim
    except ModuleNotFoundError:  # the sim extra is not installed
        return
    yield "vamos-sim", sim()


@pytest.mark.parametrize("name", ["vamos-client", "vamos-train", "vamos-sim"])
def test_every_argument_and_sub_command_has_help(name: str) -> None:
    parsers = dict(_parsers())
    if name not in parsers:
        pytest.skip("the sim extra is not installed")
    missing = [f"{path}: {a.option_strings or a.dest}" for path, a in _walk(parsers[name], name)
               if not a.help or a.help == argparse.SUPPRESS]
    assert not missing, missing
    flags = {s for _, a in _walk(parsers[name], name) for s in a.option_strings}
    assert "--version" in flags


@pytest.mark.parametrize("module", ["vamos.client", "vamos.train", "vamos.sim"])
def test_version_answers_without_the_extras(module: str) -> None:
    # `python -m vamos.X --version` goes through the same entry point as the script.
    run_ = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True,
                          env={"PYTHONPATH": str(SRC)}, timeout=60)
    assert run_.returncode == 0, run_.stderr
    assert run_.stdout == f"vamos-{module.split('.')[1]} {vamos.__version__}\n"


def test_a_missing_extra_is_one_line_naming_it(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    # A module of the extra that cannot be there: the same path as a missing pybullet.
    (tmp_path / "needs_extra.py").write_text("import pybullet_utils.not_a_module\n\ndef main(argv):\n    return 0\n")
    sys.path.insert(0, str(tmp_path))
    try:
        assert run("vamos-sim", "sim", "needs_extra", ["generate"]) == 2
    finally:
        sys.path.remove(str(tmp_path))
    err = capsys.readouterr().err
    assert err == missing_extra_message("vamos-sim", "sim", "pybullet_utils") + "\n"
    assert err.count("\n") == 1 and "pip install 'vamos-client[sim]'" in err and "Traceback" not in err
    # A missing module that belongs to no extra is a bug, and is not hidden.
    (tmp_path / "broken.py").write_text("import no_such_module_anywhere\n")
    sys.path.insert(0, str(tmp_path))
    try:
        with pytest.raises(ModuleNotFoundError):
            run("vamos-sim", "sim", "broken", [])
    finally:
        sys.path.remove(str(tmp_path))
