"""The shipped CiA 402 servo EDS files are generated, never edited twice by hand."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "generate_eds.py"


def _generator():
    spec = importlib.util.spec_from_file_location("generate_eds", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


GENERATOR = _generator()


@pytest.mark.parametrize("name", GENERATOR.GENERATED_DRIVERS)
def test_regenerating_gives_exactly_the_shipped_eds(name):
    folder = ROOT / "drivers" / name
    shipped = GENERATOR.shipped_path(folder).read_text(encoding="utf-8")
    assert GENERATOR.generate(folder) == shipped, f"run python scripts/generate_eds.py after editing {folder}"


def test_the_filter_slots_follow_the_driver_encoding():
    real = GENERATOR.generate(ROOT / "drivers" / "canopen-servo")
    fixed = GENERATOR.generate(ROOT / "drivers" / "canopen-servo-fixed")
    b0 = "[2301sub2]\nParameterName=b0\nObjectType=0x7\nDataType={}\nAccessType=rw\nDefaultValue={}\n"
    assert b0.format("0x0008", "1.0") in real and b0.format("0x0004", "0x20000000") in fixed
    assert "ProductNumber=0x00040202" in fixed and "INTEGER32 Q2.29 notch filter slots" in fixed


def test_check_mode_reports_a_hand_edited_file(tmp_path, monkeypatch, capsys):
    for name in GENERATOR.GENERATED_DRIVERS:
        copy = tmp_path / "drivers" / name
        copy.mkdir(parents=True)
        for f in (ROOT / "drivers" / name).iterdir():
            copy.joinpath(f.name).write_bytes(f.read_bytes())
    eds = GENERATOR.shipped_path(tmp_path / "drivers" / "canopen-servo")
    eds.write_text(eds.read_text().replace("DefaultValue=1.0", "DefaultValue=2.0", 1))
    monkeypatch.setattr(GENERATOR, "ROOT", tmp_path)
    assert GENERATOR.main(["--check"]) == 1
    assert "canopen-servo.eds" in capsys.readouterr().err
    assert GENERATOR.main([]) == 0 and GENERATOR.main(["--check"]) == 0
