"""The twin's coupling stiffness and damping as functions of the cart position (thesis eqs. 2.3-2.4).

Config parsing and its errors, the truth function, bit-identity of a constant
function with a number, and the simulated plant's ringing frequency against the
truth: held at two positions, and through a slow move across the travel.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

import hilident.emulator.plant as plant_module
from hilident.config.tables import PositionFunction, load_config, parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.coupling import PositionCurve
from hilident.emulator.factory import build_drive, coupling_curves, plant_model, true_modes
from hilident.emulator.plant import (
    COUPLING_TOLERANCE,
    DAMPING_TOLERANCE,
    Plant,
    ThreeMass,
    TwoMass,
    modes,
    modes_at,
)
from hilident.errors import ConfigError

MAP_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-gantry-map.toml"
LIMITS = "[limits]\ntorque_nm = 10\nvelocity_mps = 1\nposition_min_m = -0.6\nposition_max_m = 0.6\n"
K_POLY = [1.28e5, -2.7e4, 1.35e5]


def plant_config(lines: str, limits: str = LIMITS):
    return parse_config(limits + "[emulator.plant]\n" + lines + "\n", "plant.toml")


def zero_crossings(t, y):
    """Times of the upward zero crossings of y, linearly interpolated."""
    i = np.nonzero((y[:-1] < 0.0) & (y[1:] >= 0.0))[0]
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


# --- configuration --------------------------------------------------------------------------


def test_both_forms_are_read_and_a_polynomial_holds_over_the_position_window():
    plant = plant_config(
        f"k = {{ poly = {K_POLY} }}\nd = {{ positions_m = [-0.5, 0.0, 0.5], values = [30.0, 40, 50.0] }}"
    ).emulator.plant
    assert isinstance(plant.k, PositionFunction) and plant.k.poly == K_POLY and plant.k.span_m == (-0.6, 0.6)
    assert isinstance(plant.d, PositionFunction) and plant.d.is_table and plant.d.values == [30.0, 40.0, 50.0]
    k_of, d_of = coupling_curves(
        plant_config(f"k = {{ poly = {K_POLY} }}\nd = {{ positions_m = [-0.5, 0.5], values = [30.0, 50.0] }}").emulator
    )
    assert k_of is not None and d_of is not None
    assert k_of.poly == tuple(K_POLY) and d_of.positions_m == (-0.5, 0.5) and d_of.values == (30.0, 50.0)
    assert k_of(0.2) == pytest.approx(1.28e5 - 2.7e4 * 0.2 + 1.35e5 * 0.04, rel=1e-15)
    assert k_of(5.0) == k_of(0.6) and k_of(-5.0) == k_of(-0.6)  # held beyond the [limits] window
    assert d_of(0.25) == pytest.approx(45.0) and d_of(-9.0) == 30.0 and d_of(9.0) == 50.0


def test_a_number_is_read_as_before():
    plant = plant_config("k = 2e5\nd = 0").emulator.plant
    assert plant.k == 2e5 and isinstance(plant.k, float) and plant.d == 0.0
    assert coupling_curves(plant_config("k = 2e5").emulator) == (None, None)


@pytest.mark.parametrize(
    "lines, key, says",
    [
        ("k = { positions_m = [0.0, 0.0], values = [1e5, 2e5] }", "emulator.plant.k", "increase strictly"),
        ("k = { positions_m = [0.1, -0.1], values = [1e5, 2e5] }", "emulator.plant.k", "increase strictly"),
        ("d = { positions_m = [0.0, 0.1, 0.2], values = [1.0, 2.0] }", "emulator.plant.d", "differ in length"),
        ("k = { poly = [1e5, 0.0, -5e5] }", "emulator.plant.k", "> 0 over the position window [-0.6, 0.6]"),
        ("k = { positions_m = [0.0, 0.1], values = [1e5, 0.0] }", "emulator.plant.k", "> 0 everywhere"),
        ("d = { positions_m = [0.0, 0.1], values = [1.0, -0.5] }", "emulator.plant.d", ">= 0 everywhere"),
        ("d = { poly = [10.0, 40.0] }", "emulator.plant.d", ">= 0 over the position window"),
        ("k = { poly = [] }", "emulator.plant.k", "all of its lists are empty"),
        ("k = {}", "emulator.plant.k", "all of its lists are empty"),
        ("k = { positions_m = [], values = [1e5] }", "emulator.plant.k", "non-empty"),
        ("k = { poly = [1e5], values = [1e5] }", "emulator.plant.k", "not both"),
        ("k = { poly = ['1e5'] }", "emulator.plant.k.poly[0]", "must be float"),
        ("k = { positions_m = [0.0, 1.0], values = [1e5, true] }", "emulator.plant.k.values[1]", "must be float"),
        ("k = 'stiff'", "emulator.plant.k", "a number or a table"),
        ("k = [1e5]", "emulator.plant.k", "a number or a table"),
        ("k = { poly = [1e5], slope = 2 }", "emulator.plant.k.slope", "unknown key"),
        ("k = -1.0", "emulator.plant.k", "> 0"),
        ("k = { poly = [1e5, 1e4] }\nmodel = 'mass_spring_damper'", "emulator.plant.k", "two_mass and three_mass"),
    ],
)
def test_bad_functions_are_config_errors_naming_key_and_file(lines, key, says):
    with pytest.raises(ConfigError) as err:
        plant_config(lines)
    assert err.value.key == key and err.value.file == "plant.toml" and says in err.value.message, str(err.value)


def test_a_polynomial_needs_the_position_window_a_table_does_not():
    with pytest.raises(ConfigError) as err:
        plant_config("k = { poly = [1e5, 1e4] }", limits="")
    assert err.value.key == "emulator.plant.k" and "[limits]" in err.value.message
    assert plant_config("k = { positions_m = [0.0, 1.0], values = [1e5, 2e5] }", limits="").emulator.plant.k.is_table


# --- the truth ---------------------------------------------------------------------------------


def test_the_truth_is_the_model_with_k_and_d_taken_at_the_position():
    cfg = load_config(MAP_CONFIG).emulator
    k_of, d_of = coupling_curves(cfg)
    for p in (-0.5, -0.25, 0.0, 0.25, 0.5):
        expected = modes(TwoMass(m1=40.0, m2=10.0, k=float(np.polyval(K_POLY[::-1], p)), d=d_of(p), c=10.0))
        assert true_modes(cfg, p) == expected == modes_at(plant_model(cfg), p, k_of, d_of)
    f = [true_modes(cfg, p)[0][0] for p in np.linspace(-0.5, 0.5, 101)]
    middle = (max(f) + min(f)) / 2  # the shipped example: about +-8 % over the travel around the gantry's 21.8 Hz
    assert 0.07 < (max(f) - min(f)) / (2 * middle) < 0.09 and middle == pytest.approx(21.8, rel=0.01)
    zeta = [true_modes(cfg, p)[0][1] for p in np.linspace(-0.5, 0.5, 101)]
    assert max(zeta) - min(zeta) < 0.001 and np.mean(zeta) == pytest.approx(0.018, rel=0.03)


def test_the_plant_reports_its_exact_coupling_and_modes_at_a_position():
    k_of = PositionCurve(poly=K_POLY, span_m=(-0.6, 0.6))
    plant = Plant(TwoMass(40.0, 10.0, 1.5e5, 40.0, c=10.0), stiffness=k_of)
    assert plant.coupling_at(0.3) == (k_of(0.3), 40.0)
    assert plant.modes_at(0.3) == modes(TwoMass(40.0, 10.0, k_of(0.3), 40.0, c=10.0))


# --- simulation ---------------------------------------------------------------------------------


def _bench_drive(cfg):
    drive = build_drive(cfg.emulator, find_driver("myrio-board"))
    drive.enable()
    excitation = 2.0 * np.sin(2 * np.pi * 19.0 * np.arange(6000) / 4000.0)
    return drive.run(excitation)


def test_a_constant_function_gives_bit_identical_trajectories_to_the_number():
    gantry = MAP_CONFIG.read_text()
    number = gantry.replace("k = { poly = [1.28e5, -2.7e4, 1.35e5] }", "k = 1.5e5").replace(
        "d = { positions_m = [-0.6, -0.4, -0.2, 0.0, 0.2, 0.4, 0.6], "
        "values = [45.3, 41.4, 38.5, 37.0, 37.0, 38.5, 41.4] }",
        "d = 40.0",
    )
    poly = number.replace("k = 1.5e5", "k = { poly = [1.5e5] }").replace("d = 40.0", "d = { poly = [40.0, 0.0] }")
    table = number.replace("k = 1.5e5", "k = { positions_m = [-0.5, 0.5], values = [1.5e5, 1.5e5] }")
    reference = _bench_drive(parse_config(number))
    assert np.ptp(reference[:, 4]) > 1e-4  # the cart moves (bench preset: friction, noise, disturbances)
    for text in (poly, table):
        cfg = parse_config(text)
        assert isinstance(cfg.emulator.plant.k, PositionFunction)
        assert np.array_equal(_bench_drive(cfg), reference)
    assert not np.array_equal(_bench_drive(parse_config(gantry)), reference)  # the position-dependent twin differs


def _frictionless(stiffness, damping, **model):
    return Plant(
        TwoMass(**{"m1": 40.0, "m2": 10.0, "k": 1.5e5, "d": 40.0, "c": 10.0, **model}),
        None,
        max_substep_s=1 / 16000,
        stiffness=stiffness,
        damping=damping,
    )


def _ringing(plant, p, v=0.0, seconds=2.0, dt=1 / 4000):
    """Release the plant at ``p`` after an impulse between cart and load (no net momentum), coasting at ``v``.

    Returns the times, cart positions and the deflection ``p1 - p2``, one sample per step.
    """
    m1, m2 = plant.model.m1, plant.model.m2
    plant.reset(p, v - 1e-4 * m2 / (m1 + m2), p, v + 1e-4 * m1 / (m1 + m2))
    n = int(round(seconds / dt))
    out = np.empty((n, 2))
    for i in range(n):
        out[i] = plant.p1, plant.p1 - plant.p2
        plant.step(0.0, dt)
    return np.arange(n) * dt, out[:, 0], out[:, 1]


@pytest.mark.parametrize("position_m", [-0.45, 0.3])
def test_held_at_a_position_the_plant_rings_at_the_true_frequency(position_m):
    cfg = load_config(MAP_CONFIG).emulator
    plant = _frictionless(*coupling_curves(cfg))
    t, p1, e = _ringing(plant, position_m)
    assert np.ptp(p1) < 1e-5  # held: the cart barely moves
    crossings = zero_crossings(t, e)
    measured_hz = (len(crossings) - 1) / (crossings[-1] - crossings[0])
    ((f_n, zeta),) = true_modes(cfg, position_m)
    assert measured_hz == pytest.approx(f_n * math.sqrt(1 - zeta**2), rel=0.002)
    assert abs(measured_hz - true_modes(cfg, -position_m)[0][0]) > 0.2  # the two positions differ well beyond that
    # and the decay is the true damping ratio's: amplitude per period falls by exp(-2 pi zeta / sqrt(1 - zeta^2))
    peaks = np.array([np.max(e[(t >= a) & (t < b)]) for a, b in zip(crossings[:-1], crossings[1:], strict=True)])
    decrement = np.log(peaks[:-1] / peaks[1:]).mean()
    assert decrement == pytest.approx(2 * math.pi * zeta / math.sqrt(1 - zeta**2), rel=0.01)


def test_a_slow_move_across_the_travel_changes_the_ringing_frequency_as_k_says():
    k_of = PositionCurve(poly=K_POLY, span_m=(-0.6, 0.6))
    plant = _frictionless(k_of, None, d=0.0)  # undamped: the ringing lasts the whole move
    t, p1, e = _ringing(plant, -0.5, v=0.1, seconds=10.0)
    assert p1[0] == -0.5 and p1[-1] == pytest.approx(0.5, abs=1e-3)
    crossings = zero_crossings(t, e)
    periods = np.diff(crossings)
    where = np.interp(crossings[:-1] + periods / 2, t, p1)
    truth = np.array([modes(TwoMass(40.0, 10.0, k_of(p), 0.0))[0][0] for p in where])
    assert len(periods) > 200
    assert np.max(np.abs(1 / periods / truth - 1)) < 0.002
    assert 1 / periods.max() < 20.1 and 1 / periods.min() > 23.4  # the mode swept from 23.5 Hz to 20.0 Hz and back


def test_the_coupling_in_use_stays_within_the_tolerance_and_a_held_cart_builds_no_matrices(monkeypatch):
    k_of = PositionCurve(poly=K_POLY, span_m=(-0.6, 0.6))
    d_of = PositionCurve(positions_m=[-0.6, 0.0, 0.6], values=[45.0, 37.0, 41.0])
    plant = _frictionless(k_of, d_of)
    plant.reset(-0.5, 0.4, -0.5, 0.4)
    worst_k = worst_d = 0.0
    for _ in range(10000):  # 2.5 s at 0.4 m/s: across the travel
        start = plant.p1  # a step takes the coupling where it starts
        plant.step(0.0, 1 / 4000)
        k, d = plant.coupling
        worst_k = max(worst_k, abs(k / k_of(start) - 1))
        worst_d = max(worst_d, abs(d / d_of(start) - 1))
    assert plant.p1 > 0.49 and worst_k <= COUPLING_TOLERANCE and worst_d <= DAMPING_TOLERANCE
    assert worst_k > COUPLING_TOLERANCE / 10 and worst_d > DAMPING_TOLERANCE / 10  # snapped, not exact
    built = []
    monkeypatch.setattr(
        plant_module,
        "state_matrices",
        lambda *a: built.append(a) or (_ for _ in ()).throw(AssertionError("matrices rebuilt")),
    )
    plant.reset(0.2, 0.0, 0.2 + 1e-6, 0.0)
    held = plant.coupling
    for _ in range(4000):
        plant.step(0.0, 1 / 4000)
    assert plant.coupling == held and not built


def test_three_mass_first_coupling_follows_the_position():
    k_of = PositionCurve(poly=K_POLY, span_m=(-0.6, 0.6))
    model = ThreeMass(40.0, 10.0, 2.0, 1.5e5, 40.0, 2e5, 10.0, c=10.0)
    plant = Plant(model, stiffness=k_of)
    for p in (-0.5, 0.1):
        plant.reset(p)
        assert plant.modes_at(p) == modes(dataclasses.replace(model, k=k_of(p)))
        assert plant.coupling[0] == pytest.approx(k_of(p), rel=COUPLING_TOLERANCE)
    plant.reset(-0.5, 0.2)
    for _ in range(2000):
        plant.step(0.0, 1 / 4000)
    assert plant.p1 == pytest.approx(-0.4, abs=1e-3) and plant.coupling[0] == pytest.approx(k_of(plant.p1), rel=1e-4)


def test_a_position_function_needs_a_coupling():
    with pytest.raises(ConfigError, match="two masses"):
        Plant(plant_module.MassSpringDamper(5.0, 1.0, 10.0), stiffness=PositionCurve(poly=[10.0, 1.0]))
