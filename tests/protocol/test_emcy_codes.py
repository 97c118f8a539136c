"""EMCY error codes: exact CiA 301/402 names, group and class fallbacks, manufacturer codes."""

from __future__ import annotations

import pytest

from hilident.protocol import cia402
from hilident.protocol.emcy_codes import CLASSES, CODES, emcy_class, emcy_name, error_register_names


@pytest.mark.parametrize(
    "code, name",
    [
        (0x0000, "error reset or no error"),
        (0x1000, "generic error"),
        (0x2311, "continuous over-current No. 1"),
        (0x3210, "DC link over-voltage"),
        (0x4310, "excess temperature, drive"),
        (0x5530, "EEPROM"),
        (0x6010, "software reset (watchdog)"),
        (0x6307, "data record No. 7"),
        (0x7305, "incremental sensor 1 fault"),
        (0x8110, "CAN overrun (objects lost)"),
        (0x8120, "CAN in error passive mode"),
        (0x8130, "life guard or heartbeat error"),
        (0x8140, "recovered from bus off"),
        (0x8150, "CAN-ID collision"),
        (0x8210, "PDO not processed due to length error"),
        (0x8220, "PDO length exceeded"),
        (0x8250, "RPDO timeout"),
        (0x8311, "excess torque"),
        (0x8400, "velocity/speed controller"),
        (0x8611, "following error"),
        (0x8612, "reference limit"),
        (0x9000, "external error"),
    ],
)
def test_a_listed_code_has_its_own_name(code, name):
    assert emcy_name(code) == name
    assert cia402.emcy_meaning(code) == name


@pytest.mark.parametrize(
    "code, name",
    [
        (0x2315, "continuous over-current (group 0x231x)"),  # a sub-code CiA 402 does not list
        (0x2399, "current, device output side (group 0x23xx)"),
        (0x8214, "PDO not processed due to length error (group 0x821x)"),  # per-PDO sub-codes some stacks send
        (0x8314, "torque control (group 0x83xx)"),
        (0x8A07, "control (group 0x8Axx)"),
        (0x0042, "error reset or no error (group 0x00xx)"),
        (0xF003, "additional functions (group 0xF0xx)"),
    ],
)
def test_an_unlisted_code_falls_back_to_its_group(code, name):
    assert emcy_name(code) == name


@pytest.mark.parametrize(
    "code, name",
    [
        (0x2F00, "current (class 0x2xxx)"),
        (0x3E01, "voltage (class 0x3xxx)"),
        (0x4900, "temperature (class 0x4xxx)"),
        (0x5F12, "device hardware (class 0x5xxx)"),
        (0x6A00, "device software (class 0x6xxx)"),
        (0x7F00, "additional modules (class 0x7xxx)"),
        (0x8F01, "monitoring (class 0x8xxx)"),
    ],
)
def test_a_code_outside_any_group_falls_back_to_its_class(code, name):
    assert emcy_name(code) == name


@pytest.mark.parametrize("code", [0xFF00, 0xFF01, 0xFF42, 0xFFFF])
def test_ff00_to_ffff_are_the_manufacturers(code):
    assert emcy_name(code) == f"manufacturer-specific 0x{code:04X} (device specific)"
    assert emcy_class(code) == "device specific"


@pytest.mark.parametrize("code", [0x0100, 0x1234, 0x9100, 0xA000, 0xE123, 0xF100, 0xFEFF])
def test_codes_no_class_covers_are_reserved(code):
    assert emcy_name(code) == f"reserved code 0x{code:04X}"
    assert emcy_class(code) == "reserved"


def test_every_class_and_group_entry_resolves_to_itself_and_every_code_to_its_class():
    for code, name in CODES.items():
        assert emcy_name(code) == name
        assert emcy_class(code) != "reserved", hex(code)
    assert [emcy_class(value) for value, _, _ in CLASSES] == [name for _, _, name in CLASSES]


@pytest.mark.parametrize("bad", [-1, 0x10000, 1.5, "0x8130", None, True])
def test_a_value_that_is_no_error_code_is_refused(bad):
    with pytest.raises(ValueError, match="0x0000-0xFFFF"):
        emcy_name(bad)
    assert "invalid error code" in cia402.emcy_meaning(bad)  # for messages: never raises


def test_error_register_bits():
    assert error_register_names(0) == []
    assert error_register_names(0x01) == ["generic error"]
    assert error_register_names(0x92) == ["current", "communication error", "manufacturer-specific"]
    with pytest.raises(ValueError):
        error_register_names(0x100)
