"""The docs name paths that exist: every path in the first column of the README's
Layout section, and every relative link of the READMEs of clients/ and proto/."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def layout_paths(readme: str) -> list[str]:
    section = readme[readme.index("## Layout\n"):]
    block = section[section.index("```\n") + 4:]
    block = block[:block.index("```")]
    paths = []
    for line in block.splitlines():
        if not line or line.startswith(" "):
            continue  # a description's continuation
        column = re.split(r"\s{2,}", line, maxsplit=1)[0]
        paths += [p.strip() for p in column.split(",")]
    return paths


def test_every_layout_path_exists() -> None:
    paths = layout_paths((ROOT / "README.md").read_text())
    assert len(paths) > 30
    missing = [p for p in paths if not (ROOT / p).exists()]
    assert not missing, f"README's Layout names paths that do not exist: {missing}"
    # Directories are written with a trailing slash, files without.
    wrong = [p for p in paths if p.endswith("/") != (ROOT / p).is_dir()]
    assert not wrong, wrong


def test_layout_paths_are_checked_for_real() -> None:
    text = "## Layout\n```\nsrc/main.rs, no/such/file.rs   x\n    continued\nREADME.md   y\n```\n"
    assert layout_paths(text) == ["src/main.rs", "no/such/file.rs", "README.md"]
    assert not (ROOT / "no/such/file.rs").exists()


@pytest.mark.parametrize("doc", ["clients/README.md", "clients/ros2/README.md", "clients/python/README.md",
                                 "proto/README.md"])
def test_relative_links_resolve(doc: str) -> None:
    path = ROOT / doc
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", path.read_text())
    local = [link for link in links if "://" not in link]
    missing = [link for link in local if not (path.parent / link).exists()]
    assert not missing, f"{doc} links to missing {missing}"
