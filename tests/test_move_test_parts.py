"""The move test's parts: which way a move goes, what is measured, the floor at rest, the drive's slots put
back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilident.config.tables import MoveConfig
from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.session.move_test import DriveNotch, above_floor_db, measured_signal, move_distance, standstill_rms

MOVE = MoveConfig(distance_m=0.2, max_velocity_mps=0.3, max_accel_mps2=2.0)


def test_a_move_that_would_leave_the_window_goes_the_other_way():
    assert move_distance(MOVE, 0.0, -0.5, 0.5) == 0.2
    assert move_distance(MOVE, 0.45, -0.5, 0.5) == -0.2
    with pytest.raises(DataError, match="distance_m = 0.2 m does not fit either way"):
        move_distance(MOVE, 0.0, -0.1, 0.1)


def test_the_load_deflection_is_measured_when_the_load_sensor_read_all_along():
    position = np.linspace(0.0, 0.2, 5)
    load = position + np.array([0.0, 1e-5, -1e-5, 2e-6, 0.0])
    setpoint = position + 1e-4
    what, signal = measured_signal({"position_m": position, "load_position_m": load, "excitation": setpoint})
    assert what == "load deflection" and np.allclose(signal, load - position)
    load[2] = np.nan  # out of the laser's range once: the following error instead
    what, signal = measured_signal({"position_m": position, "load_position_m": load, "excitation": setpoint})
    assert what == "following error" and np.allclose(signal, 1e-4)


def test_the_floor_is_the_rms_at_rest_about_a_line_and_the_reduction_is_taken_above_it():
    t = np.arange(0, 0.6, 1e-3)
    y = 1e-6 * np.sin(2 * np.pi * 20 * t) + 3e-3 * t  # a slow drift is no vibration
    assert standstill_rms(t, y) == pytest.approx(1e-6 / math.sqrt(2), rel=0.02)
    assert above_floor_db(5e-5, 5e-6, 3e-6) == pytest.approx(10 * math.log10((25e-10 - 9e-12) / (25e-12 - 9e-12)))
    assert above_floor_db(5e-5, 2e-6, 3e-6) is None  # with the notch nothing is left above the floor
    assert above_floor_db(5e-5, 5e-6, float("nan")) is None


class Slots:
    """A drive's filter slots as an adapter reaches them (save, disable, restore)."""

    def __init__(self):
        self.slots = {0: (Biquad((1.0, -1.9, 0.95), (1.0, -1.8, 0.9)), True), 1: (Biquad.identity(), False)}

    def save_filter(self, slot):
        return self.slots[slot]

    def disable_filter(self, slot):
        self.slots[slot] = (self.slots[slot][0], False)

    def restore_filter(self, slot, saved):
        self.slots[slot] = saved


def test_the_drive_notch_is_off_for_the_move_without_it_and_back_after_even_on_an_error():
    adapter = Slots()
    before = dict(adapter.slots)
    notch = DriveNotch(adapter, [0])
    with pytest.raises(RuntimeError), notch.disabled():
        assert adapter.slots[0][1] is False
        raise RuntimeError("the move failed")
    assert adapter.slots == before


def test_the_cli_line_gives_the_worst_move_and_how_many_rang_no_more_than_at_rest(capsys):
    from hilident.cli.main import _print_moves

    moves = [
        {
            "start_m": -0.5,
            "rms_reduction_db": 16.0,
            "peak_to_peak_reduction_db": 21.0,
            "standstill_rms_m": 1e-5,
            "rms_reduction_above_standstill_db": None,
        },
        {
            "start_m": 0.25,
            "rms_reduction_db": 9.5,
            "peak_to_peak_reduction_db": None,
            "standstill_rms_m": 1e-5,
            "rms_reduction_above_standstill_db": 12.0,
        },
    ]
    _print_moves({"moves": moves})
    line = capsys.readouterr().out
    assert "reduced by 9.5 dB RMS at worst (from +0.250 m)" in line and "1 of 2 move(s)" in line
    _print_moves(None)
    _print_moves({"moves": [{"start_m": 0.0, "rms_reduction_db": None}]})
    assert capsys.readouterr().out == ""
