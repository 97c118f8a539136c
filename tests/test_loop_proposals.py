"""`drivers new` reads the drive's cascade from the names of its EDS's gain objects and proposes [loop].

The EDS files are written here (:mod:`support.vendor_drives`), their gain objects named as vendors name theirs:
one record of position, velocity and current gains with per-mille feed-forward (as Nanotec's 0x3210), speed and
position regulator records with P/I/D gains and feed-forward factors (as maxon's 0x60F9 and 0x60FB), and records
whose sub-indices say only the term ("Proportional Term", as Faulhaber's 0x2331). Every key proposed is a
placeholder; the twin runs the proposal, and the host reads and writes the gains through it.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import pytest

from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import load_driver
from hilident.drivers.loop_proposals import propose_loop
from hilident.drivers.tools import check_driver_folder, new_driver_folder
from hilident.emulator.canopen.server import start
from hilident.protocol.eds import load_eds_text
from support.vendor_drives import VendorDrive, eds_text

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-canopen-gantry.toml"
U16, U32, I16 = 0x6, 0x7, 0x3

ONE_RECORD = VendorDrive(  # position PI, velocity PI and current PI in one record, velocity feed-forward in per mille
    "acme-one-record",
    vendor_objects=[
        (0x3210, 1, "Position loop, proportional gain (closed loop)", U32, "rw", False, 2048),
        (0x3210, 2, "Position loop, integral gain (closed loop)", U32, "rw", False, 0),
        (0x3210, 3, "Velocity loop, proportional gain (closed loop)", U32, "rw", False, 7000),
        (0x3210, 4, "Velocity loop, integral gain (closed loop)", U32, "rw", False, 4),
        (0x3210, 5, "Torque current loop, proportional gain (closed loop)", U32, "rw", False, 420000),
        (0x3210, 6, "Torque current loop, integral gain (open loop)", U32, "rw", False, 45000),
        (0x3210, 7, "Velocity feed forward factor in per mille", U32, "rw", False, 1000),
    ],
    record_names={0x3210: "Motor drive parameter set"},
)
REGULATORS = VendorDrive(  # speed PI with its own feed-forward, a position PID with its own
    "acme-regulators",
    vendor_objects=[
        (0x60F9, 1, "Speed Regulator P-Gain", I16, "rw", False, 1000),
        (0x60F9, 2, "Speed Regulator I-Gain", I16, "rw", False, 100),
        (0x60F9, 4, "Velocity Feedforward Factor in Speed Regulator", U16, "rw", False, 0),
        (0x60F9, 5, "Acceleration Feedforward Factor in Speed Regulator", U16, "rw", False, 0),
        (0x60FB, 1, "Position Regulator P-Gain", I16, "rw", False, 150),
        (0x60FB, 3, "Position Regulator D-Gain", I16, "rw", False, 200),
        (0x60FB, 4, "Velocity Feedforward Factor in Position Regulator", U16, "rw", False, 0),
    ],
    record_names={0x60F9: "Velocity Control Parameter Set", 0x60FB: "Position Control Parameter Set"},
)
TERMS_ONLY = VendorDrive(  # the record names the loop, the sub-index only the term; an integral time, not a gain
    "acme-terms",
    vendor_objects=[
        (0x2331, 1, "Proportional Term POR", U16, "rw", False, 6),
        (0x2331, 2, "Integral Time Tn", U16, "rw", False, 50),
        (0x2332, 1, "Proportional Term PP", U16, "rw", False, 10),
        (0x2340, 1, "Analog input gain", U16, "rw", False, 1),
    ],
    record_names={0x2331: "Velocity Control Parameter Set", 0x2332: "Position Control Parameter Set"},
)


def _proposal(drive: VendorDrive):
    od, _ = load_eds_text(eds_text(drive), f"{drive.name}.eds")
    proposal = propose_loop(od)
    assert proposal is not None
    return {key: value for key, value, _ in proposal.keys}, " ".join(proposal.notes)


def test_one_record_of_gains_gives_the_velocity_pi_as_gains_and_says_what_the_cascade_leaves_out():
    keys, notes = _proposal(ONE_RECORD)
    assert keys["kv_nm_per_mps"] == '{ object = "0x3210:3", scale = 1.0 }'
    assert keys["ki_nm_per_m"] == '{ object = "0x3210:4", scale = 1.0 }' and "ti_s" not in keys
    assert keys["kp_pos_per_s"] == '{ object = "0x3210:1", scale = 1.0 }'
    assert keys["velocity_feedforward"] == '{ object = "0x3210:7", scale = 0.001 }'  # per mille
    assert keys["ki_pos_per_s2"] == '{ object = "0x3210:2", scale = 1.0 }'  # a PI position loop
    assert "0x3210:5" in notes and "current loop gain" in notes
    assert "0x3210:6" not in notes  # an open-loop gain is none of the running cascade's


def test_a_feedforward_term_belongs_to_the_regulator_it_is_in_and_a_position_d_term_is_flagged():
    keys, notes = _proposal(REGULATORS)
    assert keys["viscous_feedforward_nm_per_mps"] == '{ object = "0x60F9:4", scale = 1.0 }'
    assert keys["accel_feedforward_nm_per_mps2"] == '{ object = "0x60F9:5", scale = 1.0 }'
    assert keys["velocity_feedforward"] == '{ object = "0x60FB:4", scale = 1.0 }'
    assert keys["kd_pos"] == '{ object = "0x60FB:3", scale = 1.0 }' and "ki_pos_per_s2" not in keys
    assert "D term" in notes and "block diagram" in notes


def test_a_record_names_the_loop_of_its_terms_and_an_integral_time_stays_a_time():
    keys, notes = _proposal(TERMS_ONLY)
    assert keys["kv_nm_per_mps"] == '{ object = "0x2331:1", scale = 1.0 }'
    assert keys["ti_s"] == '{ object = "0x2331:2", scale = 1.0 }' and "ki_nm_per_m" not in keys
    assert keys["kp_pos_per_s"] == '{ object = "0x2332:1", scale = 1.0 }'
    assert "0x2340" not in notes


def test_without_a_velocity_p_and_i_there_is_no_loop_to_propose():
    drive = replace(TERMS_ONLY, name="acme-p-only", vendor_objects=TERMS_ONLY.vendor_objects[:1])
    od, _ = load_eds_text(eds_text(drive), "p-only.eds")
    assert propose_loop(od) is None


@pytest.fixture
def proposed_folder(tmp_path):
    eds = tmp_path / f"{ONE_RECORD.name}.eds"
    eds.write_bytes(eds_text(ONE_RECORD).encode("latin-1"))
    report = new_driver_folder(eds, tmp_path / "drv")
    return report.folder


def test_the_proposal_is_placeholders_that_check_accepts_and_check_refuses_a_loop_object_it_cannot_write(
    proposed_folder,
):
    data = tomllib.loads((proposed_folder / "driver.toml").read_text())
    loop_keys = {p for p in data["driver"]["placeholders"] if p.startswith("loop.")}
    assert loop_keys == {f"loop.{k}" for k in data["loop"]}
    assert check_driver_folder(proposed_folder).ok
    read_only = [o if o[1] != 3 else (*o[:4], "ro", *o[5:]) for o in ONE_RECORD.vendor_objects]
    eds = next(proposed_folder.glob("*.eds"))
    eds.write_bytes(eds_text(replace(ONE_RECORD, vendor_objects=read_only)).encode("latin-1"))
    errors = " ".join(check_driver_folder(proposed_folder).errors)
    assert "[loop.kv_nm_per_mps.object] 0x3210:3 is 'ro' in the EDS; the host writes kv_nm_per_mps" in errors


def test_the_twin_runs_the_proposed_loop_and_the_host_tunes_it_in_the_cascades_terms(proposed_folder):
    cfg = load_config(CONFIG)
    driver = load_driver(proposed_folder)
    emulated = start(replace(cfg.emulator, time_scale=20.0), driver, replace(cfg.device, driver=str(proposed_folder)))
    adapter = CanopenDriveAdapter.open_device(replace(emulated.device, acquisition="streamed", timeout_s=0.5), driver)
    try:
        tuning = emulated.drive.tuning
        values = adapter.read_loop()
        assert values["kv_nm_per_mps"] == tuning.kv_nm_per_mps  # UNSIGNED32 at scale 1 holds the twin's 100
        assert values["ti_s"] == pytest.approx(tuning.ti_s, rel=1e-3)
        assert values["velocity_feedforward"] == tuning.velocity_feedforward
        adapter.write_loop({"kv_nm_per_mps": 250.0, "ti_s": 0.1, "velocity_feedforward": 0.85})
        assert emulated.drive.tuning.kv_nm_per_mps == 250.0
        assert emulated.drive.tuning.ti_s == pytest.approx(0.1)  # ki = 2500 whole units
        assert emulated.drive.tuning.velocity_feedforward == pytest.approx(0.85)  # 850 per mille
    finally:
        adapter.close()
        emulated.close()
