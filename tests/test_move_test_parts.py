"""The move test's parts: which way a move goes, what is measured, the floor at rest, the drive's slots put
back."""

from __future__ import annotations

import json
import math

import jsonschema
import numpy as np
import pytest

from hilident.config.tables import MoveConfig
from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.session.move_test import DriveNotch, above_floor_db, measured_signal, move_distance, standstill_rms
from support.filter_slots import FakeSlots

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


def test_the_drive_notch_is_off_for_the_move_without_it_and_back_after_even_on_an_error():
    adapter = FakeSlots({0: Biquad((1.0, -1.9, 0.95), (1.0, -1.8, 0.9))})  # slot 0 filters, slot 1 does not
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
    moves[0]["shapers"] = [
        {"name": "scheduled shaper", "kind": "zvd", "rms_reduction_db": 22.0, "added_delay_s": 0.05,
         "rms_reduction_above_standstill_db": None},
    ]  # fmt: skip
    moves[1]["shapers"] = [
        {"name": "scheduled shaper", "kind": "zvd", "rms_reduction_db": 18.5, "added_delay_s": 0.048,
         "rms_reduction_above_standstill_db": 15.0},
    ]  # fmt: skip
    _print_moves({"moves": moves})
    line = capsys.readouterr().out
    assert "reduced by 9.5 dB RMS at worst (from +0.250 m)" in line and "1 of 2 move(s)" in line
    assert (
        "with the scheduled shaper (zvd), reduced by 18.5 dB RMS at worst (from +0.250 m, 48 ms later); 1 of 2" in line
    )
    _print_moves(None)
    _print_moves({"moves": [{"start_m": 0.0, "rms_reduction_db": None}]})
    assert capsys.readouterr().out == ""


class Bench:
    """A cart that follows its set-point exactly and a load that rings on it at 20 Hz (the recorder a session
    gives the move test): ``record(name, mode, setpoint)`` keeps the set-point and returns its samples."""

    MODE_HZ, ZETA, RATE = 20.0, 0.02, 1000.0

    def __init__(self):
        self.setpoints = {}

    def __call__(self, name, mode, setpoint):
        from types import SimpleNamespace

        from scipy import signal

        w = 2 * math.pi * self.MODE_HZ
        t = np.arange(setpoint.size) / self.RATE
        # the load's deflection from the cart: -s^2 / (s^2 + 2 zeta w s + w^2) of the cart's position
        _, deflection, _ = signal.lsim(([-1.0, 0.0, 0.0], [1.0, 2 * self.ZETA * w, w * w]), setpoint - setpoint[0], t)
        self.setpoints[name] = setpoint
        samples = {
            "position_m": setpoint,
            "load_position_m": setpoint + deflection,
            "excitation": setpoint - setpoint[0],
            "sample_index": np.arange(setpoint.size),
        }
        return SimpleNamespace(samples=samples)


class Quiet:
    def step(self, text):
        pass


def test_the_same_move_is_made_with_each_shaper_alone_and_with_the_notch_and_measured_with_one_band():
    from hilident.config.tables import Config, RunConfig, VerificationConfig
    from hilident.filters.notch import NotchSpec, design_notch
    from hilident.motion.input_shapers import design_shaper
    from hilident.motion.scheduled_shaper import ScheduledShaper
    from hilident.motion.shaping import impulse_shaped_move, shape_move
    from hilident.pipeline.input_shaper import MoveShaper
    from hilident.schemas import summary_schema
    from hilident.session.move_test import MoveTest, move_profile

    move = MoveConfig(distance_m=0.2, max_velocity_mps=0.3, max_accel_mps2=2.5, dwell_s=1.0)
    cfg = Config(run=RunConfig(sample_rate_hz=Bench.RATE), verification=VerificationConfig(move=move))
    bench = Bench()
    notch = [design_notch(NotchSpec(20.0, 8.0, 40.0), Bench.RATE)]
    schedule = ScheduledShaper("zvd", [0.0, 0.4], [20.0, 20.0], [0.02, 0.02])
    shapers = [
        MoveShaper("fixed shaper", design_shaper("zvd", 20.0, 0.02), 1.5),
        MoveShaper("scheduled shaper and notch", schedule, 1.2, with_notch=True),
    ]
    result = MoveTest(cfg, bench, Quiet()).run("", 0.0, 0.2, "host", notch, None, [(20.0, 0.02)], shapers)
    assert list(bench.setpoints) == [
        "move_without", "move_without_back", "move_with", "move_with_back",
        "move_fixed", "move_fixed_back", "move_both", "move_both_back",
    ]  # fmt: skip
    out = move_profile(move, 0.2, Bench.RATE)
    both = impulse_shaped_move(shape_move(out, notch).profile, schedule).profile.position_m
    np.testing.assert_array_equal(bench.setpoints["move_both"][-both.size :], both)  # the notch's, then shaped
    fixed, paired = result.shaped
    assert fixed.rms_reduction_db >= 30.0  # a ZVD at the mode of a linear axis leaves next to nothing
    assert fixed.residual.band == result.comparison.without.band  # one band for every move
    assert fixed.added_delay_s == pytest.approx(design_shaper("zvd", 20.0, 0.02).duration_s, abs=1e-3)
    assert paired.added_delay_s > result.added_delay_s  # the notch's delay and the shaper's
    assert fixed.excitations[0] < 0.01 * result.modes[0].excitation
    assert (fixed.max_accel_mps2, paired.max_accel_mps2) == (1.5, 1.2)
    row = result.to_dict()
    assert [s["name"] for s in row["shapers"]] == ["fixed shaper", "scheduled shaper and notch"]
    schema = summary_schema()
    validator = jsonschema.Draft202012Validator({**schema["$defs"]["move_result"], "$defs": schema["$defs"]})
    assert list(validator.iter_errors(json.loads(json.dumps(row, default=float)))) == []


def test_a_scheduled_shaper_shapes_each_move_for_the_mode_where_the_axis_really_is():
    # set-points are streamed relative to where the axis stands: the schedule, by absolute position, must be
    # moved to where each move starts, so the tail of the move out is shaped for the mode where it ends
    from hilident.config.tables import Config, RunConfig, VerificationConfig
    from hilident.motion.input_shapers import design_shaper
    from hilident.motion.scheduled_shaper import ScheduledShaper
    from hilident.pipeline.input_shaper import MoveShaper
    from hilident.session.move_test import STANDSTILL_S, MoveTest, move_profile

    move = MoveConfig(distance_m=0.2, max_velocity_mps=0.3, max_accel_mps2=2.5, dwell_s=0.5)
    cfg = Config(run=RunConfig(sample_rate_hz=Bench.RATE), verification=VerificationConfig(move=move))
    bench = Bench()
    schedule = ScheduledShaper("zvd", [0.0, 1.0], [20.0, 40.0], [0.02, 0.02])
    start = 0.3
    shapers = [MoveShaper("scheduled shaper", schedule, 1.0)]
    notch = [Biquad.identity()]
    result = MoveTest(cfg, bench, Quiet()).run("", start, 0.2, "host", notch, None, [], shapers)
    (scheduled,) = result.shaped
    assert scheduled.frequency_hz == pytest.approx(30.0)  # at 0.5 m, where the move out ends
    out, back = move_profile(move, 0.2, Bench.RATE), move_profile(move, -0.2, Bench.RATE)
    still = int(round(STANDSTILL_S * Bench.RATE))
    for name, profile, end_m in (("move_scheduled", out, 0.5), ("move_scheduled_back", back, 0.3)):
        recorded = bench.setpoints[name][still if name == "move_scheduled" else 0 :]
        at_end = design_shaper("zvd", 20.0 + 20.0 * end_m, 0.02).apply(profile.position_m, Bench.RATE)
        i = profile.move_end_index
        np.testing.assert_allclose(recorded[i : i + 40], at_end[i : i + 40], rtol=0, atol=1e-12)


class NoisyBench(Bench):
    """The bench with a vibration at rest: white noise through the mode, new in every record."""

    def __init__(self, seed=1):
        super().__init__()
        self.rng = np.random.default_rng(seed)

    def __call__(self, name, mode, setpoint):
        from scipy import signal

        exp = super().__call__(name, mode, setpoint)
        w = 2 * math.pi * self.MODE_HZ
        t = np.arange(setpoint.size) / self.RATE
        noise = self.rng.normal(0.0, 1.0, setpoint.size)
        _, rest, _ = signal.lsim(([1e-3], [1.0, 2 * self.ZETA * w, w * w]), noise, t)
        exp.samples["load_position_m"] = exp.samples["load_position_m"] + rest
        return exp


def test_repeated_moves_are_averaged_so_the_rest_vibration_falls_and_the_ringing_stays():

    from hilident.config.tables import Config, RunConfig, VerificationConfig
    from hilident.session.move_test import MoveTest

    results = {}
    for repeats in (1, 4):
        move = MoveConfig(distance_m=0.2, max_velocity_mps=0.3, max_accel_mps2=2.5, dwell_s=1.0, repeats=repeats)
        cfg = Config(run=RunConfig(sample_rate_hz=Bench.RATE), verification=VerificationConfig(move=move))
        bench = NoisyBench(seed=repeats)
        notch = [Biquad.identity()]
        results[repeats] = MoveTest(cfg, bench, Quiet()).run("", 0.0, 0.2, "host", notch, None, [(20.0, 0.02)])
        names = list(bench.setpoints)
        assert names[: 2 * repeats : 2] == ["move_without"] + [f"move_without_{k}" for k in range(2, repeats + 1)]
    one, four = results[1], results[4]
    assert 0.3 < four.floor_rms / one.floor_rms < 0.8  # about 1/sqrt(4)
    assert four.rest_limit_db > one.rest_limit_db + 3.0
    assert four.comparison.without.first_peak == pytest.approx(one.comparison.without.first_peak, rel=0.1)


def test_records_are_averaged_on_the_samples_every_one_of_them_has():
    from hilident.session.move_test import averaged_signal

    def record(offset, keep):
        index = np.arange(10)[keep]
        position = np.zeros(index.size)
        return {"sample_index": index, "position_m": position, "load_position_m": position + offset + index * 1e-3}

    lost = np.ones(10, bool)
    lost[5] = False
    what, t, signal = averaged_signal([record(0.0, np.ones(10, bool)), record(2.0, lost)], 100.0)
    assert what == "load deflection" and 0.05 not in t and t.size == 9  # sample 5 was lost in one: left out
    np.testing.assert_allclose(signal, 1.0 + np.delete(np.arange(10), 5) * 1e-3)
