"""The docs say what exists.

- Every path in the first column of the README's Layout section exists.
- Every relative link of the README, of ``docs/*.md`` and of the other READMEs and guides
  resolves: the file exists, and a ``#anchor`` into a Markdown file names one of its
  headings (GitHub's anchor rules).
- Every command the README and ``docs/*.md`` show is one the programs accept: for each
  ``vamos ...`` line of their shell blocks and inline code (continuations, ``$(...)``,
  pipes, environment prefixes and comments read as a shell reads them), the sub-command
  path exists and every option it uses is in that sub-command's ``--help`` (``VAMOS_BIN``,
  the release binary; skipped without it), and a whole command line of a shell block has
  the options its usage line requires. The same for ``vamos-sim``, ``vamos-train`` and
  ``vamos-client`` (this package's console scripts, through their ``--help``); a script
  of the repository that a command runs exists. Negative controls show each check failing.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import pytest

ROOT = Path(__file__).resolve().parents[3]

#: The Markdown files whose commands are checked: the README and the docs folder.
COMMAND_DOCS = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]

#: The Markdown files whose relative links (and anchors) are checked.
LINK_DOCS = [*COMMAND_DOCS, "ARCHITECTURE.md", "SECURITY.md", "benches/README.md", "deploy/README.md",
             "fuzz/README.md", "assets/demo/README.md", "clients/README.md", "clients/ros2/README.md",
             "clients/python/README.md", "proto/README.md"]

#: Fenced blocks with these info strings hold shell commands (an untagged block counts:
#: output and other text is tagged, e.g. ``text``).
SHELL_LANGUAGES = {"", "sh", "bash", "shell", "console"}

#: The console scripts of this package: program -> entry point in ``vamos._cli``.
PYTHON_PROGRAMS = {"vamos-sim": "sim", "vamos-train": "train", "vamos-client": "client"}


# --- Markdown -------------------------------------------------------------------------------

@dataclass
class Block:
    """A fenced code block: its info string, body (indentation of the fence removed) and
    the line of its opening fence (1-based)."""

    language: str
    body: str
    line: int


FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([^\s`]*)[^`]*$")


def split_markdown(text: str) -> tuple[list[Block], str]:
    """The fenced code blocks of ``text``, and ``text`` with each block's lines blanked
    (so prose searches neither see code nor lose line numbers)."""
    blocks: list[Block] = []
    prose: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            prose.append(lines[i])
            i += 1
            continue
        indent, fence, language = len(m.group(1)), m.group(2), m.group(3).lower()
        start = i
        body: list[str] = []
        i += 1
        while i < len(lines) and not re.match(rf"^\s*{re.escape(fence[0])}{{{len(fence)},}}\s*$", lines[i]):
            line = lines[i]
            body.append(line[indent:] if line[:indent].strip() == "" else line.lstrip())
            i += 1
        blocks.append(Block(language, "\n".join(body), start + 1))
        prose.extend([""] * (i + 1 - start))
        i += 1
    return blocks, "\n".join(prose[:len(lines)])


def headings(text: str) -> list[str]:
    """The ATX headings outside code blocks, in order."""
    _, prose = split_markdown(text)
    return [m.group(1) for m in re.finditer(r"^#{1,6}[ \t]+(.*?)[ \t]*#*[ \t]*$", prose, re.MULTILINE)]


def github_anchor(heading: str) -> str:
    """GitHub's anchor of a heading (before de-duplication): the rendered text (links and
    code marks removed) in lower case, without punctuation but hyphens and underscores,
    spaces as hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"<[^>]+>", "", text).lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every anchor GitHub gives the headings of ``text`` (repeated ones get ``-1``,
    ``-2``, ...), and the ``id``/``name`` of any HTML anchor."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    for heading in headings(text):
        base = github_anchor(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    out.update(re.findall(r"<a\s+(?:id|name)=\"([^\"]+)\"", text))
    return out


def without_inline_code(prose: str) -> str:
    """``prose`` with its inline code spans blanked."""
    return re.sub(r"(`+)(?!`).*?(?<!`)\1(?!`)", lambda m: " " * len(m.group(0)), prose, flags=re.DOTALL)


def relative_links(text: str) -> list[str]:
    """The link targets of ``text`` (inline links, images, reference definitions) that are
    not URLs, outside code."""
    _, prose = split_markdown(text)
    prose = without_inline_code(prose)
    targets = re.findall(r"\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)", prose)
    targets += re.findall(r"^\s*\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", prose, re.MULTILINE)
    return [t for t in targets if not re.match(r"^[a-zA-Z][\w+.-]*:", t)]


def broken_links(doc: Path) -> list[str]:
    """The relative links of ``doc`` whose file is missing or whose anchor is not a heading
    of the Markdown file it points into, each with the reason."""
    broken = []
    for target in relative_links(doc.read_text()):
        path_part, _, anchor = target.partition("#")
        dest = (doc.parent / path_part).resolve() if path_part else doc
        if not dest.exists():
            broken.append(f"{target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest.read_text()):
            broken.append(f"{target} (no heading with anchor #{anchor} in {display(dest)})")
    return broken


def display(path: Path) -> str:
    """``path`` relative to the repository where it is inside it."""
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path.resolve())


# --- Commands in the docs --------------------------------------------------------------------

@dataclass
class Command:
    """One command of a doc: the program and its arguments as a shell would pass them
    (brackets of optional parts removed), and where it was found."""

    program: str
    args: list[str]
    where: str
    words: list[str] = field(default_factory=list)
    #: A whole command line (of a shell block), not a mention in prose: its required options
    #: must be there too.
    complete: bool = False


def logical_lines(body: str) -> list[str]:
    """Shell lines with ``\\`` continuations joined and a ``$ `` prompt removed."""
    out: list[str] = []
    pending = ""
    for line in body.splitlines():
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        out.append(pending + line)
        pending = ""
    if pending:
        out.append(pending)
    return [re.sub(r"^\s*\$\s+", "", line) for line in out]


def strip_comment(line: str) -> str:
    """``line`` up to a shell comment (a ``#`` starting a word, outside quotes)."""
    quote = ""
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i]
    return line


def substitutions(line: str) -> tuple[str, list[str]]:
    """``line`` with each ``$(...)`` replaced by a placeholder word, and the commands
    inside them (nested ones too)."""
    inner: list[str] = []
    out = []
    i = 0
    while i < len(line):
        if line.startswith("$(", i):
            depth, j = 1, i + 2
            while j < len(line) and depth:
                depth += {"(": 1, ")": -1}.get(line[j], 0)
                j += 1
            body = line[i + 2:j - 1]
            rest, nested = substitutions(body)
            inner += [rest, *nested]
            out.append("SUBSTITUTED")
            i = j
        else:
            out.append(line[i])
            i += 1
    return "".join(out), inner


def split_pipeline(line: str) -> list[str]:
    """The simple commands of a line: split at ``|``, ``||``, ``&&``, ``;`` and ``&``
    outside quotes and outside the ``[...]`` of a usage line's optional parts."""
    parts, current, quote, depth = [], "", "", 0
    i = 0
    while i < len(line):
        ch = line[i]
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "[" and (i == 0 or line[i - 1].isspace() or line[i - 1] == "["):
            depth += 1
        elif ch == "]" and depth:
            depth -= 1
        elif depth == 0 and ch in "|;&":
            # `2>&1` and `&>` are redirections, not separators.
            if ch == "&" and (line[i - 1:i] == ">" or line[i + 1:i + 2] == ">"):
                current += ch
                i += 1
                continue
            parts.append(current)
            current = ""
            while i + 1 < len(line) and line[i + 1] in "|&":
                i += 1
            i += 1
            continue
        current += ch
        i += 1
    parts.append(current)
    return [p.strip() for p in parts if p.strip()]


def words_of(simple: str) -> list[str]:
    """The words of a simple command: shell-split, redirections and the ``[``/``]`` and
    ``|`` of optional parts removed."""
    try:
        raw = shlex.split(simple)
    except ValueError:  # an unbalanced quote: split on blanks
        raw = simple.split()
    words: list[str] = []
    skip = False
    for w in raw:
        if skip:
            skip = False
            continue
        if re.fullmatch(r"\d?(>>?|<)(&\d)?", w) or w == "&>":
            skip = not w.endswith(("&1", "&2"))
            continue
        if re.match(r"^\d?(>>?|<)\S", w):
            continue  # `>file`, `2>/dev/null`
        w = w.strip("[]")
        if w and w != "|":
            words.append(w)
    return words


def command_of(words: list[str], where: str) -> Optional[Command]:
    """The command ``words`` run, when it is one this test knows: ``vamos`` (also as
    ``cargo run --release -- ...`` or ``target/release/vamos``), a console script of this
    package, or a script of the repository."""
    while words and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", words[0]):
        words = words[1:]  # environment assignments
    if words[:1] == ["env"]:
        return command_of(words[1:], where)
    if not words:
        return None
    program = words[0]
    if program in ("vamos", "./vamos") or re.fullmatch(r"(\./)?target/(release|debug)/vamos", program):
        return Command("vamos", words[1:], where, words)
    if words[:2] == ["cargo", "run"] and "--" in words:
        before = words[:words.index("--")]
        if not any(w in ("--example", "--bench", "--bin", "-p", "--package") for w in before):
            return Command("vamos", words[words.index("--") + 1:], where, words)
        return None
    if program in PYTHON_PROGRAMS:
        return Command(program, words[1:], where, words)
    if program in ("python", "python3") and len(words) > 1 and words[1].endswith(".py"):
        return Command("script", [words[1]], where, words)
    if "/" in program and not program.startswith(("/", "~", "$")) and re.search(r"\.(sh|py)$", program):
        return Command("script", [program], where, words)
    return None


def commands_in(text: str, doc: str) -> list[Command]:
    """Every command of ``text``: in its shell blocks and in inline code spans that are a
    command of a known program."""
    blocks, prose = split_markdown(text)
    found: list[Command] = []

    def add_line(line: str, where: str, complete: bool) -> None:
        line, inner = substitutions(strip_comment(line))
        for part in [line, *inner]:
            for simple in split_pipeline(part):
                cmd = command_of(words_of(simple), where)
                if cmd:
                    cmd.complete = complete
                    found.append(cmd)

    for block in blocks:
        if block.language not in SHELL_LANGUAGES:
            continue
        for line in logical_lines(block.body):
            add_line(line, f"{doc}, block at line {block.line}: {line.strip()}", True)
    for m in re.finditer(r"(?<!`)`([^`]+)`(?!`)", prose):
        span = " ".join(m.group(1).split())
        first = [w for w in span.split() if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", w)][:1]
        if first and (first[0] in ("vamos", "python", "python3", *PYTHON_PROGRAMS)
                      or first[0].startswith("scripts/")):
            if " " not in span and first[0] == span:
                continue  # a program named, not run (`vamos-sim`)
            line_no = prose.count("\n", 0, m.start()) + 1
            add_line(span, f"{doc}, line {line_no}: `{span}`", False)
    return found


# --- What the programs accept ----------------------------------------------------------------

@dataclass
class Help:
    """What a (sub-)command's help says it accepts."""

    subcommands: list[str]
    options: set[str]
    #: The options that take a value (the word after them is not a sub-command).
    valued: set[str] = field(default_factory=set)
    #: The required options of the usage line: each set is satisfied by any one of its names.
    required: list[set[str]] = field(default_factory=list)
    #: Each option's other names (`-o` and `--out`, aliases).
    synonyms: dict[str, set[str]] = field(default_factory=dict)


def parse_help(text: str) -> Help:
    """Sub-commands and options of a clap or argparse help text.

    Options are the ``-x``/``--name`` words that start an option line (before its
    description), plus clap's ``[aliases: ...]``. Sub-commands are clap's ``Commands:``
    list, or argparse's choices indented under a ``COMMAND``/``{a,b}`` positional."""
    options: set[str] = set()
    valued: set[str] = set()
    subcommands: list[str] = []
    lines = text.splitlines()
    synonyms: dict[str, set[str]] = {}
    takes_value = False  # whether the option defined last takes a value (its aliases do too)
    group: set[str] = set()  # the names of the option defined last
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("-"):
            head = re.split(r"\s{2,}", stripped, maxsplit=1)[0]
            names = re.findall(r"(?<![\w-])(--?[A-Za-z0-9][\w-]*)", head)
            if names:
                options.update(names)
                group = set(names)
                for name in names:
                    synonyms[name] = group
                # `--out <OUT>` (clap), `-o OUT, --out OUT` or `--kind {a,b}` (argparse).
                takes_value = bool(re.search(r"(?<!\[)<[^>]+>|(?<![\w-])[A-Z][A-Z0-9_]*\b|\{[^}]*\}", head))
                if takes_value:
                    valued.update(names)
        for aliases in re.findall(r"\[(?:short )?aliases?: ([^\]]+)\]", line):
            names = [a.strip() for a in aliases.split(",")]
            options.update(names)
            group.update(names)
            for name in names:
                synonyms[name] = group
            if takes_value:
                valued.update(names)
    if "Commands:" in lines:
        for line in lines[lines.index("Commands:") + 1:]:
            m = re.match(r"^  (\S+)", line)
            if not m:
                break
            subcommands.append(m.group(1))
    else:
        under = False
        for line in lines:
            if re.fullmatch(r"  (\{[^}]*\}|[A-Z][A-Z_]*)\s*", line):
                under = True
                continue
            m = re.match(r"^    ([\w-]+)(?:\s{2,}|$)", line)
            if under and m:
                subcommands.append(m.group(1))
            elif under and not line.startswith("     "):
                under = False
    return Help([s for s in subcommands if s != "help"], options, valued, required_options(text), synonyms)


def required_options(text: str) -> list[set[str]]:
    """The options a usage line requires: those outside its ``[...]`` parts, each alone or,
    in an argparse ``(--a | --b)`` group, any one of the group."""
    m = re.search(r"^(?:Usage|usage): (.*?)(?:\n\s*\n|\Z)", text, re.DOTALL | re.MULTILINE)
    if not m:
        return []
    usage = " ".join(m.group(1).split())
    previous = None
    while previous != usage:  # optional parts, innermost first
        previous, usage = usage, re.sub(r"\[[^\[\]]*\]", "", usage)
    option = r"(?<![\w<-])(--?[A-Za-z][\w-]*)"
    groups = [set(re.findall(option, g)) for g in re.findall(r"\(([^()]*)\)", usage)]
    usage = re.sub(r"\([^()]*\)", "", usage)
    return [g for g in groups if g] + [{o} for o in re.findall(option, usage)]


class Programs:
    """Runs ``PROGRAM SUB... --help`` once per sub-command path."""

    def __init__(self, vamos_bin: Optional[str]) -> None:
        self.vamos_bin = vamos_bin
        self._helps: dict[tuple[str, tuple[str, ...]], Help] = {}

    def argv(self, program: str) -> Optional[list[str]]:
        if program == "vamos":
            return [self.vamos_bin] if self.vamos_bin else None
        entry = PYTHON_PROGRAMS[program]
        return [sys.executable, "-c", f"import sys; from vamos._cli import {entry}; sys.exit({entry}())"]

    def help(self, program: str, path: tuple[str, ...]) -> Help:
        if (program, path) not in self._helps:
            self._helps[(program, path)] = self._read_help(program, path)
        return self._helps[(program, path)]

    def _read_help(self, program: str, path: tuple[str, ...]) -> Help:
        argv = self.argv(program)
        assert argv is not None
        proc = subprocess.run([*argv, *path, "--help"], capture_output=True, text=True, timeout=120,
                              env={**os.environ, "NO_COLOR": "1", "COLUMNS": "200"})
        if proc.returncode != 0:
            if "dependencies (module" in proc.stderr:
                pytest.skip(f"{program}'s extra is not installed: {proc.stderr.strip()}")
            raise LookupError(f"`{program} {' '.join(path)} --help` failed: {proc.stderr.strip()[:300]}")
        return parse_help(proc.stdout)


def problems_of(cmd: Command, programs: Programs) -> list[str]:
    """What is wrong with ``cmd``: an unknown sub-command, an option its sub-command does
    not take, a script that does not exist."""
    if cmd.program == "script":
        return [] if (ROOT / cmd.args[0]).exists() else [f"{cmd.where}: no such script {cmd.args[0]}"]
    if programs.argv(cmd.program) is None:
        return []
    path: list[str] = []
    args = list(cmd.args)
    if "--" in args:
        args = args[:args.index("--")]
    help_ = programs.help(cmd.program, ())
    i = 0
    # Descend through the sub-commands (options before a sub-command belong to its parent).
    while i < len(args) and help_.subcommands:
        word = args[i]
        if word.startswith("-"):
            if not _option_known(word, help_):
                return [f"{cmd.where}: `{cmd.program} {' '.join(path)}` has no option {word.split('=')[0]}"]
            i += 2 if word in help_.valued else 1  # `--server URL`: URL is not a sub-command
            continue
        if word not in help_.subcommands:
            return [f"{cmd.where}: `{cmd.program} {' '.join(path)}` has no sub-command {word!r} "
                    f"(it has {', '.join(help_.subcommands)})"]
        path.append(word)
        help_ = programs.help(cmd.program, tuple(path))
        i += 1
    used = [w.split("=")[0] for w in args[i:] if re.match(r"^--?[A-Za-z]", w)]
    unknown = [w for w in used if not _option_known(w, help_)]
    problems = [f"{cmd.where}: `{cmd.program} {' '.join(path)}` has no option {w}" for w in unknown]
    if cmd.complete and not help_.subcommands:
        given = {name for w in used for name in help_.synonyms.get(w, {w})}
        for need in help_.required:
            if not need & given:
                problems.append(f"{cmd.where}: `{cmd.program} {' '.join(path)}` needs {' or '.join(sorted(need))}")
    return problems


def _option_known(word: str, help_: Help) -> bool:
    name = word.split("=")[0]
    if re.fullmatch(r"-[A-Za-z]{2,}", name):  # combined short flags: -abc
        return all(f"-{c}" in help_.options for c in name[1:])
    return name in help_.options


# --- Tests -------------------------------------------------------------------------------------

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


def test_the_readme_names_the_test_command_ci_runs() -> None:
    # .ci/run greps README.md for it.
    assert "scripts/test.sh" in (ROOT / "README.md").read_text()


@pytest.mark.parametrize("doc", LINK_DOCS)
def test_relative_links_resolve(doc: str) -> None:
    path = ROOT / doc
    if not path.exists():
        pytest.skip(f"{doc} does not exist")
    broken = broken_links(path)
    assert not broken, f"{doc} has broken links: {broken}"


def test_the_link_check_can_fail(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# Other\n\n## The load users run (issue 43, 2026-12-07)\n\n"
                                       "```sh\n# Not a heading\n```\n\n## Twice\n\n## Twice\n")
    doc = tmp_path / "doc.md"
    doc.write_text("# Doc\n\n## `e_o`, localised: 50% & more\n\n"
                   "[ok](other.md#the-load-users-run-issue-43-2026-12-07) [ok](other.md#twice-1) "
                   "[ok](#e_o-localised-50--more) ![img](other.md)\n"
                   "[gone](missing.md) [bad anchor](other.md#not-a-heading) [bad](#nowhere) "
                   "[second twice](other.md#twice-2) [web](https://example.com/x.md#y)\n"
                   "`[in code](missing-too.md)`\n\n[ref]: missing-ref.md\n")
    assert broken_links(doc) == [
        "missing.md (no such file)",
        f"other.md#not-a-heading (no heading with anchor #not-a-heading in {display(tmp_path / 'other.md')})",
        f"#nowhere (no heading with anchor #nowhere in {display(doc)})",
        f"other.md#twice-2 (no heading with anchor #twice-2 in {display(tmp_path / 'other.md')})",
        "missing-ref.md (no such file)",
    ]


def test_commands_are_found_as_a_shell_reads_them() -> None:
    text = (
        "Run `vamos demo --robots 2` or `vamos-sim`; `vamos::client` is a path.\n\n"
        "```sh\n"
        "# vamos comment --not-checked\n"
        "VAMOS_LOG__FORMAT=json vamos serve --profile p.toml   # trailing --comment\n"
        "vamos flow a.png b.png -o f.png [--preset default|realtime] \\\n"
        "    [--threads N] | tee log 2>&1 && echo \"$(vamos config --config x.toml)\"\n"
        "cargo run --release -- demo --no-model > out.txt\n"
        "cargo run --release --example render_time -- 100000\n"
        "scripts/test.sh; python3 tests/fixtures/x.py\n"
        "vamos stream e.mcap [--speed 2 | --fast [--window 4] | --batch]\n"
        "```\n\n"
        "```text\nvamos demo: server on http://127.0.0.1:1\n```\n"
    )
    got = [(c.program, c.args) for c in commands_in(text, "t.md")]
    assert got == [
        ("vamos", ["serve", "--profile", "p.toml"]),
        ("vamos", ["flow", "a.png", "b.png", "-o", "f.png", "--preset", "default|realtime", "--threads", "N"]),
        ("vamos", ["config", "--config", "x.toml"]),
        ("vamos", ["demo", "--no-model"]),
        ("script", ["scripts/test.sh"]),
        ("script", ["tests/fixtures/x.py"]),
        ("vamos", ["stream", "e.mcap", "--speed", "2", "--fast", "--window", "4", "--batch"]),
        ("vamos", ["demo", "--robots", "2"]),
    ]


def test_help_texts_are_parsed() -> None:
    clap = ("Usage: vamos render [OPTIONS] --output <OUTPUT> <A>\n\nCommands:\n  demo   The main job\n"
            "  help   Print this\n\nOptions:\n  -o, --output <OUTPUT>\n          Where - not --this\n"
            "      --raw <RAW>  [aliases: --flo]\n      --quiet\n")
    clap_help = parse_help(clap)
    assert clap_help.subcommands == ["demo"]
    assert clap_help.options == {"-o", "--output", "--raw", "--flo", "--quiet"}
    assert clap_help.valued == {"-o", "--output", "--raw", "--flo"}
    assert clap_help.required == [{"--output"}]
    assert clap_help.synonyms["-o"] == {"-o", "--output"} and clap_help.synonyms["--flo"] == {"--raw", "--flo"}
    argparse_help = ("usage: vamos-sim [-h] -o OUT [--rate RATE | --fast]\n"
                     "                 (--a A | --b) COMMAND ...\n\n"
                     "positional arguments:\n  COMMAND\n    generate  generate a dataset\n    other\n\n"
                     "options:\n  -h, --help  show this\n  -o OUT, --out OUT  output folder\n"
                     "  --channels-last, --no-channels-last\n")
    argparse_parsed = parse_help(argparse_help)
    assert argparse_parsed.subcommands == ["generate", "other"]
    assert argparse_parsed.options == {"-h", "--help", "-o", "--out", "--channels-last", "--no-channels-last"}
    assert argparse_parsed.valued == {"-o", "--out"}
    assert argparse_parsed.required == [{"--a", "--b"}, {"-o"}]


def vamos_bin() -> str:
    path = os.environ.get("VAMOS_BIN")
    if not path or not Path(path).exists():
        pytest.skip("VAMOS_BIN is not set to the vamos binary")
    return path


@pytest.mark.parametrize("doc", COMMAND_DOCS)
def test_every_command_of_the_docs_is_accepted(doc: str) -> None:
    programs = Programs(vamos_bin())
    cmds = commands_in((ROOT / doc).read_text(), doc)
    problems = [p for cmd in cmds for p in problems_of(cmd, programs)]
    assert not problems, "commands the programs do not accept:\n" + "\n".join(problems)


def test_the_readme_shows_commands_and_they_are_checked() -> None:
    programs = Programs(vamos_bin())
    cmds = commands_in((ROOT / "README.md").read_text(), "README.md")
    checked = {c.args[0] for c in cmds if c.program == "vamos" and c.args}
    # The quick start's main job and the sub-commands a newcomer meets first are in it.
    assert {"demo", "serve", "score", "calibrate", "eval", "profile"} <= checked, checked
    assert {c.program for c in cmds} >= {"vamos", "vamos-sim", "vamos-train", "script"}
    assert programs.help("vamos", ("profile",)).subcommands  # a nested sub-command path is walked


def test_the_command_check_can_fail() -> None:
    programs = Programs(vamos_bin())
    text = ("```sh\n"
            "vamos flow a.png b.png -o f.png --no-such-option\n"
            "vamos frobnicate --robots 2\n"
            "VAMOS_X=1 vamos robot frobnicate x\n"
            "vamos robot inspect --robot r/ --not-an-inspect-option \\\n    --joints j.json\n"
            "echo $(vamos demo --made-up)\n"
            "vamos demo --robots 2 --speed 1 --vision -q\n"
            "scripts/no-such-script.sh\n"
            "vamos render --episode run.mcap --frame 10\n"
            "```\n"
            "A mention in prose is not a whole command: `vamos render --frame 10`.\n")
    problems = [p for cmd in commands_in(text, "t.md") for p in problems_of(cmd, programs)]
    assert len(problems) == 10, problems
    assert "has no option --no-such-option" in problems[0]
    assert "`vamos ` has no sub-command 'frobnicate'" in problems[1]
    assert "`vamos robot` has no sub-command 'frobnicate'" in problems[2]
    assert "`vamos robot inspect` has no option --not-an-inspect-option" in problems[3]
    assert "`vamos demo` has no option --made-up" in problems[4]
    assert "`vamos demo` has no option -q" in problems[5]
    assert "no such script scripts/no-such-script.sh" in problems[6]
    # The profile init's next step as the README once showed it: render's required options missing.
    assert [p.split(": ")[-1] for p in problems[7:]] == [
        "`vamos render` needs --robot", "`vamos render` needs --camera", "`vamos render` needs --out"]
    # The same commands spelled right pass.
    good = ("```sh\nvamos flow a.png b.png -o f.png --raw f.flo\nvamos robot inspect --robot r/ --joints j.json\n"
            "vamos demo --robots 2 --speed 1\nscripts/test.sh\n"
            "vamos render --robot r/ --camera c.json --episode run.mcap --frame 10 -o overlay.png\n```\n")
    assert [p for cmd in commands_in(good, "t.md") for p in problems_of(cmd, programs)] == []


def test_the_python_command_check_can_fail() -> None:
    # No server binary needed: the console scripts' own --help is read.
    programs = Programs(None)
    text = ("```sh\n"
            "vamos-sim generate --out x --no-such-option 1\n"
            "vamos-train frobnicate d -o r\n"
            "vamos-client --server http://h:1 stream e.mcap --profile p --made-up\n"
            "vamos flow a.png b.png --anything   # vamos itself is not checked without VAMOS_BIN\n"
            "```\n")
    problems = [p for cmd in commands_in(text, "t.md") for p in problems_of(cmd, programs)]
    assert len(problems) == 3, problems
    assert "`vamos-sim generate` has no option --no-such-option" in problems[0]
    assert "`vamos-train ` has no sub-command 'frobnicate'" in problems[1]
    assert "`vamos-client stream` has no option --made-up" in problems[2]
    good = ("```sh\nvamos-sim generate --out x --seed 1 [--camera fixed|wrist]\n"
            "vamos-train fit d -o r --free-bits 0.1\nvamos-client --server http://h:1 stream e.mcap --profile p\n```\n")
    assert [p for cmd in commands_in(good, "t.md") for p in problems_of(cmd, programs)] == []
