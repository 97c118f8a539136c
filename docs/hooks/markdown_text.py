"""Plain text (help strings, docstrings) written into generated Markdown as it reads in the source."""

from __future__ import annotations

import re

#: Characters of plain text that Markdown would read as markup, and what shows them as written.
MARKUP_ESCAPES = {"\\": "\\\\", "|": "\\|", "*": "\\*", "_": "\\_", "[": "\\[", "]": "\\]", "<": "&lt;", ">": "&gt;"}


def sentence(text: str) -> str:
    """``text`` on one line (help strings and docstrings are wrapped in the source)."""
    return " ".join(text.split())


def cell(text: str) -> str:
    """Plain ``text`` shown as written inside a Markdown table cell."""
    return "".join(MARKUP_ESCAPES.get(char, char) for char in text)


def rst_to_markdown(text: str) -> str:
    """A docstring line in Markdown: ``literal`` and :role:`a.b` become code spans (:role:`~a.b` shows ``b``)."""
    return re.sub(r":\w+:`(~?)([^`]+)`", _role_as_code, text).replace("``", "`")


def _role_as_code(match: re.Match) -> str:
    shortened, target = match.group(1), match.group(2)
    return f"`{target.rsplit('.', 1)[-1] if shortened else target}`"
