"""Driver descriptions: found from a checkout or an installed wheel, and from user folders."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest

from hilident.drivers.description import (
    available_drivers,
    check_run_against_driver,
    declared_modes,
    find_driver,
    load_driver,
    search_path,
    valid_sample_rates,
)
from hilident.errors import ConfigError


def test_builtin_board_is_found_wherever_hilident_is_installed():
    d = find_driver("myrio-board")
    assert d.transport == "serial" and d.filter_slots >= 1
    assert (d.folder / "PROTOCOL.md").is_file() or (d.folder / "driver.toml").is_file()
    assert "velocity_mps" in [c.name for c in d.channels]
    assert d.text.startswith("#")  # the file verbatim, for the recordings


def test_a_channel_says_how_it_is_sampled_and_a_wrong_word_names_its_key(tmp_path):
    assert find_driver("myrio-board").averaged_channels == ("torque_cmd_nm", "torque_nm")
    assert find_driver("modbus-servo").averaged_channels == ()  # instant unless the description says otherwise
    folder = _user_copy(tmp_path, edit=lambda t: t.replace('sampling = "mean"', 'sampling = "median"', 1))
    with pytest.raises(ConfigError, match=r"channels.*sampling") as exc:
        load_driver(folder)
    assert str(folder / "driver.toml") in str(exc.value)


def test_one_channel_at_most_enters_the_filter_slots(tmp_path):
    assert find_driver("myrio-board").filter_input_channel == "torque_cmd_nm"  # PROTOCOL.md: before the slots
    assert find_driver("canopen-servo").filter_input_channel == "torque_cmd_nm"  # 0x6074, before the slots
    assert find_driver("modbus-servo").filter_input_channel is None  # its command is not recorded
    folder = _user_copy(
        tmp_path, edit=lambda t: t.replace('name = "torque_nm"\n', 'name = "torque_nm"\nfilter_input = true\n', 1)
    )
    with pytest.raises(ConfigError, match=r"channels\[3\]\.filter_input.*'torque_cmd_nm' already does") as exc:
        load_driver(folder)
    assert str(folder / "driver.toml") in str(exc.value)


def _user_copy(tmp_path, name="my-board", edit=None):
    folder = tmp_path / "mydrivers" / name
    shutil.copytree(find_driver("myrio-board").folder, folder)
    text = (folder / "driver.toml").read_text().replace('name = "myrio-board"', f'name = "{name}"')
    if edit:
        text = edit(text)
    (folder / "driver.toml").write_text(text)
    return folder


def test_user_folders_by_path_by_search_path_and_by_environment(tmp_path, monkeypatch):
    folder = _user_copy(tmp_path, edit=lambda t: t.replace("filter_slots = 4", "filter_slots = 2"))
    assert find_driver(str(folder)).filter_slots == 2
    assert find_driver("my-board", [folder.parent]).filter_slots == 2
    with pytest.raises(ConfigError, match="my-board"):
        find_driver("my-board")
    monkeypatch.setenv("HILIDENT_DRIVER_PATH", str(folder.parent))
    assert find_driver("my-board").name == "my-board"
    assert "my-board" in available_drivers() and folder.parent in search_path()


def test_unknown_driver_lists_what_exists():
    with pytest.raises(ConfigError) as err:
        find_driver("no-such-board")
    assert "device.driver" in str(err.value) and "myrio-board" in str(err.value)


def test_invalid_description_names_key_and_file(tmp_path):
    folder = _user_copy(tmp_path, edit=lambda t: t.replace('format = "i32"', 'format = "i24"'))
    with pytest.raises(ConfigError) as err:
        find_driver(str(folder))
    assert "format" in str(err.value) and "driver.toml" in str(err.value)


def test_a_name_never_loads_a_folder_of_the_current_directory(tmp_path, monkeypatch):
    _user_copy(tmp_path, name="myrio-board", edit=lambda t: t.replace("filter_slots = 4", "filter_slots = 1"))
    monkeypatch.chdir(tmp_path / "mydrivers")  # ./myrio-board/driver.toml exists here
    assert find_driver("myrio-board").filter_slots == 4  # the installed one
    assert find_driver("./myrio-board").filter_slots == 1  # a path, because it looks like one
    assert find_driver("myrio-board", ["."]).filter_slots == 1  # the user asked for "." in driver_paths


@pytest.mark.parametrize("value", ["./nothing", "../nothing", "/nothing/here", "~/nothing-here", "a/b"])
def test_a_path_that_holds_no_description_is_named(value, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match="taken as a path") as err:
        find_driver(value)
    assert err.value.key == "device.driver"


@pytest.mark.parametrize("value", ["", "  "])
def test_an_empty_driver_name_is_refused(value):
    with pytest.raises(ConfigError, match="device.driver"):
        find_driver(value)


def test_a_description_file_read_as_a_path(tmp_path):
    folder = _user_copy(tmp_path)
    assert find_driver(str(folder / "driver.toml")).name == "my-board"


def _gantry(**tables):
    import dataclasses

    from hilident.config.tables import load_config

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml")
    for table, values in tables.items():
        cfg = dataclasses.replace(cfg, **{table: dataclasses.replace(getattr(cfg, table), **values)})
    return cfg


@pytest.mark.parametrize("driver", ["myrio-board", "canopen-servo", "canopen-servo-fixed", "modbus-servo"])
def test_the_shipped_configs_pass_the_checks_against_every_shipped_driver(driver):
    check_run_against_driver(_gantry(), find_driver(driver))


@pytest.mark.parametrize("rate", [1500.0, 8000.0, 4000.0 / 70000])
def test_a_rate_that_does_not_divide_the_loop_rate_lists_the_valid_ones(rate):
    with pytest.raises(ConfigError) as err:
        check_run_against_driver(_gantry(run={"sample_rate_hz": rate}), find_driver("myrio-board"))
    assert err.value.key == "run.sample_rate_hz" and "emulated-gantry.toml" in str(err.value)
    assert "valid: 4000, 2000, 1333.33, 1000, 800, 666.667" in str(err.value)


def test_rates_above_the_maximum_are_not_offered(tmp_path):
    folder = _user_copy(tmp_path, edit=lambda t: t.replace("max_sample_rate_hz = 4000.0", "max_sample_rate_hz = 1000"))
    driver = find_driver(str(folder))
    assert valid_sample_rates(driver, 3) == [1000.0, 800.0, 4000.0 / 6]
    check_run_against_driver(_gantry(run={"sample_rate_hz": 1000.0}), driver)
    with pytest.raises(ConfigError, match="valid: 1000, 800"):
        check_run_against_driver(_gantry(run={"sample_rate_hz": 2000.0}), driver)


@pytest.mark.parametrize(
    "driver, tables, key",
    [
        ("myrio-board", {"identification": {"output": "load_velocity"}}, "identification.output"),
        ("modbus-servo", {"identification": {"output": "load_position_m"}}, "identification.output"),
        ("myrio-board", {"run": {"channels": ["excitation", "torque_nm", "velocity_mps", "speed"]}}, "run.channels[3]"),
        (
            "canopen-servo",
            {"run": {"channels": ["excitation", "torque_nm", "velocity_mps", "time_s"]}},
            "run.channels[3]",
        ),
    ],
)
def test_channels_the_driver_does_not_record_are_refused(driver, tables, key):
    with pytest.raises(ConfigError) as err:
        check_run_against_driver(_gantry(**tables), find_driver(driver))
    assert err.value.key == key and driver in str(err.value)


def test_modes_and_slots_must_be_declared(tmp_path):
    import copy

    base = find_driver("canopen-servo")
    sections = copy.deepcopy(base.sections)
    del sections["canopen"]["modes"]["velocity"]
    del sections["canopen"]["modes"]["torque"]
    driver = dataclasses.replace(base, sections=sections)
    assert declared_modes(driver) == ("torque_injection", "position")
    with pytest.raises(ConfigError) as err:
        check_run_against_driver(_gantry(), driver)  # excitation.mode = "torque"
    assert err.value.key == "excitation.mode" and "torque_injection, position" in str(err.value)
    # no velocity mode: the friction legs run as a position profile
    check_run_against_driver(_gantry(excitation={"mode": "torque_injection"}), driver)
    del sections["canopen"]["modes"]["position"]
    driver = dataclasses.replace(base, sections=sections)
    with pytest.raises(ConfigError) as err:
        check_run_against_driver(_gantry(excitation={"mode": "torque_injection"}), driver)
    assert err.value.key == "friction_test.enabled" and "velocity (or position)" in str(err.value)
    check_run_against_driver(_gantry(excitation={"mode": "torque_injection"}, friction_test={"enabled": False}), driver)
    # a device without filter slots is no error: the session designs the notch and reports it, not uploaded
    check_run_against_driver(_gantry(), dataclasses.replace(find_driver("myrio-board"), filter_slots=0))
