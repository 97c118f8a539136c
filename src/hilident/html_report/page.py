"""The whole page: head with inline CSS (screen and print), a contents list, the sections.

Pure. No JavaScript, no external reference: plots are ``data:`` URIs, the
style is inline, links are relative to the folder.
"""

from __future__ import annotations

from collections.abc import Sequence

from hilident.html_report.gather import ReportInputs
from hilident.html_report.markup import esc
from hilident.html_report.sections import SECTIONS, title_of

__all__ = ["CSS", "page", "render"]

CSS = """
:root { color-scheme: light; }
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; font-size: 15px; line-height: 1.45;
       color: #1b1b1b; background: #fff; max-width: 1100px; margin: 0 auto; padding: 1.5em; }
h1 { font-size: 1.6em; margin: 0 0 .2em; }
h2 { font-size: 1.3em; border-bottom: 2px solid #3a6ea5; padding-bottom: .15em; margin-top: 1.8em; }
h3 { font-size: 1.05em; margin: 1.2em 0 .4em; }
.subtitle { color: #555; margin: 0 0 1em; }
nav ol { columns: 3; padding-left: 1.4em; margin: .5em 0 1em; }
table { border-collapse: collapse; margin: .6em 0 1em; font-variant-numeric: tabular-nums; }
caption { text-align: left; font-weight: 600; padding: .3em 0; }
th, td { border: 1px solid #c9d3df; padding: .25em .55em; text-align: left; vertical-align: top; }
thead th { background: #eef3f9; }
table.kv th { background: #f6f8fb; font-weight: 600; white-space: nowrap; }
pre { background: #f6f8fb; border: 1px solid #dde3ea; padding: .7em; overflow-x: auto; font-size: 13px;
      white-space: pre-wrap; word-break: break-word; }
details summary { cursor: pointer; font-weight: 600; margin: .4em 0; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #dde3ea; }
figcaption { color: #444; font-size: .92em; }
.file { color: #777; }
.note { color: #555; font-style: italic; }
strong.flagged { color: #c62828; }
.failed { background: #fdecea; border-left: 4px solid #c62828; padding: .6em .8em; }
ul.warnings li { margin-bottom: .55em; }
h3.notes { color: #555; }
ul.notes { color: #555; border-left: 3px solid #b0bec5; padding-left: 1.6em; }
ul.notes li { margin-bottom: .4em; }
.todo { color: #1f5130; }
.todo.general { color: #555; }
.print-only { display: none; }
footer { margin-top: 2em; color: #777; font-size: .85em; }
@media print {
  body { max-width: none; padding: 0; font-size: 11pt; }
  nav, .screen-only { display: none; }
  .print-only { display: block; }
  section { break-before: page; page-break-before: always; }
  section#run { break-before: auto; page-break-before: auto; }
  h2, h3, caption { break-after: avoid; page-break-after: avoid; }
  figure, img, tr, li { break-inside: avoid; page-break-inside: avoid; }
  figure img { max-height: 24cm; }
  thead { display: table-header-group; }
  a { color: inherit; }
  pre { white-space: pre-wrap; }
}
"""


def page(title: str, subtitle: str, sections: Sequence[tuple[str, str, str]], footer: str) -> str:
    """A whole self-contained page: ``<head>`` with :data:`CSS`, a contents list, the sections.

    Parameters
    ----------
    title, subtitle : str
        Plain text (escaped here).
    footer : str
        HTML.
    sections : sequence of (anchor, heading, html)
        In page order; ``html`` is the section as :func:`~hilident.html_report.markup.section` wrote it.
    """
    contents = "".join(f'<li><a href="#{esc(anchor)}">{esc(heading)}</a></li>' for anchor, heading, _ in sections)
    body = "".join(html for _, _, html in sections)
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{esc(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n"
        f'<header><h1>{esc(title)}</h1><p class="subtitle">{esc(subtitle)}</p></header>\n'
        f"<nav><ol>{contents}</ol></nav>\n<main>\n{body}</main>\n"
        f"<footer>{footer}</footer>\n</body>\n</html>\n"
    )


def render(inputs: ReportInputs) -> str:
    """``report.html`` of ``inputs`` as text."""
    return page(
        title_of(inputs),
        f"{inputs.folder.name}, summary written {inputs.summary_time_utc}",
        [(anchor, heading, write(inputs)) for anchor, heading, write in SECTIONS],
        "Written by hilident from summary.json and the files beside it; "
        "<code>hilident report DIR</code> writes it again.",
    )
