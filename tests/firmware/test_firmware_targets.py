"""The firmware's other targets build from the same core: the linux process and the Cortex-M skeleton."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from support.c_board import FIRMWARE, build


def test_the_linux_target_builds_warning_free_and_refuses_to_run_unfilled(tmp_path):
    """The linux target builds for this computer with -Wall -Wextra -Werror, like posix-sim; its hardware
    table is stubs that refuse to run until a user fills them."""
    exe = build("linux", tmp_path)
    done = subprocess.run([str(exe), "--tcp", "0"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "hw_user.c" in done.stderr, done.stderr


def test_the_cortex_m_skeleton_builds_and_fits_its_part(tmp_path):
    """``make cortex-m`` cross-compiles the core with the skeleton and prints its size; it fits the STM32F446's
    512 kB of flash and 128 kB of RAM (the linker script also keeps 4 kB for the stack)."""
    if shutil.which("arm-none-eabi-gcc") is None or shutil.which("make") is None:
        pytest.skip("no arm-none-eabi-gcc or make on PATH (Debian: gcc-arm-none-eabi, libnewlib-arm-none-eabi)")
    done = subprocess.run(
        ["make", "-C", str(FIRMWARE), f"BUILD={tmp_path}", "cortex-m"], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stdout + done.stderr
    sizes = re.search(r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+\w+\s+\S*board\.elf$", done.stdout, re.M)
    assert sizes, done.stdout  # arm-none-eabi-size's line: text, data, bss, dec, hex, file
    text, data, bss = map(int, sizes.groups())
    assert text + data < 512 * 1024 and data + bss < 124 * 1024, (text, data, bss)
