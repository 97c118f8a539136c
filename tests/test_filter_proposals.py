"""``drivers new`` proposes the ``[filters]`` table of a documented family it recognises in the EDS.

The EDS of each family (:mod:`support.filter_families`: its filter objects as
the vendor documents them) gets the family's table of docs/filter_encodings.md,
every key a placeholder; once the placeholders are confirmed, ``drivers check``
passes and the slot works on the folder's twin. Recognised from the objects
alone (no vendor ID, or an unknown one), the proposal says so; another
vendor's EDS, or one whose vendor ID is another family's, gets none.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import pytest

from hilident.cli.driver_trial import try_filter_slots
from hilident.drivers.filter_proposals import FAMILIES as RECOGNISERS
from hilident.drivers.tools import check_driver_folder, new_driver_folder
from hilident.protocol.canopen_filters import parse_filter_objects
from hilident.protocol.filter_encoding import FilterEncoding
from support.filter_families import FAMILIES
from support.vendor_drives import VendorDrive, eds_text

_UINT16, _OCTETS = 0x6, 0xA


def _eds(tmp_path: Path, drive: VendorDrive, drop: str = "") -> Path:
    path = tmp_path / f"{drive.name}.eds"
    text = eds_text(drive)
    if drop:
        assert drop in text, drop
        text = re.sub(rf"^{re.escape(drop)}.*\r?\n", "", text, flags=re.M)
    path.write_bytes(text.encode("latin-1"))
    return path


def _new(tmp_path: Path, drive: VendorDrive, drop: str = ""):
    report = new_driver_folder(_eds(tmp_path, drive, drop), tmp_path / "out" / drive.name)
    return report, (report.folder / "driver.toml").read_text()


def _confirm_filters(folder: Path) -> None:
    """What a user does having checked the proposal: the PLACEHOLDER marks of the filter keys and their names in
    [driver] placeholders removed."""
    path = folder / "driver.toml"
    text = path.read_text()
    data = tomllib.loads(text)
    keep = [p for p in data["driver"]["placeholders"] if not (p.startswith("filters") or p == "board.filter_slots")]
    lines, table = [], ""
    for line in text.splitlines():
        if m := re.match(r"\[([^\]]+)\]", line):
            table = m.group(1)
        if table.startswith("filters") or line.startswith("filter_slots"):
            line = re.sub(r"\s*# PLACEHOLDER:.*$", "", line)
        lines.append(line)
    text = "\n".join(lines) + "\n"
    text = re.sub(r"^placeholders = \[.*\]$", "placeholders = " + str(keep).replace("'", '"'), text, flags=re.M)
    path.write_text(text)


@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_drivers_new_proposes_the_documented_table_as_placeholders(tmp_path, name):
    drive = FAMILIES[name]
    report, text = _new(tmp_path, drive)
    assert report.proposal is not None and report.proposal.by_vendor
    data = tomllib.loads(text)
    assert data["filters"] == tomllib.loads(drive.filter_table)["filters"]  # the table of docs/filter_encodings.md
    assert data["board"]["filter_slots"] == drive.filter_slots
    proposed = [p for p in report.placeholders if p.startswith("filters")]
    assert "filters.encoding" in proposed and "board.filter_slots" in report.placeholders
    assert f"recognised by vendor ID 0x{drive.vendor_number:08X}" in text
    # a placeholder is listed where it is set, with where its value comes from
    check = check_driver_folder(report.folder)
    assert check.ok, check.errors
    assert set(proposed) <= set(check.placeholders)
    assert not [w for w in check.warnings if "PLACEHOLDER" in w or "not a key" in w], check.warnings


@pytest.mark.twin
@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_a_confirmed_proposal_passes_check_and_works_on_the_twin(tmp_path, name):
    report, _ = _new(tmp_path, FAMILIES[name])
    _confirm_filters(report.folder)
    check = check_driver_folder(report.folder)
    assert check.ok, check.errors
    assert not [p for p in check.placeholders if p.startswith("filters") or p == "board.filter_slots"]
    assert not [w for w in check.warnings if "[driver.placeholders]" in w], check.warnings
    trial = try_filter_slots(report.folder)
    assert trial.tried and trial.errors == (), trial.errors


def _other_vendor() -> VendorDrive:
    """Another vendor's drive with objects at the families' indices that are something else (as real EDS files
    have them: a jerk time at 0x2023, a record of user variables at 0x2106)."""
    return VendorDrive(
        "other-vendor",
        vendor="Other Motion",
        vendor_number=0x0000009A,
        vendor_objects=[
            (0x2023, None, "Jerk time", _UINT16, "rw", False, 0),
            (0x2106, 0, "Highest sub-index supported", 0x5, "ro", False, 1),
            (0x2106, 1, "User variable 1", 0x4, "rw", False, 0),
        ],
    )


@pytest.mark.parametrize("drive", [_other_vendor(), VendorDrive("acme-plain")], ids=["other-objects", "plain"])
def test_another_vendors_eds_gets_no_proposal(tmp_path, drive):
    report, text = _new(tmp_path, drive)
    assert report.proposal is None
    assert "[filters" not in text and tomllib.loads(text)["board"]["filter_slots"] == 0
    assert not [p for p in report.placeholders if p.startswith("filters")]


def test_objects_of_a_family_under_another_familys_vendor_id_get_no_proposal(tmp_path):
    drive = dataclasses.replace(FAMILIES["synapticon-somanet"], vendor_number=0x000000AB)  # Copley's
    report, _ = _new(tmp_path, drive)
    assert report.proposal is None


@pytest.mark.parametrize(
    ("vendor_number", "drop", "says"),
    [
        (0x0000009A, "", "gives vendor ID 0x0000009A, not the family's"),
        (0, "VendorNumber=", "gives no vendor ID"),
    ],
    ids=["unknown-vendor", "no-vendor"],
)
def test_objects_alone_make_a_proposal_that_says_so(tmp_path, vendor_number, drop, says):
    drive = dataclasses.replace(FAMILIES["kollmorgen-akd"], vendor_number=vendor_number)
    report, text = _new(tmp_path, drive, drop)
    assert report.proposal is not None and not report.proposal.by_vendor
    assert "filters.encoding" in report.placeholders
    assert says in text and "only" in text and "confirm the drive is one" in text


def test_the_vendor_id_is_read_from_the_identity_object_when_device_info_gives_none(tmp_path):
    report, text = _new(tmp_path, FAMILIES["synapticon-somanet"], drop="VendorNumber=")
    assert report.proposal is not None and report.proposal.by_vendor  # 0x1018:1's default
    assert "recognised by vendor ID 0x000022D2" in text


def test_a_first_generation_copley_block_gets_the_nine_word_preset(tmp_path):
    block = bytes.fromhex("FFFF") + bytes(16)  # 9 words, disabled: the first generation's size
    objects = [(0x2106, None, "Velocity loop output filter coefficients", _OCTETS, "rw", False, block)]
    drive = dataclasses.replace(FAMILIES["copley-plus"], name="copley-first", vendor_objects=objects)
    report, text = _new(tmp_path, drive)
    assert report.proposal is not None and tomllib.loads(text)["filters"]["preset"] == "copley"
    assert check_driver_folder(report.folder).ok


@pytest.mark.parametrize("family", RECOGNISERS, ids=lambda f: f.name)
def test_every_proposed_table_is_one_the_encodings_read(family):
    text = "\n".join(f"[{table}]\n" + "\n".join(f"{k} = {v}" for k, v, _ in keys) for table, keys in family.tables)
    table = tomllib.loads(text)["filters"]
    encoding = FilterEncoding.from_table(table)
    objects = parse_filter_objects(table)
    assert objects is not None and objects.count >= family.filter_slots
    assert all(source for _, keys in family.tables for _, _, source in keys)  # each value says where it is from
    assert set(encoding.fields) <= set(objects.slots[0])


def _changed_object(name: str, index: int, object_name: str = "", data_type: int = 0) -> VendorDrive:
    """The family's drive with the filter object ``index`` renamed or of another data type."""
    drive = FAMILIES[name]
    objects = [
        (o[0], o[1], object_name or o[2], data_type or o[3], *o[4:]) if o[0] == index else o
        for o in drive.vendor_objects
    ]
    assert objects != drive.vendor_objects
    return dataclasses.replace(drive, vendor_objects=objects)


@pytest.mark.parametrize(
    "drive",
    [
        _changed_object("beckhoff-ax2000", 0x3664, data_type=0x8),  # BQFC a REAL32: not the documented Integer32
        _changed_object("beckhoff-ax2000", 0x3666, object_name="Operating mode"),  # 0x3666 is some other object
        _changed_object("ingenia-denali", 0x2582, data_type=0x7),  # Q an integer: not Ingenia's float
        _changed_object("ingenia-denali", 0x2588, object_name="Position reference filter 2 type"),
    ],
    ids=["beckhoff-real32-bqfc", "beckhoff-other-0x3666", "ingenia-integer-q", "ingenia-other-chain"],
)
def test_a_family_is_not_recognised_from_objects_of_another_type_or_name(tmp_path, drive):
    report, text = _new(tmp_path, drive)
    assert report.proposal is None and "filters" not in tomllib.loads(text)
    assert not [p for p in report.placeholders if p.startswith("filters")]
