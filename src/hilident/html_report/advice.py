"""Warnings grouped by topic, each split into what was found and what to do about it.

Pure. hilident's warnings usually carry their own remedy after a semicolon,
a colon or in parentheses ("...: decimate by 2 (to 500 Hz) before fitting a
discrete-time model"); :func:`split_advice` finds it. A warning without one
gets its topic's general advice, marked as such.

Examples
--------
>>> split_advice("sampling: 1000 Hz is outside 228-685 Hz: decimate by 2 (to 500 Hz) before fitting")
('sampling: 1000 Hz is outside 228-685 Hz', 'decimate by 2 (to 500 Hz) before fitting')
>>> [g.topic for g in group_warnings(["parameter 'Fc' = 0.1 is not significant", "connect: 3 frames discarded"])]
['Connection and stream', 'Model fit']
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

__all__ = ["WarningGroup", "group_warnings", "split_advice"]

#: Topics in the order they are shown: (title, words that put a warning in it, general advice).
TOPICS: tuple[tuple[str, tuple[str, ...], str], ...] = (
    (
        "Connection and stream",
        ("connect:", "lost block", "underrun", "sync", "corrupt", "out of order", "stream"),
        "Check the link (cable, bus load, baud rate) and the stream statistics below; lost data is counted, "
        "never filled.",
    ),
    (
        "Model fit",
        ("[model]", "parameter '", "rigid_axis", "mass_spring_damper", "residual", "transfer-function", "validation:"),
        "Read each parameter with its standard deviation; a richer excitation, a longer record or a model with "
        "more physics narrows it.",
    ),
    (
        "Friction",
        ("friction",),
        "Repeat the friction test with more speeds or longer legs when the friction parameters matter.",
    ),
    (
        "Notch and upload",
        ("notch", "filter slot", "slot ", "upload", "quantis", "save"),
        "Compare the designed and the achieved notch below before relying on it.",
    ),
    (
        "Measurement and excitation",
        ("coherence", "excitation", "amplitude", "sampling", "record", "resolution", "period", "closed-loop", "band"),
        "A larger excitation amplitude or a longer record improves coherence and resolution.",
    ),
    ("Other", (), "See the documentation page of the key or command the message names (docs/)."),
)

#: Verbs that start a remedy ("decimate by 2", "set [data] sample_rate_hz", "give [data].excitation").
_REMEDY = re.compile(
    r"(?:;|:|,|\(|\bso\b|\bthen\b)\s*(?:then\s+|so\s+|or\s+)?"
    r"((?:set|give|record|use|try|decimate|raise|lower|increase|reduce|check|compare|run|add|pass|widen|"
    r"lengthen|clear|fit|repeat|remove|choose|connect|replace|split|upload|confirm|lengthen|excite)\b.*)$",
    re.IGNORECASE | re.DOTALL,
)


def split_advice(text: str) -> tuple[str, str]:
    """``(finding, remedy)`` of one warning; the remedy is empty when the text gives none."""
    match = _REMEDY.search(text)
    if match is None:
        return text, ""
    remedy = match.group(1).strip()
    if text[match.start()] == "(" and remedy.endswith(")") and remedy.count("(") < remedy.count(")"):
        remedy = remedy[:-1]
    finding = text[: match.start()].rstrip(" ;:,(")
    return (finding or text), remedy


@dataclass
class WarningGroup:
    """The warnings of one topic: ``items`` are ``(finding, remedy)``; ``advice`` is the topic's general one."""

    topic: str
    advice: str
    items: list[tuple[str, str]] = field(default_factory=list)


def _topic(text: str) -> int:
    """The topic of a warning: by its leading ``name:`` when it has one ("sampling: ..."), else by its words."""
    low = text.lower()
    head = low.split(":", 1)[0] + ":" if ":" in low[:40] else ""
    for part in (head, low):
        for i, (_, words, _) in enumerate(TOPICS):
            if part and any(w in part for w in words):
                return i
    return len(TOPICS) - 1


def group_warnings(warnings: list) -> list[WarningGroup]:
    """``warnings`` (strings; other values are shown as their text) grouped by topic, topics in a fixed order."""
    groups: dict[int, WarningGroup] = {}
    for w in warnings:
        text = str(w)
        i = _topic(text)
        title, _, advice = TOPICS[i]
        groups.setdefault(i, WarningGroup(title, advice)).items.append(split_advice(text))
    return [groups[i] for i in sorted(groups)]
