"""A position controller with integral and derivative terms (a PI, PD or PID position loop, as vendors' drives
have): the emulated drive runs it, the cascade's model predicts it, and [loop] and the host carry it."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.emulator.drive import DriveLoop
from hilident.errors import ConfigError
from hilident.protocol.loop_parameters import PARAMETERS, TUNABLE, parse_loop
from test_feedforward import RATE, _axis

PID = dict(ki_pos_per_s2=60.0, kd_pos=0.08)


def _position_response(loop: DriveLoop, bins: np.ndarray, n: int = 4000, periods: int = 3) -> np.ndarray:
    """The measured set-point-to-position response of ``loop`` on the lines ``bins`` of an ``n``-tick multisine."""
    rng = np.random.default_rng(5)
    t = np.arange(n) / RATE
    period = sum(np.cos(2 * np.pi * b * t + rng.uniform(0, 2 * np.pi)) for b in bins)
    period *= 1e-3 / np.abs(period).max()
    loop.set_mode("position")
    loop.enable()
    rows = loop.run(np.tile(period, periods))
    position = rows[:, DriveLoop.CHANNELS.index("position_m")] - loop.hold_position_m
    return np.fft.rfft(position[-n:])[bins] / np.fft.rfft(period)[bins]


def test_a_pid_position_loop_runs_as_the_cascade_predicts_and_a_p_model_would_miss_it():
    loop, seen, cascade = _axis(**PID)
    bins = np.arange(1, 60)
    f = bins * RATE / 4000
    measured = _position_response(loop, bins)
    model = cascade.closed_loop(f, seen.at(f)[0], "position")
    assert np.max(np.abs(measured / model - 1)) < 0.01
    p_only = _axis()[2].closed_loop(f, seen.at(f)[0], "position")
    assert np.max(np.abs(measured / p_only - 1)) > 0.05
    # the position loop broken at the velocity set-point carries the terms: its integral lifts the low end
    low = f < 2.0
    assert np.all(
        np.abs(cascade.open_loop(f[low], seen.at(f[low])[0], "position"))
        > np.abs(_axis()[2].open_loop(f[low], seen.at(f[low])[0], "position"))
    )


def test_the_position_terms_are_optional_parameters_of_loop_and_a_host_may_write_them():
    table = {n: {"object": f"0x2400:{i}"} for i, n in enumerate(PARAMETERS, start=1)}
    loop = parse_loop({**table, "ki_pos_per_s2": {"object": "0x2400:20"}}, "d.toml")
    assert "ki_pos_per_s2" in loop.parameters and "kd_pos" not in loop.parameters
    assert {"ki_pos_per_s2", "kd_pos"} <= set(TUNABLE)
    with pytest.raises(ConfigError, match=r"loop\.kd_pos\.value"):
        parse_loop({**table, "kd_pos": {"value": -1.0}}, "d.toml")
