"""``report.html``: one self-contained page a person reads (or prints to PDF) after a run, identify or upload.

:func:`write_report` reads an output folder (``summary.json``, the PNG
plots, the HDF5 recordings), and writes ``report.html`` beside them: what
was run on what, the headline results with units, the warnings with what to
do about each, every plot (embedded), the friction fit, the model with its
uncertainty and validation, the notches designed and achieved, the stream
statistics and links to the recordings. No JavaScript, no network: CSS is
inline and images are ``data:`` URIs.

:func:`write_report_quietly` is what ``run``, ``identify`` and ``upload``
call at their end: a report that cannot be written becomes a warning line,
never a failed command. ``hilident report DIR`` calls :func:`write_report`.

Modules: :mod:`~hilident.html_report.gather` (reads the folder),
:mod:`~hilident.html_report.sections` and :mod:`~hilident.html_report.page`
(pure HTML), :mod:`~hilident.html_report.advice` (warnings by topic),
:mod:`~hilident.html_report.markup` (escaping, tables, figures, numbers with units);
:mod:`~hilident.html_report.batch` writes a batch's report (drift verdicts, drift plots, failures) on the
same page and pieces.

May import ``io``, ``plots`` and ``errors``; never ``session``, ``adapters``, ``emulator`` or ``cli``.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

from hilident.io.serialise import atomic_write

__all__ = ["REPORT_NAME", "write_report", "write_report_quietly"]

REPORT_NAME = "report.html"


def write_report(folder: str | os.PathLike) -> Path:
    """Write ``folder/report.html`` from what the folder holds; returns its path.

    Parameters
    ----------
    folder : path-like
        The output folder of ``hilident run``, ``identify`` or ``upload``.

    Raises
    ------
    UsageError
        ``folder`` holds no ``summary.json``.
    DataError
        ``summary.json`` is not a JSON object.
    """
    from hilident.html_report.gather import gather
    from hilident.html_report.page import render

    inputs = gather(folder)
    text = render(inputs)
    path = Path(folder) / REPORT_NAME
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))
    return path


def _stderr_line(line: str) -> None:
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):  # nobody reads stderr any more: the report is not worth an error
        pass


def write_report_quietly(folder: str | os.PathLike, warn: Callable[[str], None] = _stderr_line) -> Path | None:
    """:func:`write_report`, with any failure turned into one ``warning:`` line given to ``warn`` (stderr).

    Returns the report's path, or None when it could not be written.
    """
    try:
        return write_report(folder)
    except Exception as exc:  # the command's results are already written; the report must not fail it
        warn(f"warning: {Path(folder) / REPORT_NAME} not written: {exc or type(exc).__name__}")
        return None
