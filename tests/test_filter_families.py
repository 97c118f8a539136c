"""The notch on vendor filter objects as vendors document them: Copley's word block, Synapticon's record,
Kollmorgen's field-major AR filters, Beckhoff AX2000's bi-quad and Ingenia's current reference biquads.

Each folder is written by :mod:`support.filter_families` (an EDS modelled on
the documented objects, the ``[filters]`` table of docs/filter_encodings.md, a
README citing the sources); ``drivers check`` passes it as written and refuses
a wrong table naming the key and the object, and the twin built from it runs
the whole session: the notch designed at the drive's filter rate, realised on
its grid, written, read back, enabled and verified. For Beckhoff and Ingenia
``drivers new`` writes the folder from the EDS first: with only its
placeholders edited it passes ``drivers check`` and the trial on a twin, and
its ``[filters]`` table is the one the session then runs with.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w

from hilident.cli.driver_trial import try_filter_slots
from hilident.cli.main import main
from hilident.drivers.tools import check_driver_folder, new_driver_folder
from hilident.session.run import Session
from support.filter_families import FAMILIES, family_folder
from support.vendor_drives import eds_text, write_vendor_drive
from test_canopen_vendor_drives import CONFIG, session_config
from test_filter_proposals import _confirm_filters

pytestmark = pytest.mark.twin


def _checked_folder(tmp_path: Path, name: str) -> Path:
    folder = write_vendor_drive(tmp_path / "drivers", FAMILIES[name])
    report = check_driver_folder(folder)
    assert report.ok, report.errors
    return folder


def _assert_notch_verified(upload: dict, verification: dict, warnings: list) -> None:
    assert upload["written"] and upload["verified_readback"], warnings
    (slot,) = upload["slots"]
    assert slot["matches"] and len(slot["readback_b"]) == 3  # read back as the drive's encoding stored it
    achieved = slot["achieved"]
    # at least 20 dB off the resonance, or the drive's grid falls short and the session says by how much
    assert verification["peak_reduction_db"] >= 20.0 or achieved["quantisation_loss_db"] > 0.5
    if achieved["quantisation_loss_db"] > 0.5:
        assert any(w.startswith("filter slot 0:") for w in warnings), warnings


# the first-generation Copley block runs its whole session in test_canopen_vendor_drives.py ("copley")
@pytest.mark.parametrize("name", ["synapticon-somanet", "kollmorgen-akd"])
def test_a_documented_family_runs_the_whole_session_on_its_twin(tmp_path, name):
    folder = _checked_folder(tmp_path, name)
    cfg = session_config(folder, duration_s=5.0)
    session = Session(cfg, tmp_path / "out", plots=False)
    summary = session.run()
    _assert_notch_verified(summary["upload"], summary["verification"], summary["warnings"])
    biquad, enabled = session.emulator.drive.filters.read(0)  # what the twin's torque command runs through
    assert enabled and list(biquad.b) == summary["upload"]["slots"][0]["readback_b"]


def test_the_copley_plus_block_goes_through_hilident_run_without_a_traceback(tmp_path):
    # the path: an OCTET_STRING 0x2106 without a default, the table of docs/filter_encodings.md as is
    folder = _checked_folder(tmp_path, "copley-plus")
    raw = tomllib.loads(CONFIG.read_text())
    raw["device"].update(driver=str(folder), acquisition="streamed")
    raw["run"]["sample_rate_hz"] = 250.0
    raw["emulator"]["time_scale"] = 20.0
    raw["friction_test"] = {"enabled": False}
    # six periods: a busy machine holds back set-points (each a held torque that sets the mode ringing)
    raw["excitation"].update(period_s=1.0, duration_s=6.0, amplitude_nm=8.0)
    config = tmp_path / "copley.toml"
    config.write_text(tomli_w.dumps(raw))
    out = subprocess.run(
        [sys.executable, "-m", "hilident.cli", "run", str(config), "--out", str(tmp_path / "o"), "-q", "--yes"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr and "Traceback" not in out.stdout
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    _assert_notch_verified(summary["upload"], summary["verification"], summary["warnings"])


def _folder_for_the_session(tmp_path: Path, name: str) -> Path:
    """The family's folder, after ``drivers new`` on its EDS proposed the same ``[filters]`` table.

    ``drivers new``, then what a user does with the manual at hand: the proposed ``[filters]`` keys confirmed,
    the guessed loop rate, sample rate and position unit set to the drive's; ``drivers check`` and its trial
    pass. The session runs on the family's own folder, which holds that table and a drive that produces SYNC
    (``[canopen.sync]``, from a manual: an EDS cannot tell ``drivers new``), as a clock kept by the host's loop
    skips cycles on a busy test machine.
    """
    drive = FAMILIES[name]
    eds = tmp_path / f"{name}.eds"
    eds.write_bytes(eds_text(drive).encode("latin-1"))
    report = new_driver_folder(eds, tmp_path / "drivers" / name)
    assert report.proposal is not None and report.proposal.by_vendor
    _confirm_filters(report.folder)
    path = report.folder / "driver.toml"
    text = path.read_text()
    for key, value in (
        ("loop_rate_hz", drive.loop_rate_hz),
        ("max_sample_rate_hz", drive.max_sample_rate_hz),
        ("position_unit_m", 1e-7),
    ):
        text, edits = re.subn(rf"^{key} = .*# PLACEHOLDER.*$", f"{key} = {value}", text, flags=re.M)
        assert edits == 1, key
    path.write_text(text)
    check = check_driver_folder(report.folder)
    assert check.ok, check.errors
    trial = try_filter_slots(report.folder)  # what `drivers check` tries on a throw-away twin
    assert trial.tried and trial.errors == (), trial.errors
    folder = write_vendor_drive(tmp_path / "family", drive)
    proposed, written = (tomllib.loads((f / "driver.toml").read_text()) for f in (report.folder, folder))
    assert proposed["filters"] == written["filters"]
    assert proposed["board"]["loop_rate_hz"] == written["board"]["loop_rate_hz"]
    return folder


def _session(tmp_path: Path, folder: Path) -> tuple[Session, dict]:
    session = Session(session_config(folder, duration_s=5.0), tmp_path / "out", plots=False)
    summary = session.run()
    upload = summary["upload"]
    assert upload["written"] and upload["verified_readback"], summary["warnings"]
    biquad, enabled = session.emulator.drive.filters.read(0)  # what the twin's torque command runs through
    assert enabled and list(biquad.b) == upload["slots"][0]["readback_b"]
    return session, summary


def test_ingenia_from_drivers_new_to_run_cuts_the_resonance_band_20_db(tmp_path):
    session, summary = _session(tmp_path, _folder_for_the_session(tmp_path, "ingenia-denali"))
    fw = session.emulator.server.firmware
    # filter 1 runs as a notch on FREQ and Q; GAIN keeps its default, filter 2 stays disabled
    assert fw.stored(0x2580, 0) == 5 and fw.stored(0x2583, 0) == 0.0 and fw.stored(0x2588, 0) == 0
    assert summary["verification"]["peak_reduction_db"] >= 20.0
    achieved = summary["upload"]["slots"][0]["achieved"]
    assert achieved["attenuation_at_design_center_db"] >= 20.0  # a full cut a fraction of a hertz off the resonance


def test_beckhoff_from_drivers_new_to_run_reaches_its_14_db_and_says_what_is_short(tmp_path):
    session, summary = _session(tmp_path, _folder_for_the_session(tmp_path, "beckhoff-ax2000"))
    fw = session.emulator.server.firmware
    # BQMODE 2 runs the bi-quad; BQFR 1 and BQDR at its highest, 5: the deepest notch the ranges allow
    assert fw.stored(0x3666, 0) == 2 and fw.stored(0x3665, 0) == 1000 and fw.stored(0x3663, 0) == 5000
    limit = 20.0 * math.log10(5.0)
    achieved = summary["upload"]["slots"][0]["achieved"]
    assert achieved["attenuation_at_design_center_db"] == pytest.approx(limit, abs=0.05)
    assert achieved["quantisation_loss_db"] > 20.0  # 40 dB designed
    assert summary["verification"]["peak_reduction_db"] >= limit - 1.0
    notes = [w for w in summary["warnings"] if w.startswith("filter slot 0:")]
    assert any("at most 14.0 dB deep" in w for w in notes) and any("not the 40 dB asked" in w for w in notes), notes


@pytest.mark.parametrize(
    ("name", "old", "new", "words"),
    [
        # BQFC's weighting of 1000 forgotten: the trial's 1000 Hz is written as 1000, below 0x3664's LowLimit
        (
            "beckhoff-ax2000",
            "scales = { center_hz = 0.001,",
            "scales = { center_hz = 1,",
            ("[filters.fields.center_hz]", "0x3664", "too low"),
        ),
        # Q in hundredths as an integer, but Ingenia's Q-factor is a float
        (
            "ingenia-denali",
            "scales = { center = 1, width = 0 }",
            "scales = { center = 1, width = 0.01 }",
            ("[filters.fields.width]", "0x2582", "REAL32", "writes an integer there"),
        ),
    ],
    ids=["beckhoff-weighting", "ingenia-q-type"],
)
def test_a_wrong_table_of_a_family_is_refused_by_drivers_check(tmp_path, capsys, name, old, new, words):
    folder = family_folder(tmp_path, FAMILIES[name], old, new)
    assert main(["drivers", "check", str(folder)]) == 2
    out = capsys.readouterr().out
    assert any(all(w in line for w in words) for line in out.splitlines()), out
    assert "Traceback" not in out
