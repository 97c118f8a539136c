"""Warnings and notes that name their subject, so that one cause found on many subjects reads as one line.

A run finds the same thing again and again: the same sampling hint for each
resonance, the same delay in the model of every mapped position. A
:class:`Finding` is a line of text that keeps its cause and its subject
apart; :func:`grouped` turns a list of lines into one line per cause that
names every subject. A finding *is* its text (a ``str``), so it travels in
the ordinary lists of warnings and notes.

Examples
--------
>>> cause = "sampling: {subjects} sampled finer than the rule asks"
>>> grouped([Finding(cause, "21.8 Hz"), "friction: a plain warning", Finding(cause, "22.1 Hz")])
['sampling: 21.8 Hz, 22.1 Hz sampled finer than the rule asks', 'friction: a plain warning']
"""

from __future__ import annotations

from collections.abc import Iterable


class Finding(str):
    """One cause found on one subject; its text is ``cause`` with the subject in place of ``{subjects}``.

    Parameters
    ----------
    cause : str
        The line, with ``{subjects}`` where the subjects go (worded so that
        it reads for one subject and for several).
    subject : str
        What it was found on, e.g. a resonance (``"21.79 Hz"``).
    """

    cause: str
    subject: str

    def __new__(cls, cause: str, subject: str) -> Finding:
        text = super().__new__(cls, cause.format(subjects=subject))
        text.cause = cause
        text.subject = subject
        return text

    def __getnewargs__(self) -> tuple[str, str]:  # type: ignore[override]
        # pickle (a batch's worker processes) rebuilds it from its cause and subject, not from its text
        return self.cause, self.subject


def grouped(lines: Iterable[str]) -> list[str]:
    """One line per cause, where the first of its kind stood; a line repeated word for word is kept once.

    Findings of one cause become one line naming their subjects in the
    order found, each subject once; any other line is kept as it is.
    """
    found: dict[tuple[str, bool], list[str]] = {}  # by (cause or plain line, whether it is a finding)
    for line in lines:
        if isinstance(line, Finding):
            named = found.setdefault((line.cause, True), [])
            if line.subject not in named:
                named.append(line.subject)
        else:
            found.setdefault((str(line), False), [])
    return [
        text.format(subjects=", ".join(named)) if is_finding else text for (text, is_finding), named in found.items()
    ]
