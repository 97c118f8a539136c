"""The ``board`` fixture: every conformance check runs once per board implementation (see boards.py)."""

from __future__ import annotations

import pytest

from conformance.boards import c_board, python_twin
from conformance.wire import Wire
from support.c_board import build


@pytest.fixture(scope="session")
def c_board_executable(tmp_path_factory):
    """The C firmware's ``posix-sim``, built once per test process (skipped without ``cc`` and ``make``)."""
    return build("posix-sim", tmp_path_factory.mktemp("conformance-firmware"))


@pytest.fixture(params=["python-twin", "c-board"])
def board(request, tmp_path):
    """A freshly powered-up board on a TCP line of 127.0.0.1 (:class:`conformance.boards.Board`)."""
    if request.param == "python-twin":
        with python_twin() as served:
            yield served
    else:
        with c_board(request.getfixturevalue("c_board_executable"), tmp_path) as served:
            yield served


@pytest.fixture
def wire(board) -> Wire:
    """A host connection to ``board``."""
    return board.connect()
