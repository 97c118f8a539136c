"""A twin built from any EDS serves every type the EDS declares, and a failure in it is one log line.

The EDS is a vendor drive's (:mod:`support.vendor_drives`) with objects of the
types real vendor files declare beside the numeric ones: OCTET_STRING,
VISIBLE_STRING and DOMAIN with and without defaults (hex with leading zeros,
text that looks like a number), INTEGER64, UNSIGNED64 and REAL64. A plain
canopen host reads and writes them over the virtual bus.
"""

from __future__ import annotations

import logging
import struct
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from canopen.sdo import SdoAbortedError

import canopen
from hilident.config.tables import CanopenDeviceConfig, DeviceConfig, load_config
from hilident.drivers.description import load_driver
from hilident.emulator.canopen.server import start
from support.vendor_drives import VendorDrive, write_vendor_drive

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-canopen-gantry.toml"
NODE = 5
_OCTETS, _VSTRING, _DOMAIN, _INT64, _UINT64, _REAL64 = 0x0A, 0x09, 0x0F, 0x15, 0x1B, 0x11
COUNTING = bytes(range(18))  # written in the EDS as hex with leading zeros: 000102...11

DRIVE = VendorDrive(
    "acme-types",
    vendor_objects=[
        (0x2106, None, "Filter block without a default", _OCTETS, "rw", False, None),
        (0x2107, None, "Octets counting from zero", _OCTETS, "rw", False, COUNTING),
        (0x2110, None, "Text without a default", _VSTRING, "rw", False, None),
        (0x2111, None, "Text of digits", _VSTRING, "rw", False, "0042"),
        (0x2112, None, "Domain without a default", _DOMAIN, "rw", False, None),
        (0x2113, None, "Signed 64", _INT64, "rw", False, -5),
        (0x2114, None, "Unsigned 64", _UINT64, "rw", False, 2**40),
        (0x2115, None, "Real 64", _REAL64, "rw", False, 1.5),
    ],
)


@pytest.fixture
def twin(tmp_path):
    folder = write_vendor_drive(tmp_path, DRIVE)
    driver = load_driver(folder)
    emu = replace(load_config(CONFIG).emulator, time_scale=10.0)
    emulated = start(emu, driver, DeviceConfig(driver=str(folder), canopen=CanopenDeviceConfig(node_id=NODE)))
    network = canopen.Network()
    network.connect(interface=emulated.device.canopen.can_interface, channel=emulated.device.port)
    node = network.add_node(NODE, str(folder / "acme-types.eds"))
    yield node.sdo, emulated
    network.disconnect()
    emulated.close()


def test_every_declared_type_is_served_as_declared(twin):
    sdo, _ = twin
    assert sdo.upload(0x2107, 0) == COUNTING  # hex digits with leading zeros are bytes, not a number
    assert sdo.upload(0x2111, 0) == b"0042"  # digits in a string are text
    for index in (0x2106, 0x2110, 0x2112):  # no default: the drive says something, as a drive does
        assert len(sdo.upload(index, 0)) > 0
    assert struct.unpack("<q", sdo.upload(0x2113, 0)) == (-5,)
    assert struct.unpack("<Q", sdo.upload(0x2114, 0)) == (2**40,)
    assert struct.unpack("<d", sdo.upload(0x2115, 0)) == (1.5,)
    for index, value in (
        (0x2106, bytes(28)),
        (0x2112, b"\x01" * 300),  # segmented
        (0x2113, struct.pack("<q", -(2**62))),
        (0x2114, struct.pack("<Q", 2**64 - 1)),
        (0x2115, struct.pack("<d", -2.25e-3)),
        (0x2110, b"written"),
    ):
        sdo.download(index, 0, value)
        assert sdo.upload(index, 0) == value


def test_a_failure_in_the_twin_is_an_abort_and_one_log_line_naming_the_object(twin, caplog, monkeypatch):
    sdo, emulated = twin

    def broken(index, subindex, od):
        raise RuntimeError("broken object")

    monkeypatch.setattr(emulated.server.firmware.objects, "unset_value", broken)
    with caplog.at_level(logging.DEBUG), pytest.raises(SdoAbortedError) as err:
        sdo.upload(0x2106, 0)
    assert err.value.code == 0x08000000
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and warnings[0].exc_info is None, warnings
    assert "0x2106:0" in warnings[0].getMessage() and "RuntimeError: broken object" in warnings[0].getMessage()
    assert any(r.levelno == logging.DEBUG and r.exc_info for r in caplog.records)  # the traceback, for --log-level
    monkeypatch.undo()
    assert sdo.upload(0x2107, 0) == COUNTING  # the server goes on


_LOG_SOMETHING = """
import logging, sys
from hilident.cli.main import _configure_logging, _no_last_resort
_no_last_resort()
if sys.argv[1] == "log":
    _configure_logging("warning")
try:
    raise TypeError("string argument without an encoding")
except TypeError as exc:
    logging.getLogger("canopen.sdo.server").exception(exc)
logging.getLogger("hilident.emulator.canopen.sdo").warning("SDO 0x2106:0 failed")
"""


@pytest.mark.parametrize("level", ["none", "log"])
def test_library_logs_reach_the_terminal_only_through_log_level(level):
    out = subprocess.run([sys.executable, "-c", _LOG_SOMETHING, level], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    if level == "none":
        assert out.stderr == ""  # Python's last-resort handler would print the traceback
    else:
        assert "ERROR canopen.sdo.server: string argument" in out.stderr and "SDO 0x2106:0" in out.stderr
