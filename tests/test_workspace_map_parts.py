"""Moving between mapped positions: the cart is still at its target before the next experiment starts."""

from __future__ import annotations

import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import tomli_w

from hilident.config.tables import parse_config
from hilident.session.map_positions import MAX_SETTLES, move_axis, nearest_resonance

MAP_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry-map.toml"
CFG = parse_config(MAP_CONFIG.read_text(), str(MAP_CONFIG))


class Axis:
    """Records what is asked of it; ends ``misses[i]`` past each set-point's end, moving at ``speeds[i]``."""

    def __init__(self, start_m: float, misses: list[float], speeds: list[float]):
        self.here, self.misses, self.speeds, self.calls = start_m, misses, speeds, []

    def record(self, name, mode, samples):
        i = len(self.calls)
        self.calls.append((name, mode, np.asarray(samples)))
        self.here += float(samples[-1]) - (self.misses[i] if i < len(self.misses) else 0.0)
        v = self.speeds[i] if i < len(self.speeds) else 0.0
        n = len(samples)
        return SimpleNamespace(samples={"position_m": np.full(n, self.here), "velocity_mps": np.full(n, v)})


def test_a_move_that_ends_off_its_target_or_still_moving_goes_the_rest_of_the_way():
    axis = Axis(0.0, misses=[0.004, 0.0], speeds=[0.0, 0.002, 0.0])
    reached = move_axis(CFG, axis.record, "map_move_0", 0.0, -0.5)
    assert [c[0] for c in axis.calls] == ["map_move_0", "map_move_0_settle_1", "map_move_0_settle_2"]
    assert all(c[1] == "position" for c in axis.calls)
    assert axis.calls[1][2][-1] == pytest.approx(0.004)  # 4 mm past the target: back by what is left
    assert axis.calls[2][2].max() == 0.0  # at the target but moving: held there
    assert reached == -0.5


def test_a_move_gives_up_waiting_after_a_few_short_moves():
    axis = Axis(0.0, misses=[0.004] * 10, speeds=[])
    move_axis(CFG, axis.record, "m", 0.0, 0.3)
    assert len(axis.calls) == 1 + MAX_SETTLES


def test_no_move_is_recorded_when_the_cart_is_already_there():
    axis = Axis(0.2, [], [])
    assert move_axis(CFG, axis.record, "m", 0.2, 0.2) == 0.2 and axis.calls == []


def test_the_mapped_mode_is_the_resonance_nearest_the_runs_on_a_log_scale():
    modes = [SimpleNamespace(frequency_hz=f) for f in (11.0, 21.0, 44.0)]
    assert nearest_resonance(modes, 20.0).frequency_hz == 21.0
    assert nearest_resonance(modes, None).frequency_hz == 11.0 and nearest_resonance([], 20.0) is None


def test_the_map_config_parses_with_its_move_test_and_feed_forward():
    raw = tomllib.loads(MAP_CONFIG.read_text())
    cfg = parse_config(tomli_w.dumps(raw), str(MAP_CONFIG))
    assert cfg.map.count == 5 and cfg.verification.move is not None
    assert cfg.emulator.drive.accel_feedforward_nm_per_mps2 == 5.0
