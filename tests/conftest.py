"""Fixtures shared by the end-to-end tests."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest


@pytest.fixture
def standalone_emulator():
    """Start ``hilident emulate TRANSPORT --config CONFIG ...`` in another process.

    Yields ``start(transport, config, *extra) -> port``, the line the emulator
    printed. Every emulator started is stopped with SIGTERM at teardown and
    must exit cleanly (code 0).
    """
    procs: list[subprocess.Popen] = []

    def start(transport: str, config, *extra: str) -> str:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hilident.cli", "emulate", transport, "--config", str(config), *extra],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        procs.append(proc)
        port = proc.stdout.readline().strip()
        assert port, proc.stderr.read()
        return port

    yield start
    for proc in procs:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0, proc.stderr.read()
