"""``vamos schema``: the JSON Schemas of the files vamos reads, made from the Rust types
that read them, accept every such file the project ships and refuse what vamos refuses.

Each schema is checked (jsonschema, draft 7) against the shipped files: the example
settings, the demo's and the load generator's profiles, the camera descriptions. Then a
misspelt key, a wrong type and an unknown enum value must be refused by the schema and
by vamos itself (``vamos config`` loading the same settings file), so the schema is as
strict as the program. Needs ``VAMOS_BIN``; skipped without it.
"""

from __future__ import annotations

import json
import os
import subprocess
import tomllib
from pathlib import Path
from typing import Any

import pytest

jsonschema = pytest.importorskip("jsonschema")

from _server import ROOT, vamos_bin  # noqa: E402

SHIPPED = {
    "settings": ["deploy/vamos.example.toml"],
    "profile": ["assets/demo/profile.toml", "assets/demo/profile-no-model.toml",
                "benches/load/sim-arm.toml", "benches/load/sim-paper.toml"],
    "camera": ["assets/demo/camera.json", "tests/fixtures/sim/camera.json"],
}


def _schema(file: str) -> Any:
    run = subprocess.run([str(vamos_bin()), "schema", file], capture_output=True, text=True, check=True)
    schema = json.loads(run.stdout)
    jsonschema.Draft7Validator.check_schema(schema)
    return schema


def _load(path: Path) -> Any:
    return tomllib.loads(path.read_text()) if path.suffix == ".toml" else json.loads(path.read_text())


@pytest.mark.parametrize("file", sorted(SHIPPED))
def test_every_shipped_file_conforms(file: str) -> None:
    validator = jsonschema.Draft7Validator(_schema(file))
    for name in SHIPPED[file]:
        errors = [e.message for e in validator.iter_errors(_load(ROOT / name))]
        assert not errors, (name, errors)
    # The descriptions are the types' doc comments.
    assert _schema(file).get("description") or _schema(file).get("properties")


def _vamos_config(path: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
    return subprocess.run([str(vamos_bin()), "--config", str(path), "config"], capture_output=True, text=True,
                          env=env)


@pytest.mark.parametrize("change", ["misspelt key", "wrong type", "unknown value"])
def test_the_schema_refuses_what_vamos_refuses(change: str, tmp_path: Path) -> None:
    validator = jsonschema.Draft7Validator(_schema("settings"))
    text = (ROOT / "deploy" / "vamos.example.toml").read_text()
    good = tmp_path / "good.toml"
    good.write_text(text)
    assert _vamos_config(good).returncode == 0
    bad = {
        "misspelt key": "[service]\nmax_sesions = 4\n",
        "wrong type": "[service]\nmax_sessions = \"four\"\n",
        "unknown value": "[log]\nformat = \"xml\"\n",
    }[change]
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    assert list(validator.iter_errors(tomllib.loads(bad))), f"the schema accepts {bad!r}"
    run = _vamos_config(path)
    assert run.returncode != 0, f"vamos accepts {bad!r}: {run.stdout}"
