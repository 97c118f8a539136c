"""Configuration loading: every bad key is named with its file."""

from __future__ import annotations

import pytest

from hilident.config.tables import load_config, parse_config
from hilident.errors import ConfigError

LIMITS = "[limits]\ntorque_nm = 10\nvelocity_mps = 1\nposition_min_m = -1\nposition_max_m = 1\n"


def error(text: str) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        parse_config(text, "bench.toml")
    return err.value


def test_defaults_fill_what_is_not_given():
    cfg = parse_config(LIMITS)
    assert cfg.device.port == "emulator" and cfg.uses_emulator
    assert cfg.emulator.plant.model == "two_mass" and cfg.limits.torque_nm == 10.0
    assert isinstance(cfg.limits.velocity_mps, float)  # integers are accepted for floats


@pytest.mark.parametrize(
    "text, key",
    [
        (LIMITS + "[emulator.plant]\nm1 = 0\n", "emulator.plant.m1"),
        (LIMITS + "[emulator.plant]\nmodel = 'four_mass'\n", "emulator.plant.model"),
        (LIMITS + "[excitation]\nkind = 'sine'\nduration_s = 'long'\n", "excitation.duration_s"),
        (LIMITS + "[excitation]\nf_max_hz = 600.0\n", "excitation.f_max_hz"),
        (LIMITS + "[excitation]\namplitude_nm = 11.0\n", "excitation.amplitude_nm"),
        (LIMITS + "[friction_test]\nspeeds_mps = [0.1, 2.0]\n", "friction_test.speeds_mps"),
        (LIMITS + "[run]\nchanels = []\n", "run.chanels"),
        (LIMITS + "[notch]\nenabled = 1\n", "notch.enabled"),
        (LIMITS + "[emulator]\nplant = 3\n", "emulator.plant"),
        (LIMITS.replace("position_min_m = -1", "position_min_m = 2"), "limits.position_min_m"),
        ("[limits\n", "(syntax)"),
        (LIMITS + "[run]\nchannels = ['excitation', 'torque_nm']\n", "run.channels"),
    ],
)
def test_bad_values_name_key_and_file(text, key):
    err = error(text)
    assert err.key == key and err.file == "bench.toml"
    assert f"[{key}]" in str(err) and "bench.toml" in str(err)


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path / "nope.toml")
    assert "nope.toml" in str(err.value)


def test_a_bench_run_needs_limits():
    from hilident.session.run import Session

    cfg = parse_config("[emulator.plant]\nm1 = 30.0\n", "bench.toml")
    assert cfg.limits is None  # fine for `hilident identify`, which moves nothing
    with pytest.raises(ConfigError) as err:
        Session(cfg, "unused")
    assert err.value.key == "limits" and "bench.toml" in str(err.value)


OLD_STYLE = """
[device]
driver = "canopen-servo"
node_id = 5
can_interface = "virtual"
parity = "N"
[emulator.faults]
exception_register = 117
close_after_s = 0.8
drive_fault_after_s = 1.0
"""


def test_flat_keys_of_the_last_release_are_read_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning) as caught:
        cfg = parse_config(LIMITS + OLD_STYLE, "old.toml")
    said = [str(w.message) for w in caught]
    assert len(said) == 5 and all("old.toml" in s for s in said)
    assert any("[device.node_id]" in s and "[device.canopen.node_id]" in s for s in said)
    assert any("[emulator.faults.exception_register]" in s and "[emulator.faults.modbus]" in s for s in said)
    assert cfg.device.canopen.node_id == 5 and cfg.device.node_id == 5 and cfg.device.can_interface == "virtual"
    assert cfg.device.modbus.parity == "N" and cfg.emulator.faults.modbus.exception_register == 117
    assert cfg.emulator.faults.serial.close_after_s == 0.8 and cfg.emulator.faults.drive_fault_after_s == 1.0
    new_style = parse_config(
        LIMITS + '[device]\ndriver = "canopen-servo"\n[device.canopen]\nnode_id = 5\n'
        'can_interface = "virtual"\n[device.modbus]\nparity = "N"\n[emulator.faults]\n'
        "drive_fault_after_s = 1.0\n[emulator.faults.modbus]\nexception_register = 117\n"
        "[emulator.faults.serial]\nclose_after_s = 0.8\n",
        "old.toml",
    )
    assert new_style.device == cfg.device and new_style.emulator == cfg.emulator


def test_the_deprecation_is_a_line_on_stderr(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "old.toml"
    path.write_text(LIMITS + "[device]\nnode_id = 5\n")
    code = "import sys; from hilident.config.tables import load_config; print(load_config(sys.argv[1]).device.node_id)"
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "5"
    assert "DeprecationWarning" in run.stderr and "[device.node_id]" in run.stderr and str(path) in run.stderr


def test_a_key_given_flat_and_in_its_sub_table_is_refused():
    err = error(LIMITS + "[device]\nnode_id = 5\n[device.canopen]\nnode_id = 6\n")
    assert err.key == "device.node_id" and "device.canopen.node_id" in err.message


@pytest.mark.parametrize(
    "text, key",
    [
        ("[device]\nnode_id = 0\n", "device.node_id"),
        ("[device.canopen]\nnode_id = 0\n", "device.canopen.node_id"),
        ("[emulator.faults.canopen]\nabort_object = 'zz'\n", "emulator.faults.canopen.abort_object"),
        ("[emulator.faults.modbus]\nunknown_unit_id = 'x'\n", "emulator.faults.modbus.unknown_unit_id"),
    ],
)
def test_sub_table_errors_name_the_key_as_written(text, key):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        err = error(LIMITS + text)
    assert err.key == key and f"[{key}]" in str(err)


def test_moved_attributes_replace_into_their_sub_table():
    from dataclasses import replace

    from hilident.config.tables import DeviceConfig, FaultsConfig

    device = replace(DeviceConfig(node_id=3, parity="O"), can_interface="virtual", port="x")
    assert device.canopen.node_id == 3 and device.canopen.can_interface == "virtual" and device.modbus.parity == "O"
    faults = replace(FaultsConfig(), response_delay_s=0.1, corrupt_frame_rate=0.5)
    assert faults.modbus.response_delay_s == 0.1 and faults.serial.corrupt_frame_rate == 0.5
