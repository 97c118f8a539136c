"""``drivers check`` of a ``[filters]`` table against the EDS's own object structure, without a twin.

The documented families' folders (:mod:`support.filter_families`) pass as
written; a table that cannot work on the drive is refused naming the key and
the object: a word block whose size is not the object's, a field on a
sub-index the record does not have, a REAL32 written into an UNSIGNED32, an
enable value the enable object cannot hold, two fields on one object.
"""

from __future__ import annotations

import pytest

from hilident.drivers.tools import check_driver_folder
from support.filter_families import FAMILIES, family_folder


def _folder(tmp_path, name: str, old: str = "", new: str = ""):
    return family_folder(tmp_path, FAMILIES[name], old, new)


@pytest.mark.parametrize("name", sorted(FAMILIES))
def test_the_documented_tables_pass_check_as_written(tmp_path, name):
    report = check_driver_folder(_folder(tmp_path, name))
    assert report.ok, report.errors
    assert not [w for w in report.warnings if "[filters" in w], report.warnings


@pytest.mark.parametrize(
    ("name", "old", "new", "words"),
    [
        # a word block carries its own enable: nothing is asked of a sub-index, but the size must be the object's
        ("copley-plus", 'objects = ["0x2106"]', 'objects = ["0x2108"]', ()),
        (
            "copley-plus",
            'preset = "copley_plus"\nobjects = ["0x2106"]',
            'preset = "copley"\nobjects = ["0x2108"]',
            ("[filters.objects]", "0x2108", "28 bytes", "18 bytes"),
        ),
        (
            "copley-plus",
            'objects = ["0x2106"]',
            'objects = ["0x6041"]',
            ("[filters.objects]", "0x6041", "UNSIGNED16", "OCTET_STRING"),
        ),
        (
            "synapticon-somanet",
            "band = 3 }",
            "band = 4 }",
            ("[filters.fields.band]", "0x2023:4 is not in the EDS"),
        ),
        (
            "synapticon-somanet",
            "enable_subindex = 1",
            "enable_subindex = 1\nenable_values = { on = 2, off = 0 }",
            ("[filters.enable_values]", "0x2023:1", "BOOLEAN"),
        ),
        (
            "kollmorgen-akd",
            "scales = { pole_hz = 0.001, pole_q = 0.001, zero_hz = 0.001, zero_q = 0.001 }\n",
            "",
            ("[filters.fields.pole_hz]", "0x3406:1 (VL.ARPF1) is UNSIGNED32", "REAL32"),
        ),
        (
            "kollmorgen-akd",
            'zero_q = ["0x3406:0xD", "0x3406:0xE"]',
            'zero_q = ["0x3406:0xD", "0x3406:0x9"]',
            ("[filters.fields.zero_q]", "0x3406:9 holds fields.zero_hz"),
        ),
        (
            "synapticon-somanet",
            "fields = { center = 2, band = 3 }",
            "fields = { center = 2 }",
            ("[filters.fields.band] is not given",),
        ),
    ],
)
def test_a_wrong_table_is_refused_naming_the_key_and_the_object(tmp_path, name, old, new, words):
    report = check_driver_folder(_folder(tmp_path, name, old, new))
    if not words:
        assert report.ok, report.errors
        return
    assert not report.ok
    assert any(all(w in e for w in words) for e in report.errors), report.errors
