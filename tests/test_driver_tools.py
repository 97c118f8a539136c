"""`hilident drivers new` / `drivers check` / `drivers -v` on driver folders written from fixture EDS files."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import pytest

from hilident.cli.main import main
from hilident.drivers.tools import check_driver_folder, describe_driver, new_driver_folder
from hilident.errors import ConfigError, UsageError

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "eds"
ALL = sorted(p.name for p in FIXTURES.iterdir())


def new(tmp_path, fixture, **kw):
    report = new_driver_folder(FIXTURES / fixture, tmp_path / "drv", **kw)
    text = (report.folder / "driver.toml").read_text(encoding="utf-8")
    return report, text, tomllib.loads(text)


def edit(folder: Path, old: str, new_text: str) -> None:
    path = folder / "driver.toml"
    text = path.read_text(encoding="utf-8")
    assert old in text, old
    path.write_text(text.replace(old, new_text, 1), encoding="utf-8")


def marked(text: str) -> list[str]:
    """Dotted keys whose line carries a PLACEHOLDER comment."""
    keys, table = [], ""
    for line in text.splitlines():
        if m := re.match(r"\[([^\]]+)\]", line):
            table = m.group(1)
        elif m := re.match(r"(\w+) = .*# PLACEHOLDER: \S", line):
            keys.append(f"{table}.{m.group(1)}")
    return keys


@pytest.mark.parametrize("fixture", ALL)
def test_every_fixture_gets_a_folder_that_parses_passes_check_and_lists_each_placeholder(tmp_path, fixture):
    report, text, data = new(tmp_path, fixture)
    assert (report.folder / fixture).read_bytes() == (FIXTURES / fixture).read_bytes()
    assert data["canopen"]["eds"] == fixture and data["driver"]["transport"] == "canopen"
    assert data["driver"]["placeholders"] == marked(text) == list(report.placeholders)
    assert "board.loop_rate_hz" in report.placeholders and "canopen.scaling.position_unit_m" in report.placeholders
    check = check_driver_folder(report.folder)
    assert check.ok, check.errors
    assert check.placeholders == report.placeholders


def test_limits_modes_and_period_of_a_four_entry_two_rpdo_drive(tmp_path):
    _, text, data = new(tmp_path, "pdo4_rpdo2.eds", name="four")
    assert data["driver"]["name"] == "four"
    assert data["canopen"]["cyclic_modes"] == ["cst", "csv", "csp"]
    assert "2 RPDOs x up to 4 entries, 4 TPDOs x up to 4 entries" in text
    assert data["board"]["loop_rate_hz"] == 1000.0  # 0x60C2 default: 1 ms
    assert "emulator" not in data  # 0x6502 has a default: the twin reads it from the EDS
    assert data["canopen"]["save"]["object"] == "0x1010:1"
    assert data["driver"]["default_baudrate"] == 1_000_000  # [DeviceInfo] BaudRate_1000=1, BaudRate_500=1


def test_an_8_ms_ip_only_drive_with_vendor_recorder_and_generator_listed_for_the_user(tmp_path):
    _, text, data = new(tmp_path, "period_60c2_8ms.eds")
    assert data["canopen"]["cyclic_modes"] == ["ip"]
    assert data["board"]["loop_rate_hz"] == 1000.0  # 8 ms is the default, not the fastest period
    assert "loop_rate_hz = 1000.0  # PLACEHOLDER: the default period of 0x60C2 is 8 ms;" in text
    assert "0x60C2 (value 8, exponent -3: 8 ms by default)" in text
    assert "#   0x2010 Data recorder control" in text and "#   0x2050 PRBS excitation amplitude" in text
    assert data["board"]["filter_slots"] == 0


def test_current_only_drive_asks_for_kt_and_takes_the_position_unit_from_the_feed_constant(tmp_path):
    report, _, data = new(tmp_path, "current_only.eds")
    scaling = data["canopen"]["scaling"]
    assert "torque_constant_nm_per_a" in scaling and "rated_torque_nm" not in scaling
    assert "rated_current_a" not in scaling  # 0x6075 has a default (5000 mA)
    assert scaling["position_unit_m"] == pytest.approx(2 * math.pi / 10000, rel=1e-5)  # 0x6092: 10000 per shaft rev
    assert "canopen.scaling.torque_constant_nm_per_a" in report.placeholders


def test_without_a_6502_default_the_twin_gets_placeholder_modes_and_check_warns(tmp_path):
    report, _, data = new(tmp_path, "no_6502_default.eds")
    assert data["emulator"]["supported_modes"] == ["cst", "csv", "csp", "ip"]
    assert "emulator.supported_modes" in report.placeholders
    assert "canopen.scaling.rated_torque_nm" in report.placeholders  # 0x6076 defaults to 0
    check = check_driver_folder(report.folder)
    assert check.ok and any("0x6502 has no default" in w for w in check.warnings)


def test_check_warns_that_a_drive_without_a_cyclic_mode_cannot_be_excited(tmp_path):
    eds = tmp_path / "profile_only.eds"  # 0x6502: profile position, velocity and torque only (bits 0, 2, 3)
    text = (FIXTURES / "pdo4_rpdo2.eds").read_text(encoding="utf-8")
    assert "DefaultValue=0x000003A5" in text
    eds.write_text(text.replace("DefaultValue=0x000003A5", "DefaultValue=0x0000000D"), encoding="utf-8")
    report = new_driver_folder(eds, tmp_path / "drv")
    assert "cyclic_modes =" not in (report.folder / "driver.toml").read_text(encoding="utf-8")
    check = check_driver_folder(report.folder)
    assert any("no cyclic mode" in w and "cannot excite it" in w for w in check.warnings), check.warnings
    # a drive with cyclic modes gets no such warning
    assert not any(
        "no cyclic mode" in w for w in check_driver_folder(new(tmp_path / "b", "pdo4_rpdo2.eds")[0].folder).warnings
    )


def test_the_eds_quirks_are_written_as_comments_naming_the_file_not_where_it_was_read(tmp_path):
    _, text, data = new(tmp_path, "quirks_dup_lower_crlf.eds")
    assert "#   quirks_dup_lower_crlf.eds: line 1104 [6041]: duplicate key 'ObjectType'" in text
    assert str(FIXTURES) not in text
    assert "Müller" in data["driver"]["description"]
    assert "#   0x2300 Notch filter 1" in text
    assert data["driver"]["default_baudrate"] == 500_000  # BaudRate_1000=0, BaudRate_500=1


def test_a_dcf_gets_its_configured_period(tmp_path):
    _, text, data = new(tmp_path, "configured.dcf")
    assert "0x60C2 (value 2, exponent -3: 2 ms by default)" in text  # ParameterValue 2, DefaultValue 1
    assert data["canopen"]["eds"] == "configured.dcf"


def test_a_drive_without_cyclic_modes_gets_no_preference_and_a_comment_saying_why(tmp_path):
    eds = tmp_path / "pp_only.eds"
    text = (FIXTURES / "pdo4_rpdo2.eds").read_text(encoding="utf-8")
    eds.write_text(text.replace("DefaultValue=0x000003A5", "DefaultValue=0x00000025"), encoding="utf-8")  # PP/PV/HM
    report = new_driver_folder(eds, tmp_path / "drv")
    data = tomllib.loads((report.folder / "driver.toml").read_text(encoding="utf-8"))
    assert report.summary.cyclic_modes == () and "cyclic_modes" not in data["canopen"]
    assert "# cyclic_modes: the drive has no cyclic mode" in (report.folder / "driver.toml").read_text()
    assert check_driver_folder(report.folder).ok


def test_new_refuses_an_existing_driver_a_bad_name_and_an_unreadable_eds(tmp_path):
    new(tmp_path, "pdo4_rpdo2.eds")
    with pytest.raises(UsageError, match="already holds"):
        new_driver_folder(FIXTURES / "pdo4_rpdo2.eds", tmp_path / "drv")
    with pytest.raises(UsageError, match="--name"):
        new_driver_folder(FIXTURES / "pdo4_rpdo2.eds", tmp_path / "other", name="a b/c")
    bad = tmp_path / "bad.eds"
    bad.write_text("not an eds\n")
    with pytest.raises(ConfigError, match="bad.eds"):
        new_driver_folder(bad, tmp_path / "other")
    assert not (tmp_path / "other").exists()


# --- check finds what is wrong ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "old, new_text, words",
    [
        (
            "heartbeat_ms = 100",
            'heartbeat_ms = 100\nobjects = { sample_counter = "0x2100" }',
            ("0x2100 is not in the EDS",),
        ),
        ("heartbeat_ms = 100", 'heartbeat_ms = 100\nobjects = { statusword = "0x6071" }', ()),  # rww is readable
        ("heartbeat_ms = 100", 'heartbeat_ms = 100\nobjects = { target_torque = "0x6041" }', ("'ro'", "must write")),
        ("heartbeat_ms = 100", 'heartbeat_ms = 100\nobjects = { device_name = "0x6041" }', ("needs a bytes",)),
        ("heartbeat_ms = 100", 'heartbeat_ms = 100\nobjects = { controlword = "60x40" }', ("object address",)),
        (
            "heartbeat_ms = 100",
            'heartbeat_ms = 100\nmodes = { position = { code = 7, setpoint = "target_position" } }',
            ("mode 7 (IP)", "not in 0x6502"),
        ),
        (
            "heartbeat_ms = 100",
            'heartbeat_ms = 100\nmodes = { velocity = { code = 9, setpoint = "velocity_offset" } }',
            ("0x60B1 is not in the EDS",),
        ),
        ('cyclic_modes = ["cst", "csv", "csp"]', 'cyclic_modes = ["ip"]', ("none of ip",)),
        ('cyclic_modes = ["cst", "csv", "csp"]', 'cyclic_modes = ["turbo"]', ("must be a list of",)),
        ("position_unit_m = ", "position_unit_m = -", ("position_unit_m", "positive")),
        ('object = "0x1010:1"', 'object = "0x1010:3"', ("0x1010:3 is not in the EDS",)),
        (
            "heartbeat_ms = 100",
            'heartbeat_ms = 100\nchannels = { a = "position_actual", b = "velocity_actual", '
            'c = "torque_actual", d = "torque_demand", e = "error_code", f = "statusword", '
            'g = "target_position", h = "target_velocity", i = "target_torque", '
            'j = "controlword", k = "modes_display", l = "position_actual", '
            'm = "position_actual" }',
            ("do not fit", "4 TPDOs of up to 4 entries"),
        ),
        ("heartbeat_ms = 100", 'heartbeat_ms = 100\nchannels = { x = "current_actual" }', ("0x6078",)),
        (
            "heartbeat_ms = 100",
            'heartbeat_ms = 100\nobjects = { vendor_setpoint = "0x6041" }\n'
            'modes = { velocity = { code = 9, setpoint = "vendor_setpoint" } }',
            ("[canopen.modes.velocity.setpoint] 0x6041 (vendor_setpoint) is 'ro'",),
        ),
        ("heartbeat_ms = 100", "heartbeat_ms = 70000", ("heartbeat_ms", "UNSIGNED16")),
        ("host_node_id = 127", "host_node_id = 0", ("host_node_id", "1..127")),
    ],
)
def test_check_reports_each_problem_as_an_error_naming_the_key(tmp_path, old, new_text, words):
    report, _, _ = new(tmp_path, "pdo4_rpdo2.eds")
    edit(report.folder, old, new_text)
    check = check_driver_folder(report.folder)
    if not words:
        assert check.ok, check.errors
        return
    assert len(check.errors) == 1, check.errors
    assert all(w in check.errors[0] for w in words), check.errors[0]
    assert str(report.folder / "driver.toml") in check.errors[0]


def test_check_warns_of_a_negative_mode_on_an_unsigned8_mode_object(tmp_path):
    report, _, _ = new(tmp_path, "mode_u8_wo.eds")
    edit(
        report.folder,
        "heartbeat_ms = 100",
        'heartbeat_ms = 100\nmodes = { torque_injection = { code = -3, setpoint = "torque_offset" } }',
    )
    check = check_driver_folder(report.folder)
    assert check.ok
    assert any("negative mode -3, but 0x6060 is UNSIGNED8: written as 253" in w for w in check.warnings)


def test_check_validates_filter_objects_fields_and_encoding(tmp_path):
    report, _, _ = new(tmp_path, "quirks_dup_lower_crlf.eds")
    path = report.folder / "driver.toml"
    good = (
        '\n[filters]\nencoding = "notch_parameters"\nobjects = ["0x2300"]\nenable_subindex = 1\n'
        "fields = { center = 1, width = 2, depth = 3 }\n"
    )
    path.write_text(path.read_text(encoding="utf-8") + good, encoding="utf-8")
    # the fixture's notch record 0x2300 has no enable: sub 1 is the centre, which an enable would overwrite
    (error,) = check_driver_folder(report.folder).errors
    assert "[filters.enable_subindex] must be a free sub-index" in error
    eds = report.folder / report.eds_file
    eds.write_bytes(
        eds.read_bytes().replace(b"DefaultValue=3", b"DefaultValue=4", 1)
        + b"\r\n[2300sub4]\r\nParameterName=Notch enable\r\nObjectType=0x7\r\nDataType=0x0005\r\n"
        b"AccessType=rw\r\nDefaultValue=0\r\nPDOMapping=0\r\n"
    )
    edit(report.folder, "enable_subindex = 1", "enable_subindex = 4")
    assert check_driver_folder(report.folder).ok, check_driver_folder(report.folder).errors
    edit(report.folder, 'encoding = "notch_parameters"', 'encoding = "real32"')
    errors = check_driver_folder(report.folder).errors
    assert any("[filters.fields.b0] is not given" in e for e in errors)
    edit(report.folder, "fields = { center = 1, width = 2, depth = 3 }", "fields = { b0 = 1, b1 = 2, b2 = 3 }")
    errors = [e for e in check_driver_folder(report.folder).errors if "is not given" not in e]
    assert len(errors) == 3 and all("UNSIGNED16" in e and "real32 encoding writes a REAL32" in e for e in errors)
    edit(report.folder, 'encoding = "real32"', 'encoding = "notch_parameters"')
    edit(report.folder, "fields = { b0 = 1, b1 = 2, b2 = 3 }", "fields = { center = 1, width = 2, depth = 5 }")
    assert any(
        "[filters.fields.depth] 0x2300:5 is not in the EDS" in e for e in check_driver_folder(report.folder).errors
    )


def test_check_warns_about_placeholders_not_listed_or_not_keys(tmp_path):
    report, _, _ = new(tmp_path, "pdo4_rpdo2.eds")
    edit(report.folder, 'placeholders = ["board.loop_rate_hz", ', 'placeholders = ["board.nothing", ')
    check = check_driver_folder(report.folder)
    assert check.ok
    assert any("'board.nothing' is not a key" in w for w in check.warnings)
    assert any("board.loop_rate_hz is marked PLACEHOLDER but not listed" in w for w in check.warnings)


def test_check_of_a_folder_without_its_eds_or_toml_is_an_error_not_a_traceback(tmp_path):
    report, _, _ = new(tmp_path, "pdo4_rpdo2.eds")
    (report.folder / "pdo4_rpdo2.eds").unlink()
    check = check_driver_folder(report.folder)
    assert not check.ok and "pdo4_rpdo2.eds" in check.errors[0]
    assert not check_driver_folder(tmp_path / "nowhere").ok


# --- command line -------------------------------------------------------------------------------------------------


def test_cli_new_check_and_verbose_listing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "acme"
    assert main(["drivers", "new", "--eds", str(FIXTURES / "current_only.eds"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "placeholder: canopen.scaling.torque_constant_nm_per_a" in printed and "cyclic modes: csv, csp" in printed
    assert main(["drivers", "check", str(out)]) == 0
    assert f"{out}: ok" in capsys.readouterr().out
    edit(out, "position_unit_m = ", "position_unit_m = -")
    assert main(["drivers", "check", str(out)]) == 2
    assert "error: " in capsys.readouterr().out
    assert main(["drivers", "new", "--eds", str(tmp_path / "missing.eds"), "--out", str(tmp_path / "x")]) == 2
    assert "missing.eds" in capsys.readouterr().err
    monkeypatch.setenv("HILIDENT_DRIVER_PATH", str(tmp_path))
    assert main(["drivers", "-v"]) == 0
    listing = capsys.readouterr().out
    assert re.search(rf"^acme\t.*\t{re.escape(str(out))}$", listing, re.M)
    assert "modes: CSV, CSP" in listing and "0x6502: pp, pv, csp, csv" in listing


def test_describe_names_channels_rates_modes_and_capabilities(tmp_path):
    report, _, _ = new(tmp_path, "period_1006_only.eds")
    text = describe_driver(report.folder)
    # what a session would record and run: the host's set-point channel and the drive's objects; hilident modes
    assert "channels: excitation, torque_cmd_nm, torque_nm, position_m, velocity_mps" in text
    assert "modes: torque, velocity, position, torque_injection" in text and "0x6502: csp, csv, cst" in text
    assert "rates: loop 1000.0 Hz" in text and "filter slots: 0" in text
    assert "period 0x1006" in text and "heartbeat consumer 0x1016" in text and "save 0x1010:1" in text
    assert "placeholders (refused on a real port): board.loop_rate_hz" in text
    assert "loop:" not in text  # an EDS without gain objects: no loop described


def test_describe_says_the_loop_the_driver_describes_and_its_controllers_forms():
    from hilident.drivers.description import find_driver

    text = describe_driver(find_driver("canopen-servo-fixed").folder)
    assert "loop: velocity PI (its integral as a gain), position P; feed-forward: velocity_feedforward" in text
    assert "loop parameters the drive holds: kv_nm_per_mps, ki_nm_per_m, kp_pos_per_s" in text
    assert "its integral as a time" in describe_driver(find_driver("modbus-servo").folder)


@pytest.mark.parametrize("default", ["", "DefaultValue=0\n"])
def test_check_warns_of_a_following_error_window_of_0_on_a_drive_with_position_modes(tmp_path, default):
    import shutil

    from hilident.drivers.description import find_driver

    folder = tmp_path / "cia402-standard"
    shutil.copytree(find_driver("cia402-standard").folder, folder)
    eds = folder / "cia402-standard.eds"
    assert "DefaultValue=0x186A0\n" in eds.read_text()
    good = check_driver_folder(folder)
    assert good.ok and not any("0x6065" in w for w in good.warnings)
    eds.write_text(eds.read_text().replace("DefaultValue=0x186A0\n", default))
    report = check_driver_folder(folder)
    assert report.ok  # a warning: the drive itself may hold another value
    (warning,) = [w for w in report.warnings if "0x6065" in w]
    assert "[canopen.cyclic_modes]" in warning and "refused until the drive holds" in warning
    assert "twin holds 0: give it one in [emulator] values" in warning
    (folder / "driver.toml").write_text(
        (folder / "driver.toml").read_text() + '\n[emulator]\nvalues = { "0x6065" = 1 }\n'
    )
    (warning,) = [w for w in check_driver_folder(folder).warnings if "0x6065" in w]
    assert "twin holds the one [emulator] values gives" in warning


def test_new_gives_the_twin_a_following_error_window_where_the_eds_gives_none(tmp_path):
    import shutil

    from hilident.drivers.description import find_driver

    eds = tmp_path / "drive.eds"
    shutil.copyfile(find_driver("cia402-standard").folder / "cia402-standard.eds", eds)
    eds.write_text(eds.read_text().replace("DefaultValue=0x186A0\n", ""))
    report = new_driver_folder(eds, tmp_path / "out")
    text = (report.folder / "driver.toml").read_text()
    assert 'values = { "0x6065" = 100000 }  # PLACEHOLDER: 0x6065 (following error window) has no default' in text
    assert "emulator.values" in report.placeholders
    data = tomllib.loads(text)
    assert data["emulator"]["values"] == {"0x6065": 100000}
