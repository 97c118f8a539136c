"""Griffe extension: hilident's numpy-style docstrings read by the API pages as a person reads them.

Three habits of the source that the Markdown of the API pages reads otherwise:

- an ``Example`` section heading, which numpydoc takes as ``Examples`` and
  griffe knows only in the plural (its doctests would render as prose);
- a paragraph of prose after the parameter list, at the list's indentation,
  which griffe would take for more parameters: it is read as the start of a
  ``Notes`` section;
- Sphinx roles (``:func:`~hilident.x.f```), which Markdown shows as written:
  they become code spans of the name (``f`` for the ``~`` form).
"""

from __future__ import annotations

import re

import griffe

#: A numpy section heading ``Example`` over its underline of dashes.
SINGULAR_EXAMPLE_HEADING = re.compile(r"^(?P<indent>[ \t]*)Example[ \t]*\n(?P=indent)-{3,}[ \t]*$", re.M)
#: The underline of a numpy section heading.
UNDERLINE = re.compile(r"\s*-{3,}\s*")
#: The first line of an entry of a parameter list: ``name``, ``a, b``, ``name : type``, ``**kwargs``.
PARAMETER_ENTRY = re.compile(r"\*{0,2}\w+(, \*{0,2}\w+)*( : .*)?")
#: A Sphinx cross-reference role: ``:func:`name```, ``:class:`~module.Name```.
ROLE = re.compile(r":[\w:]+:`(?P<short>~?)(?P<target>[^`]+)`")
#: Sections whose entries are parameters.
PARAMETER_SECTIONS = ("parameters", "other parameters")


def plural_example_headings(text: str) -> str:
    """``text`` with every ``Example`` section heading written ``Examples``."""
    return SINGULAR_EXAMPLE_HEADING.sub(lambda match: f"{match['indent']}Examples\n{match['indent']}--------", text)


def roles_as_code(text: str) -> str:
    """``text`` with every Sphinx role written as a code span of its target."""
    return ROLE.sub(role_as_code, text)


def role_as_code(match: re.Match) -> str:
    """One role as a code span: its whole target, or its last name for the ``~`` form."""
    target = match["target"]
    return f"`{target.rsplit('.', 1)[-1] if match['short'] else target}`"


def prose_after_parameters_as_notes(text: str) -> str:
    """``text`` with a prose paragraph that follows a parameter list opening a ``Notes`` section."""
    lines = text.split("\n")
    read: list[str] = []
    section = ""
    for number, line in enumerate(lines):
        heading = number + 1 < len(lines) and bool(line.strip()) and bool(UNDERLINE.fullmatch(lines[number + 1]))
        if heading:
            section = line.strip().lower()
        elif section in PARAMETER_SECTIONS and starts_prose_paragraph(line, read):
            read += ["Notes", "-----"]
            section = "notes"
        read.append(line)
    return "\n".join(read)


def starts_prose_paragraph(line: str, before: list[str]) -> bool:
    """Whether ``line`` opens an unindented paragraph that is no parameter entry."""
    after_blank = bool(before) and not before[-1].strip()
    unindented = bool(line) and not line[0].isspace()
    return after_blank and unindented and not PARAMETER_ENTRY.fullmatch(line) and not UNDERLINE.fullmatch(line)


def as_the_pages_read_it(text: str) -> str:
    """A docstring as the API pages read it: every habit of the module docstring rewritten."""
    return roles_as_code(prose_after_parameters_as_notes(plural_example_headings(text)))


class NumpydocReading(griffe.Extension):
    """Every docstring of the API pages read with :func:`as_the_pages_read_it`."""

    def on_object(self, *, obj: griffe.Object, loader: griffe.GriffeLoader, **kwargs: object) -> None:
        if obj.docstring is not None:
            obj.docstring.value = as_the_pages_read_it(obj.docstring.value)
