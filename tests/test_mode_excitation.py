"""How strongly a move's set-point excites a mode (``V``): against the closed form of a trapezoid, against a
simulated oscillator, against a notch on the set-point, against the twin's drive loop, and the warning and the
move it suggests when a move test's moves hardly excite their modes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.config.tables import MoveConfig
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, TwoMass
from hilident.emulator.sensors import SensorModel
from hilident.errors import DataError
from hilident.filters.notch import NotchSpec, design_notch
from hilident.motion.mode_excitation import GOOD_EXCITATION, exciting_move, mode_excitation, peak_acceleration
from hilident.motion.profiles import trapezoid
from hilident.motion.shaping import shape_move
from hilident.session.move_test import excitations, move_profile, weak_excitation_warning

RATE = 10_000.0  # fine sampling: the closed form is for the continuous move


@settings(max_examples=30, deadline=None)
@given(accel_time_s=st.floats(0.03, 0.2), cruise_time_s=st.floats(0.0, 0.5), frequency_hz=st.floats(5.0, 60.0))
def test_an_undamped_trapezoid_gives_the_closed_form(accel_time_s, cruise_time_s, frequency_hz):
    accel = 2.0
    v = accel * accel_time_s
    distance = v * (accel_time_s + cruise_time_s)
    move = trapezoid(distance, v, accel, RATE, dwell_s=0.05)
    ta, t = accel_time_s, 2 * accel_time_s + cruise_time_s
    closed = 4 * abs(math.sin(math.pi * frequency_hz * ta) * math.sin(math.pi * frequency_hz * (t - ta)))
    assert mode_excitation(move.position_m, RATE, move.move_end_index, frequency_hz) == pytest.approx(closed, abs=0.05)


def test_a_damped_mode_rings_as_the_simulated_oscillator():
    """The free vibration an oscillator driven by the set-point's acceleration has when the move ends."""
    f, zeta = 18.0, 0.05
    move = trapezoid(0.1, 0.25, 2.0, RATE, dwell_s=0.1)
    w = 2 * math.pi * f
    accel = np.gradient(np.gradient(move.position_m, 1 / RATE), 1 / RATE)
    t = np.arange(move.position_m.size) / RATE
    oscillator = signal.StateSpace([[0.0, 1.0], [-w * w, -2 * zeta * w]], [[0.0], [-1.0]], [[1.0, 0.0]], [[0.0]])
    _, _, x = signal.lsim(oscillator, accel, t)
    i = move.move_end_index
    wd = w * math.sqrt(1 - zeta * zeta)
    amplitude = math.hypot(x[i, 0], (x[i, 1] + zeta * w * x[i, 0]) / wd)
    expected = amplitude * w * w / 2.0
    assert mode_excitation(move.position_m, RATE, i, f, zeta) == pytest.approx(expected, rel=0.02)
    # the damping lets the acceleration's ringing die out before the deceleration: less than undamped
    assert mode_excitation(move.position_m, RATE, i, f, 0.3) < mode_excitation(move.position_m, RATE, i, f, 0.0)


def test_a_notch_on_the_set_point_takes_the_excitation_off_at_its_mode_and_not_elsewhere():
    rate = 1000.0
    move = trapezoid(0.2, 0.3, 2.5, rate, dwell_s=1.0)
    shaped = shape_move(move, [design_notch(NotchSpec(21.0, 12.0, 40.0), rate)]).profile
    at_notch, away = excitations(move, shaped, [(21.0, 0.02), (4.0, 0.02)])
    assert at_notch.excitation > 1.0
    assert at_notch.predicted_reduction_db > 25.0
    assert abs(away.predicted_reduction_db) < 3.0
    # against the same step: the shaped set-point's own peak does not rescale it
    assert at_notch.excitation_with_notch == pytest.approx(
        mode_excitation(
            shaped.position_m,
            rate,
            shaped.move_end_index,
            21.0,
            0.02,
            reference_accel_mps2=peak_acceleration(move.position_m, rate),
        )
    )
    (in_drive,) = excitations(move, None, [(21.0, 0.02)])
    assert in_drive.excitation_with_notch is None and in_drive.predicted_reduction_db is None


def test_bad_input_is_named():
    move = trapezoid(0.1, 0.2, 2.0, 1000.0, dwell_s=0.1)
    with pytest.raises(DataError, match="frequency"):
        mode_excitation(move.position_m, 1000.0, move.move_end_index, 0.0)
    with pytest.raises(DataError, match="damping"):
        mode_excitation(move.position_m, 1000.0, move.move_end_index, 20.0, 1.0)
    with pytest.raises(DataError, match="finite"):
        mode_excitation([0.0, np.nan, 1.0], 1000.0, 1, 20.0)
    assert mode_excitation(np.zeros(50), 1000.0, 40, 20.0) == 0.0  # a set-point that never moves


def twin_deflection(frequency_hz: float, move) -> np.ndarray:
    """The load's deflection from the cart over the dwell after ``move`` (at 4 kHz), on a stiff position loop
    with feed-forward around a two-mass plant whose mode is at ``frequency_hz``, m."""
    m1, m2, c = 40.0, 10.0, 10.0
    k = (2 * math.pi * frequency_hz) ** 2 * m1 * m2 / (m1 + m2)
    d = 2 * 0.018 * math.sqrt(k * m1 * m2 / (m1 + m2))
    loop = DriveLoop(
        Plant(TwoMass(m1, m2, k, d, c=c)),
        DriveTuning(
            loop_rate_hz=4000.0,
            kp_pos_per_s=20.0,
            kv_nm_per_mps=100.0,
            ti_s=0.2,
            torque_max_nm=40.0,
            velocity_feedforward=1.0,
            accel_feedforward_nm_per_mps2=5.0,
        ),
        SensorModel(seed=0),
    )
    loop.set_mode("position")
    loop.enable()
    rows = loop.run(move.position_m)[move.move_end_index :]
    return rows[:, DriveLoop.CHANNELS.index("load_position_m")] - rows[:, DriveLoop.CHANNELS.index("position_m")]


def test_on_the_twin_a_move_rings_as_its_excitation_says():
    """Over modes from 18 to 25 Hz, the same move's first swing after it ends is ``V a / w^2`` with the
    damping the mode has in the closed loop (measured here from the ringing's decay): the zeros of ``V``,
    where the acceleration lasts a whole number of the mode's periods, ring least."""
    accel, rate = 2.0, 4000.0  # accelerates for 0.15 s
    move = trapezoid(0.2, 0.3, accel, rate, dwell_s=1.0)
    ringing = twin_deflection(23.0, move)
    window = int(0.1 * rate)
    rms = [np.std(ringing[i * window : (i + 1) * window]) for i in range(8)]
    decay_per_s = -np.polyfit(np.arange(8) * 0.1, np.log(rms), 1)[0]
    zeta = decay_per_s / (2 * math.pi * 23.0)
    assert 0.018 < zeta < 0.08  # the loop holding the cart adds to the plant's own 0.018
    ratios, firsts = [], []
    for f in np.arange(18.0, 25.5, 1.0):
        first = float(np.max(np.abs(twin_deflection(f, move)[: int(rate / f) + 1])))
        v = mode_excitation(move.position_m, rate, move.move_end_index, f, zeta)
        ratios.append(first / (v * accel / (2 * math.pi * f) ** 2))
        firsts.append(first)
    assert 0.8 < min(ratios) and max(ratios) < 1.5, ratios
    assert int(np.argmin(firsts)) == 2  # 20 Hz: three periods of it in the acceleration
    assert max(firsts) > 2.5 * min(firsts)


MOVE = MoveConfig(distance_m=0.2, max_velocity_mps=0.3, max_accel_mps2=2.0)


class MoveDone:
    """What the warning reads of a move test's result."""

    def __init__(self, start_m: float, distance_m: float, frequency_hz: float, rest_limit_db: float | None = 6.0):
        self.start_m, self.distance_m, self.rest_limit_db = start_m, distance_m, rest_limit_db
        self.modes = excitations(move_profile(MOVE, distance_m, 1000.0), None, [(frequency_hz, 0.018)])

    @property
    def weakly_excited(self):
        return [m for m in self.modes if m.excitation < 1.0]


def test_a_move_test_whose_moves_hardly_excite_their_modes_is_told_which_move_would():
    results = [MoveDone(0.5, -0.2, 20.45), MoveDone(0.0, 0.2, 20.13), MoveDone(-0.5, 0.2, 21.7)]
    warning = weak_excitation_warning(MOVE, results, 1000.0)
    assert "+0.300 m, 20.45 Hz" in warning and "+0.200 m, 20.13 Hz" in warning and "-0.300" not in warning
    assert "rang 6.0 dB above rest" in warning and "[limits] torque_nm" in warning
    suggested = {
        k: float(v)
        for k, v in (part.split(" = ") for part in warning.split("move with ")[1].split(" excites")[0].split(" and "))
    }
    better = MoveConfig(0.2, suggested["max_velocity_mps"], suggested["max_accel_mps2"])
    for r in results:
        p = move_profile(better, r.distance_m, 1000.0)
        assert (
            mode_excitation(p.position_m, 1000.0, p.move_end_index, r.modes[0].frequency_hz, 0.018) >= GOOD_EXCITATION
        )
    assert better.max_accel_mps2 >= MOVE.max_accel_mps2  # a gentler move would ring less above the same rest
    assert weak_excitation_warning(MOVE, [MoveDone(-0.5, 0.2, 21.7)], 1000.0) is None


def test_the_suggested_move_is_the_nearest_that_reaches_the_target():
    def profile(distance, v, a):
        p = trapezoid(distance, v, a, 1000.0, dwell_s=0.1)
        return p.position_m, p.move_end_index

    velocities, accels = np.linspace(0.15, 0.3, 7), np.linspace(2.0, 3.0, 6)
    modes = [[(20.0, 0.02)], [(22.0, 0.02)]]
    best = exciting_move(profile, [0.2, -0.2], modes, 1000.0, velocities, accels, (0.3, 2.0))
    assert best.min_excitation >= GOOD_EXCITATION

    def nearness(v, a):
        return max(abs(math.log(v / 0.3)), abs(math.log(a / 2.0)))

    for v in velocities:
        for a in accels:
            if nearness(v, a) < nearness(best.max_velocity_mps, best.max_accel_mps2) - 1e-12:
                worst = min(
                    mode_excitation(p, 1000.0, end, f, z)
                    for (p, end), ((f, z),) in zip((profile(d, v, a) for d in (0.2, -0.2)), modes, strict=True)
                )
                assert worst < GOOD_EXCITATION
    assert exciting_move(profile, [0.2], [[]], 1000.0, velocities, accels, (0.3, 2.0)) is None
    # candidates given as generators are tried in every combination all the same
    again = exciting_move(profile, [0.2, -0.2], modes, 1000.0, iter(velocities), (a for a in accels), (0.3, 2.0))
    assert again == best
