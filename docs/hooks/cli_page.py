"""The command-line reference page, written from hilident's argparse parser at build time.

Every sub-command (nested ones such as ``emulate serial`` by their path) gets
its synopsis, its one-line help, a table of its arguments and options with
their help, choices and defaults, and the examples its ``--help`` ends with.
Nothing here is written by hand, so the page cannot drift from the parser.
"""

from __future__ import annotations

import argparse

from markdown_text import cell, sentence

#: The program name every synopsis starts with.
PROGRAM = "hilident"


def cli_reference(parser: argparse.ArgumentParser) -> str:
    """The Markdown of the command-line reference page.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        hilident's parser, ``hilident.cli.main.build_parser()``.

    Returns
    -------
    str
        One ``##`` section for the top level and one per sub-command, in the order the parser declares them.
    """
    parts = [
        "# Command-line reference\n",
        "Generated from the parser of `hilident` when the site is built: every sub-command and option "
        "there is, with the help `hilident COMMAND --help` prints. The [commands guide](../commands.md) "
        "explains what each command is for.\n",
        command_section("", parser, parser.description or ""),
    ]
    for path, sub, summary in subcommands(parser):
        parts.append(command_section(path, sub, summary))
    return "\n".join(parts)


def subcommands(parser: argparse.ArgumentParser, prefix: str = "") -> list[tuple[str, argparse.ArgumentParser, str]]:
    """``(path, parser, one-line help)`` of every sub-command below ``parser``, nested ones after their parent."""
    found = []
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
        for name, sub in action.choices.items():
            path = f"{prefix}{name}"
            found.append((path, sub, helps.get(name, "")))
            found.extend(subcommands(sub, path + " "))
    return found


def command_section(path: str, parser: argparse.ArgumentParser, summary: str) -> str:
    """One command: heading, summary, synopsis, the table of its arguments, its examples."""
    title = f"{PROGRAM} {path}".strip()
    lines = [f"## `{title}`\n"]
    if summary:
        lines.append(sentence(summary) + "\n")
    lines += ["```text", synopsis(path, parser), "```\n"]
    rows = [argument_row(parser, action) for action in documented_actions(parser)]
    if rows:
        lines += ["| argument | what it does |", "|---|---|", *rows, ""]
    if parser.epilog:
        lines += ["```text", parser.epilog.rstrip(), "```\n"]
    return "\n".join(lines)


def documented_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The arguments and options of ``parser`` a user gives (not ``--help``, not hidden ones)."""
    return [
        action
        for action in parser._actions
        if not isinstance(action, argparse._HelpAction) and action.help != argparse.SUPPRESS
    ]


def synopsis(path: str, parser: argparse.ArgumentParser) -> str:
    """``hilident run CONFIG [--out OUT] [-q] ...``: the command with every argument it takes."""
    words = [PROGRAM, *path.split()]
    for action in documented_actions(parser):
        words.append(synopsis_word(action))
    return " ".join(words)


def synopsis_word(action: argparse.Action) -> str:
    """How one argument reads in a synopsis: ``CONFIG``, ``INPUT...``, ``[--out OUT]``, ``--format mat|json``."""
    if isinstance(action, argparse._SubParsersAction):
        word = "{" + ",".join(action.choices) + "} ..."
        return word if action.required else f"[{word}]"
    if not action.option_strings:
        return value_word(action)
    word = action.option_strings[-1] if action.nargs == 0 else f"{action.option_strings[-1]} {value_word(action)}"
    if isinstance(action, argparse._VersionAction) or not action.required:
        return f"[{word}]"
    return word


def value_word(action: argparse.Action) -> str:
    """The placeholder of an argument's value: its metavar, its choices, or its name in capitals."""
    if action.metavar is not None:
        word = str(action.metavar)
    elif action.choices is not None:
        word = "|".join(str(choice) for choice in action.choices)
    else:
        word = action.dest.upper()
    if action.nargs in ("+", "*"):
        return f"{word}..."
    return f"[{word}]" if action.nargs == "?" else word


def argument_row(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """One table row: the argument as typed, and its help with choices and default."""
    if isinstance(action, argparse._SubParsersAction):
        names = ", ".join(f"`{name}`" for name in action.choices)
        return f"| {names} | {cell('sub-commands, each below')} |"
    if action.option_strings:
        value = "" if action.nargs == 0 else " " + value_word(action)
        name = ", ".join(f"`{option}{value}`" for option in action.option_strings)
    else:
        name = f"`{value_word(action)}`"
    return f"| {name} | {cell(argument_help(parser, action))} |"


def argument_help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The help of one argument as ``--help`` prints it (``%%`` and ``%(default)s`` expanded), with its facts."""
    text = parser._get_formatter()._expand_help(action) if action.help else ""
    facts = []
    if action.required and action.option_strings:
        facts.append("required")
    if action.choices is not None and action.metavar is not None:
        facts.append("one of " + ", ".join(f"`{choice}`" for choice in action.choices))
    if isinstance(action, argparse._VersionAction):
        text = text or "print hilident's version and exit"
    return "; ".join(part for part in (sentence(text), *facts) if part)
