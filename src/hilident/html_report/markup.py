"""Small HTML building blocks: escaped text, tables, numbers with units.

Pure: strings in, strings out. Every piece of text that comes from a summary,
a file or a user passes through :func:`esc` (``html.escape``), so a warning
holding ``<script>`` shows as text.

Examples
--------
>>> table(["f", "zeta"], [["21.8 Hz", esc("<1")]])
'<table><thead><tr><th>f</th><th>zeta</th></tr></thead><tbody><tr><td>21.8 Hz</td><td>&lt;1</td></tr></tbody></table>'
>>> num(0.0123456, "Hz")
'0.01235 Hz'
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Sequence
from typing import Any

__all__ = ["esc", "num", "pm", "table", "key_values", "note", "section", "figure", "MISSING"]

#: What a figure the summary does not hold shows as.
MISSING = "—"


def esc(value: Any) -> str:
    """``value`` as text, HTML-escaped (quotes too)."""
    return html.escape(str(value), quote=True)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def num(value: Any, unit: str = "", digits: int = 4) -> str:
    """A number to ``digits`` significant digits with its unit, escaped; :data:`MISSING` when there is none.

    An ``int`` is written in full (a count of samples).

    Parameters
    ----------
    value : float or int or None
        The figure; anything that is not a finite number shows as :data:`MISSING`.
    unit : str
        Its unit (``"Hz"``, ``"dB"``, ``"N*m"``), written after a space (``"1"``, dimensionless, is not).
    digits : int
        Significant digits.
    """
    x = _number(value)
    if x is None:
        return MISSING if value is None else esc(value)
    text = str(value) if isinstance(value, int) else f"{x:.{digits}g}"
    return esc(f"{text} {unit}" if unit and unit != "1" else text)


def pm(value: Any, half_width: Any, unit: str = "", digits: int = 4) -> str:
    """``value ± half_width unit`` (the ± part left out when it is not a number)."""
    if _number(half_width) is None:
        return num(value, unit, digits)
    return f"{num(value, '', digits)} ± {num(half_width, unit, 2)}"


def table(header: Sequence[str], rows: Iterable[Sequence[str]], caption: str = "") -> str:
    """A table; ``header`` is plain text (escaped here), cells are HTML already (escape them with :func:`esc`)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows)
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def key_values(pairs: Iterable[tuple[str, str]]) -> str:
    """A two-column table of ``(plain-text name, HTML value)`` pairs."""
    rows = "".join(f'<tr><th scope="row">{esc(k)}</th><td>{v}</td></tr>' for k, v in pairs)
    return f'<table class="kv"><tbody>{rows}</tbody></table>'


def note(text: str) -> str:
    """A paragraph saying why something is not shown (plain text, escaped here)."""
    return f'<p class="note">{esc(text)}</p>'


def section(anchor: str, title: str, body: str) -> str:
    """One report section: an ``<h2>`` heading and its body (HTML)."""
    return f'<section id="{esc(anchor)}">\n<h2>{esc(title)}</h2>\n{body}\n</section>\n'


def figure(name: str, png: bytes, caption: str) -> str:
    """A PNG embedded as a ``data:`` URI with its caption (plain text) and file name."""
    uri = "data:image/png;base64," + base64.b64encode(png).decode("ascii")
    return (
        f'<figure><img src="{uri}" alt="{esc(name)}"><figcaption>{esc(caption)} '
        f'<span class="file">({esc(name)})</span></figcaption></figure>'
    )
