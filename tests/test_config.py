"""Configuration loading: every bad key is named with its file."""

from __future__ import annotations

import pytest

from hilident.config import load_config, parse_config
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
    from hilident.session import Session

    cfg = parse_config("[emulator.plant]\nm1 = 30.0\n", "bench.toml")
    assert cfg.limits is None  # fine for `hilident identify`, which moves nothing
    with pytest.raises(ConfigError) as err:
        Session(cfg, "unused")
    assert err.value.key == "limits" and "bench.toml" in str(err.value)
