"""What a CANopen run maps is checked against the EDS first: by ``hilident drivers check`` and before a run moves.

The drives are written by :mod:`support.vendor_drives` (vendor traits, standard
objects only); a few EDS lines are then changed the way vendor files differ:
an object not PDO-mappable, a mapping record whose sub-index 0 takes fewer
entries than it declares, a transmission type range without SYNC. The adapter
writes the plan :func:`~hilident.protocol.canopen_pdo_plan.plan_streamed_run`
computes, so the check and the run cannot disagree.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.cli.main import main
from hilident.config.tables import load_config
from hilident.drivers.description import load_driver, load_object_dictionary
from hilident.drivers.tools import check_driver_folder
from hilident.emulator.canopen.server import start
from hilident.errors import ConfigError
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_pdo_plan import RunChannel, plan_streamed_run
from hilident.protocol.canopen_types import ObjectAddress
from hilident.session.run import Session
from support.vendor_drives import VendorDrive, write_vendor_drive

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-canopen-gantry.toml"
FS = 1000.0

#: 4 TPDOs x 8 entries, the standard objects mappable but the torque demand 0x6074 (a channel the run maps).
DEMAND_FIXED = VendorDrive("acme-demand-fixed", unmappable=(0x6074,))
#: A drive the check accepts: 3 entries per PDO, two RPDOs, the period in 0x1006.
HELD_OUT = VendorDrive("acme-held-out", entries=3, rpdos=2, period="1006")


def edit_eds(folder: Path, section: str, key: str, value: str) -> None:
    """Set ``key = value`` in ``[section]`` of the folder's EDS (how a vendor file differs from the helper's)."""
    eds = next(folder.glob("*.eds"))
    text = eds.read_bytes().decode("latin-1")
    head, rest = text.split(f"[{section}]\r\n", 1)
    body, sep, tail = rest.partition("\r\n\r\n")
    lines = [line for line in body.split("\r\n") if not line.startswith(f"{key}=")] + [f"{key}={value}"]
    eds.write_bytes((head + f"[{section}]\r\n" + "\r\n".join(lines) + sep + tail).encode("latin-1"))


def session_config(folder: Path, **device):
    cfg = load_config(CONFIG)
    return replace(
        cfg,
        device=replace(cfg.device, driver=str(folder), acquisition="streamed", **device),
        emulator=replace(cfg.emulator, time_scale=20.0),
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, period_s=1.0, duration_s=2.0, amplitude_nm=8.0),
    )


def planned(folder: Path, mode: str, node_id: int = 1):
    """The plan of a streamed run of the driver folder's streamed channels, from the folder alone."""
    driver = load_driver(folder)
    od = load_object_dictionary(driver, node_id)
    desc = CanopenDescription.from_sections(driver.sections, str(folder / "driver.toml"), od)
    channels = [
        RunChannel(c.name, desc.address(role) if (role := desc.channels[c.name]) else None)
        for c in driver.streamed_channels
    ]
    return plan_streamed_run(od, desc, node_id, channels, desc.modes[mode].setpoint)


# --- the failing case: refused by the check and before the run moves ---------------------------------------------


def test_check_refuses_a_channel_whose_object_is_not_pdo_mappable_and_names_it(tmp_path):
    folder = write_vendor_drive(tmp_path, DEMAND_FIXED)
    report = check_driver_folder(folder)
    assert not report.ok
    (error,) = report.errors  # one problem, shared by every mode, told once
    assert "0x6074:0 (Torque demand)" in error and "torque_cmd_nm" in error
    assert "not PDO-mappable" in error and "run.channels" in error
    assert "[streamed run, modes torque, velocity, position, torque_injection]" in error


def test_the_run_refuses_it_at_the_plan_before_anything_moves(tmp_path, capsys):
    folder = write_vendor_drive(tmp_path, DEMAND_FIXED)
    session = Session(session_config(folder), tmp_path / "out", plots=False)
    with pytest.raises(ConfigError, match=r"0x6074:0 \(Torque demand\).*not PDO-mappable") as err:
        session.prepare()
    assert err.value.exit_code == 2 and err.value.file == str(folder / "driver.toml")
    assert session.emulator is None  # nothing was started, let alone moved


def test_drivers_check_exits_2_and_names_the_object(tmp_path, capsys):
    folder = write_vendor_drive(tmp_path, DEMAND_FIXED)
    assert main(["drivers", "check", str(folder)]) == 2
    out = capsys.readouterr()
    assert "0x6074:0 (Torque demand)" in out.out + out.err and "Traceback" not in out.out + out.err


def test_leaving_the_unmappable_channel_out_lets_the_run_map(tmp_path):
    folder = write_vendor_drive(tmp_path, DEMAND_FIXED)
    cfg = session_config(folder)
    cfg = replace(cfg, run=replace(cfg.run, channels=["excitation", "torque_nm", "position_m", "velocity_mps"]))
    Session(cfg, tmp_path / "out", plots=False).prepare()


# --- the planner: what CiA 301 has a drive refuse --------------------------------------------------------------


def test_the_mapping_record_takes_no_more_entries_than_its_sub_index_0_accepts(tmp_path):
    folder = write_vendor_drive(tmp_path, VendorDrive("acme-sub0", entries=8))
    for n in range(4):
        edit_eds(folder, f"1A0{n}sub0", "HighLimit", "0x2")
    plan = planned(folder, "torque")
    assert [len(p.entries) for p in plan.carrying] == [2, 2]  # 4 channels, two a TPDO
    assert check_driver_folder(folder).ok


def test_a_transmission_type_range_without_sync_is_refused_naming_the_object(tmp_path):
    folder = write_vendor_drive(tmp_path, VendorDrive("acme-async"))
    edit_eds(folder, "1800sub2", "LowLimit", "0xFE")
    with pytest.raises(ConfigError, match=r"0x1800:2 \(TPDO communication parameter 1: Transmission type\)"):
        planned(folder, "torque")
    report = check_driver_folder(folder)
    assert not report.ok and "choose another TPDO" in report.errors[0]


def test_more_channels_than_the_tpdos_hold_is_refused_with_what_to_change(tmp_path):
    folder = write_vendor_drive(tmp_path, VendorDrive("acme-one-tpdo", tpdos=1, entries=1))
    with pytest.raises(ConfigError, match=r"need \d PDOs; the drive has 1.*map fewer channels"):
        planned(folder, "torque")


def test_a_set_point_object_the_rpdo_cannot_take_is_refused(tmp_path):
    folder = write_vendor_drive(tmp_path, VendorDrive("acme-target-ro"))
    edit_eds(folder, "6071", "AccessType", "ro")
    with pytest.raises(ConfigError, match=r"0x6071:0 \(Target torque\).*'ro'.*RPDO needs it writable"):
        planned(folder, "torque")


# --- the held-out drive: accepted by the check, runs on its twin, mapped as planned ------------------------------


@pytest.fixture
def held_out(tmp_path):
    folder = write_vendor_drive(tmp_path, HELD_OUT)
    driver = load_driver(folder)
    cfg = load_config(CONFIG)
    emu = start(replace(cfg.emulator, time_scale=20.0), driver, replace(cfg.device, driver=str(folder)))
    ad = CanopenDriveAdapter.open_device(replace(emu.device, acquisition="streamed", timeout_s=0.5), driver)
    lim = cfg.limits
    ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
    yield folder, ad, emu
    ad.close()
    emu.close()


def test_an_accepted_drive_runs_on_its_twin_mapped_exactly_as_planned(held_out):
    folder, ad, emu = held_out
    assert check_driver_folder(folder).ok
    ad.configure(FS, "torque")
    plan = planned(folder, "torque", ad.node_id)
    assert ad.layout.pdo_plan == plan  # the adapter wrote the plan the check verified
    fw = emu.server.firmware
    for pdo in plan.tpdos + plan.rpdos:
        cfg = fw.pdos[(pdo.kind, pdo.slot.number)]
        assert [a for a, _ in cfg.entries] == [a for a, _ in pdo.entries]
        assert cfg.valid == bool(pdo.entries) and cfg.cob_id == pdo.slot.cob_id
    assert [p.columns for p in plan.carrying] == [t.columns for t in ad.layout.tpdos]
    assert plan.setpoint_pdo.entries[0][0] == ObjectAddress(0x6071)
    result = ad.stream(np.zeros(500), lambda i, rows: None)
    assert result.completed and result.stats.samples == 500 and result.stats.lost_samples == 0
