"""Reading the README and the docs as a test reads them: fenced blocks, inline commands, CLI synopses, and the
generators of the site's reference pages."""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
#: The site's build hooks: the generators of the reference pages.
HOOKS = DOCS / "hooks"
#: Every markdown file a user reads: the README, every page of docs/, the driver folders' and the benches' READMEs.
DOCUMENTS = sorted(
    [
        ROOT / "README.md",
        ROOT / "CONTRIBUTING.md",
        *DOCS.rglob("*.md"),
        *(ROOT / "drivers").glob("*/README.md"),
        ROOT / "bench" / "README.md",
    ]
)


@dataclass(frozen=True)
class Block:
    """One fenced block of a markdown file."""

    file: Path
    line: int  # of the opening fence, 1-based
    lang: str
    text: str

    @property
    def where(self) -> str:
        return f"{self.file.relative_to(ROOT)}:{self.line}"


def fenced_blocks(path: Path) -> list[Block]:
    """Every fenced block of ``path``, in order."""
    blocks, lines = [], path.read_text().splitlines()
    start = None
    for number, line in enumerate(lines, 1):
        if line.lstrip().startswith("```"):
            if start is None:
                start, lang = number, line.strip()[3:].strip()
            else:
                blocks.append(Block(path, start, lang, "\n".join(lines[start : number - 1])))
                start = None
    assert start is None, f"{path.name}:{start}: a fence that is never closed"
    return blocks


def section(path: Path, heading: str) -> str:
    """The text under ``heading`` (a ``## `` or ``### `` heading line) up to the next heading of any level."""
    match = re.search(rf"^#+ {re.escape(heading)}\n(.*?)(?=^#+ |\Z)", path.read_text(), re.S | re.M)
    assert match, f"{path.name} has no heading {heading!r}"
    return match.group(1)


def block_after(path: Path, text_before: str) -> Block:
    """The first fenced block of ``path`` after the text ``text_before``."""
    text = path.read_text()
    line = text[: text.index(text_before)].count("\n") + 1
    return next(b for b in fenced_blocks(path) if b.line > line)


def hook_module(name: str) -> ModuleType:
    """A module of the site's build hooks (``docs/hooks/name.py``), imported as the build imports it: the hooks
    import each other by their bare names."""
    sys.path.insert(0, str(HOOKS))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(HOOKS))


def inline_commands(path: Path) -> list[str]:
    """The inline code spans of ``path`` that are hilident commands (``hilident run CONFIG``, ...)."""
    return re.findall(r"`(hilident [^`]+)`", path.read_text())


def hilident_commands(block_text: str) -> list[list[str]]:
    """The hilident command lines of a shell block, as argument lists without the program name.

    ``a && b && .venv/bin/hilident run X`` gives the hilident part; comments are dropped."""
    commands = []
    for line in block_text.splitlines():
        for part in line.split("&&"):
            if re.match(r"\s*(\S*/bin/)?hilident\s", part):
                commands.append(shlex.split(part, comments=True)[1:])
    return commands


def subcommand_parsers(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    """``{"run": parser, "drivers new": parser, ...}``: every sub-command of the CLI, nested ones by their path."""
    found = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                path = f"{prefix}{name}"
                found[path] = sub
                found.update(subcommand_parsers(sub, path + " "))
    return found


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    return set(parser._option_string_actions)


def split_synopsis(words: list[str], commands: dict[str, argparse.ArgumentParser]) -> tuple[str, list[str]]:
    """The longest sub-command path at the start of ``words`` (after top-level options), and the options named
    after it (``[--out DIR]`` -> ``--out``, ``--format=mat`` -> ``--format``, ``-q|--quiet`` -> both)."""
    words, leading = list(words), []
    while words and words[0].startswith("-"):  # --log-level LEVEL before the command
        leading.append(words[0])
        words = words[2:]
    path = ""
    for word in words:
        candidate = f"{path} {word}".strip()
        if candidate in commands:
            path = candidate
        else:
            break
    options = []
    for word in words[len(path.split()) :]:
        for piece in word.strip("[]").split("|"):
            piece = piece.strip("[]").split("=", 1)[0]
            if re.fullmatch(r"--?[a-zA-Z][\w-]*", piece):
                options.append(piece)
    return path, (options if path else leading)
