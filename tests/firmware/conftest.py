"""Fixtures of the C firmware's tests: ``posix-sim`` built once per test process (see :mod:`c_board`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from support.c_board import build


@pytest.fixture(scope="session")
def posix_sim(tmp_path_factory) -> Path:
    return build("posix-sim", tmp_path_factory.mktemp("firmware"))


@pytest.fixture(scope="session")
def sanitized_sim(tmp_path_factory) -> Path:
    return build("sanitize", tmp_path_factory.mktemp("firmware-sanitize"))
