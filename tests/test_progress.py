"""Progress of long steps: elapsed time and time left, on a terminal (tqdm) and in a log."""

import io
import re

from hilident.progress import Progress


class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_log_lines_every_quarter_with_elapsed_and_left():
    out = io.StringIO()
    update = Progress(out).fraction("identification")
    for i in range(101):
        update(i / 100)
    lines = out.getvalue().splitlines()
    assert [line.split(" %")[0] for line in lines] == [f"  identification: {p:3d}" for p in (0, 25, 50, 75, 100)]
    assert all(re.search(r"\(\d+:\d\d elapsed", line) for line in lines)
    assert all(re.search(r", \d+:\d\d left\)$", line) for line in lines[1:-1])  # a time left once there is a rate
    assert lines[-1].endswith("elapsed)")  # done: nothing left to announce


def test_terminal_bar_shows_elapsed_and_left_and_ends_its_line():
    out = FakeTerminal()
    update = Progress(out).fraction("verification")
    for i in range(0, 101, 10):
        update(i / 100)
    text = out.getvalue()
    assert "verification: 100 %" in text
    assert re.search(r"\d+:\d\d elapsed, \d+:\d\d left", text)
    assert text.endswith("\n")  # closed at 100 %: the next step starts on its own line


def test_quiet_writes_nothing_and_a_closed_stream_silences_without_stopping():
    out = io.StringIO()
    quiet = Progress(out, enabled=False)
    quiet.step("x")
    quiet.fraction("y")(0.5)
    assert out.getvalue() == ""

    closed = io.StringIO()
    closed.close()
    progress = Progress(closed)
    progress.step("the pipe went away")  # no exception
    progress.fraction("z")(0.5)
    assert progress.enabled is False
