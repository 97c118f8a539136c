"""The notch on vendor filter objects as vendors document them: Copley's word block, Synapticon's record,
Kollmorgen's field-major AR filters.

Each folder is written by :mod:`support.filter_families` (an EDS modelled on
the documented objects, the ``[filters]`` table of docs/filter_encodings.md, a
README citing the sources); ``drivers check`` passes it as written and refuses
a wrong table naming the key and the object, and the twin built from it runs
the whole session: the notch designed at the drive's filter rate, realised on
its grid, written, read back, enabled and verified.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w

from hilident.drivers.tools import check_driver_folder
from hilident.session.run import Session
from support.filter_families import FAMILIES
from support.vendor_drives import write_vendor_drive
from test_canopen_vendor_drives import CONFIG, session_config

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
    raw["excitation"].update(period_s=1.0, duration_s=5.0, amplitude_nm=8.0)
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
