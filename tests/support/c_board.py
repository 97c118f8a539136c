"""The reference C firmware of the serial board (``drivers/myrio-board/firmware``), built and served for the tests.

``posix-sim`` is the firmware's core on this computer with a simulated gantry behind its hardware layer; it
serves a raw TCP line on 127.0.0.1 (``socket://`` in pyserial) that ``hilident run`` opens as it would a
serial-to-Ethernet converter. Each test process builds its own copy into a temporary folder, with the
firmware's own Makefile and nothing but ``cc`` and ``make``.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[2] / "drivers" / "myrio-board" / "firmware"

#: Make target -> the executable it builds in the build folder.
EXECUTABLES = {"posix-sim": "posix-sim", "sanitize": "posix-sim-sanitize", "linux": "hilident-board"}

#: A sanitizer finding ends the board at once (and fails the test that reads its exit code).
SANITIZER_ENV = {
    "ASAN_OPTIONS": "abort_on_error=1:halt_on_error=1",
    "UBSAN_OPTIONS": "halt_on_error=1:abort_on_error=1:print_stacktrace=1",
}


def build(target: str, build_dir: Path) -> Path:
    """``make -C drivers/myrio-board/firmware <target>`` into ``build_dir``; the executable's path.

    Skips the test when there is no C compiler or no make on PATH: nothing else is needed.
    """
    compiler = os.environ.get("CC", "cc")
    missing = [tool for tool in (compiler, "make") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"the C firmware needs {' and '.join(missing)} on PATH to be built")
    done = subprocess.run(
        ["make", "-C", str(FIRMWARE), f"BUILD={build_dir}", target],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, f"make {target} failed:\n{done.stdout}\n{done.stderr}"
    return build_dir / EXECUTABLES[target]


def plant(executable: Path) -> dict[str, float]:
    """The simulated gantry's parameters as ``posix-sim --print-plant`` states them (``mode_hz``, ``fc_nm``, ...)."""
    done = subprocess.run([str(executable), "--print-plant"], capture_output=True, text=True, timeout=30, check=True)
    return {name: float(value) for name, value in (line.split() for line in done.stdout.splitlines())}


class CBoard:
    """``posix-sim`` serving a raw TCP line on 127.0.0.1; :attr:`url` is what a host opens.

    Parameters
    ----------
    executable : Path
    *args : str
        More command-line options (``--time-scale 4``).
    sanitized : bool
        Run with the sanitizers set to abort at the first finding.
    """

    def __init__(self, executable: Path, *args: str, sanitized: bool = False):
        env = dict(os.environ, **SANITIZER_ENV) if sanitized else None
        self.proc = subprocess.Popen(
            [str(executable), "--tcp", "0", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        self.url = self.proc.stdout.readline().strip()
        if not self.url.startswith("socket://127.0.0.1:"):
            rc, err = self.stop()
            raise AssertionError(f"posix-sim did not start (rc {rc}): {err}")

    @property
    def port(self) -> int:
        return int(self.url.rsplit(":", 1)[1])

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> tuple[int, str]:
        """SIGTERM (the board disables its drive and reports its loop); its exit code and stderr."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            _, err = self.proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
            err = "posix-sim did not stop on SIGTERM\n" + err
        return self.proc.returncode, err
