"""``[map]``: the positions it asks for, and the errors that name the key before anything moves."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
import tomli_w

from hilident.config.tables import map_positions, parse_config
from hilident.errors import ConfigError

GANTRY = Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml"


def config_with(**table):
    raw = tomllib.loads(GANTRY.read_text())
    raw["map"] = table
    return parse_config(tomli_w.dumps(raw), "bench.toml")


def test_a_count_spreads_positions_evenly_inside_the_margin():
    cfg = config_with(count=5, margin_m=0.1)  # the gantry's window is -0.6 .. 0.6 m
    assert map_positions(cfg) == pytest.approx([-0.5, -0.25, 0.0, 0.25, 0.5])
    assert cfg.map.enabled and not config_with().map.enabled


def test_positions_are_taken_as_given():
    assert map_positions(config_with(positions_m=[0.3, -0.2, 0.0])) == [0.3, -0.2, 0.0]


@pytest.mark.parametrize(
    "table, key, words",
    [
        ({"positions_m": [0.0, 0.58]}, "map.positions_m", "outside the position window"),
        ({"positions_m": [0.1]}, "map.positions_m", "at least two"),
        ({"count": 1}, "map.count", "at least two"),
        ({"count": 3, "positions_m": [0.0, 0.1]}, "map.count", "not both"),
        ({"count": 3, "margin_m": 0.6}, "map.margin_m", "leaves nothing"),
        ({"count": 3, "max_velocity_mps": 0.4}, "map.max_velocity_mps", "limits.velocity_mps"),
        ({"count": 3, "max_accel_mps2": 0.0}, "map.max_accel_mps2", ""),
        ({"count": 3, "settle": 1.0}, "map.settle", ""),
    ],
)
def test_a_bad_map_names_its_key_and_file(table, key, words):
    with pytest.raises(ConfigError) as info:
        config_with(**table)
    assert info.value.key == key and info.value.file == "bench.toml"
    assert words in str(info.value)


def test_a_map_excitation_shorter_than_a_period_is_refused():
    with pytest.raises(ConfigError) as info:
        config_with(count=3, duration_s=1.0)  # the gantry's multisine period is 4 s
    assert info.value.key == "map.duration_s" and "excitation.period_s = 4" in str(info.value)
