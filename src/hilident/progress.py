"""Progress of long steps on stderr (light: no numerics, so a command's first error is not kept waiting).

On a terminal a step's fraction is a tqdm bar with the elapsed time and the
time left; elsewhere (a log file, a pipe) a line every 25 % with the same two
times, so a log stays short and still says how long each step took.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

__all__ = ["Progress"]

#: Percent between two lines when the output is no terminal.
LOG_STEP_PERCENT = 25


def _interval(seconds: float) -> str:
    """``seconds`` as tqdm writes a time (``0:05``, ``1:02:03``)."""
    from tqdm import tqdm

    return tqdm.format_interval(max(0.0, seconds))


class Progress:
    """Progress of long steps on stderr: one updating bar on a terminal, a few lines otherwise.

    Parameters
    ----------
    stream : file, optional
        Where to write (default: ``sys.stderr``).
    enabled : bool
        False: write nothing (``-q``).
    """

    def __init__(self, stream: TextIO | None = None, enabled: bool = True):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        try:
            self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        except ValueError:  # closed already
            self.tty = False

    def step(self, message: str) -> None:
        """One line saying what happens now."""
        if self.enabled:
            self._print(message)

    def _print(self, text: str, end: str = "\n") -> None:
        """Print, or fall silent when nobody reads any more (a closed pipe or terminal must not stop a run)."""
        try:
            print(text, end=end, file=self.stream, flush=True)
        except (OSError, ValueError):
            self.enabled = False

    def fraction(self, label: str) -> Callable[[float], None]:
        """A callback taking the fraction done (0 to 1) of the step ``label``; it shows elapsed time and time left."""
        started = time.monotonic()
        if self.tty:
            return self._bar(label)
        last = -1

        def update(x: float) -> None:
            nonlocal last
            pct = int(100 * x)
            if not self.enabled or pct // LOG_STEP_PERCENT == last // LOG_STEP_PERCENT:
                return
            last = pct
            elapsed = time.monotonic() - started
            left = elapsed * (1.0 - x) / x if x > 0 else float("nan")
            times = f"{_interval(elapsed)} elapsed" + (f", {_interval(left)} left" if 0 < x < 1 else "")
            self._print(f"  {label}: {pct:3d} % ({times})")

        return update

    def _bar(self, label: str) -> Callable[[float], None]:
        """The terminal form: a tqdm bar from 0 to 100 %, closed (left on screen) when the step is done."""
        from tqdm import tqdm

        bar: Any = None

        def update(x: float) -> None:
            nonlocal bar
            if not self.enabled:
                return
            try:
                if bar is None:
                    bar = tqdm(
                        total=100,
                        desc=f"  {label}",
                        file=self.stream,
                        leave=True,
                        dynamic_ncols=True,
                        bar_format="{desc}: {percentage:3.0f} %|{bar}| {elapsed} elapsed, {remaining} left",
                    )
                bar.update(max(0, int(100 * x) - bar.n))
                if x >= 1.0:
                    bar.close()
            except (OSError, ValueError):  # the terminal went away: the run goes on silently
                self.enabled = False

        return update
