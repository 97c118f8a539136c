"""The C firmware's compiled-in board data (``core/board_config.h``) is ``drivers/myrio-board/driver.toml``'s.

The header is read as text: no compiler needed. A change to one of the two files that is not made to the
other fails here, before a board answers IDENTIFY with numbers its driver description does not have.
"""

from __future__ import annotations

import re
import tomllib

from support.c_board import FIRMWARE

DRIVER = tomllib.loads((FIRMWARE.parent / "driver.toml").read_text())
HEADER = (FIRMWARE / "core" / "board_config.h").read_text()


def define(name: str) -> str:
    """The value of ``#define name value`` in the header (a C literal, its suffix dropped)."""
    found = re.search(rf"^#define {name} (.+)$", HEADER, re.MULTILINE)
    assert found, f"board_config.h defines no {name}"
    return found.group(1).split("/*")[0].strip().rstrip("uU")


def test_the_board_table_is_driver_tomls():
    board = DRIVER["board"]
    assert define("BOARD_NAME") == f'"{DRIVER["driver"]["name"]}"'
    assert define("BOARD_FIRMWARE") == f'"{board["firmware"]}"'
    assert int(define("BOARD_PROTOCOL_VERSION")) == DRIVER["driver"]["protocol_version"]
    assert float(define("BOARD_LOOP_RATE_HZ")) == board["loop_rate_hz"]
    assert float(define("BOARD_MAX_SAMPLE_RATE_HZ")) == board["max_sample_rate_hz"]
    assert int(define("BOARD_FILTER_SLOTS")) == board["filter_slots"]
    assert int(define("BOARD_EXCITATION_CAPACITY")) == board["excitation_buffer_samples"]


def test_the_channel_list_is_driver_tomls_in_board_order():
    table = HEADER.split("#define BOARD_CHANNEL_TABLE", 1)[1].split("\n\n", 1)[0]
    compiled = re.findall(r'\{"([^"]*)", "([^"]*)"\}', table)
    assert compiled == [(c["name"], c["unit"]) for c in DRIVER["channels"]]
    names = re.findall(r"^\s+(CH_\w+)", HEADER, re.MULTILINE)
    assert len(names) == len(DRIVER["channels"])


def test_every_loop_parameter_has_its_power_up_value():
    """driver.toml's ``[loop]`` keeps each parameter in the LOOP message or fixes it; board_config.h names a
    power-up value ``BOARD_LOOP_<KEY>`` for each, and a fixed one is driver.toml's value."""
    loop = DRIVER["loop"]
    assert list(loop) == [
        "kv_nm_per_mps",
        "ti_s",
        "kp_pos_per_s",
        "velocity_filter_hz",
        "current_loop_hz",
        "delay_ticks",
    ]
    for name, entry in loop.items():
        value = float(define(f"BOARD_LOOP_{name.upper()}").replace("INFINITY", "inf"))
        if "value" in entry:
            assert value == entry["value"], name
        else:
            assert entry == {"message": "LOOP"}, name
        assert value > 0 or name == "delay_ticks", (name, value)
