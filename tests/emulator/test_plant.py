"""Plant physics against analytic truth: modes, step responses, stiction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from hilident.emulator.plant import (
    MassSpringDamper,
    Plant,
    StribeckFriction,
    ThreeMass,
    TwoMass,
    frf,
    modes,
    state_matrices,
)
from hilident.errors import ConfigError

GANTRY = TwoMass(m1=8.0, m2=2.0, k=8e4, d=20.0, c=10.0)


def simulate(plant, torque_nm, dt_s, n):
    """Step ``plant`` n times with constant torque; states before every step and after the last."""
    out = np.empty((n + 1, 4))
    out[0] = plant.state
    for i in range(n):
        plant.step(torque_nm, dt_s)
        out[i + 1] = plant.state
    return out


def zero_crossings(t, y):
    """Times of the sign changes of y, linearly interpolated."""
    i = np.nonzero(np.signbit(y[:-1]) != np.signbit(y[1:]))[0]
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


def sign_changes(v):
    s = np.sign(v)
    s = s[s != 0]
    return int(np.count_nonzero(s[1:] != s[:-1]))


# -- truth functions -------------------------------------------------------------


def test_modes_two_mass_matches_closed_form():
    m = GANTRY
    f, zeta = modes(m)[0]
    mu = m.m1 * m.m2 / (m.m1 + m.m2)
    omega = math.sqrt(m.k / mu)
    assert f == pytest.approx(omega / (2 * math.pi), rel=1e-12)
    assert zeta == pytest.approx(m.d / mu / (2 * omega), rel=1e-12)
    # The full state matrix has the same non-zero eigenvalues.
    lam = np.linalg.eigvals(state_matrices(m)[0])
    lam = lam[np.abs(lam) > 1.0]
    assert np.allclose(np.abs(lam), omega, rtol=1e-9)


def test_modes_mass_spring_damper():
    f, zeta = modes(MassSpringDamper(m=5.0, b=1.0, k=10.0))[0]
    assert f == pytest.approx(math.sqrt(2.0) / (2 * math.pi), rel=1e-12)
    assert zeta == pytest.approx(1.0 / (2 * math.sqrt(50.0)), rel=1e-12)
    # Overdamped: still one mode, damping ratio > 1.
    f, zeta = modes(MassSpringDamper(m=1.0, b=10.0, k=1.0))[0]
    assert f == pytest.approx(1 / (2 * math.pi)) and zeta == pytest.approx(5.0)
    assert modes(MassSpringDamper(m=1.0, b=1.0, k=0.0)) == []


@pytest.mark.parametrize("model", [GANTRY, MassSpringDamper(m=5.0, b=1.0, k=10.0, c=2.0)])
@pytest.mark.parametrize("output", ["velocity", "position", "load_position"])
def test_frf_equals_state_space_response(model, output):
    A, B = state_matrices(model)
    n = A.shape[0]
    row = {"velocity": 1, "position": 0, "load_position": 2 if n == 4 else 0}[output]
    f = np.array([0.3, 5.0, 35.0, 36.0, 400.0])
    expected = [model.c * np.linalg.solve(2j * np.pi * fi * np.eye(n) - A, B)[row] for fi in f]
    assert np.allclose(frf(model, f, output), expected, rtol=1e-9, atol=0)


def test_frf_rejects_unknown_output():
    with pytest.raises(ValueError, match="load_velocity"):
        frf(GANTRY, [1.0], "load_velocity")


def test_stribeck_curve_shape():
    f = StribeckFriction(Fc=0.5, Fs=0.8, Fv=2.0, vs=0.01, delta_v=1.0, delta_s=2.0)
    v = np.array([1e-9, 0.01, 0.1, 1.0])
    assert f(0.0) == 0.0
    assert np.array_equal(f(-v), -f(v))
    assert f(1e-9) == pytest.approx(0.8)  # breakaway level at rest
    assert f(0.01) == pytest.approx(0.5 + 0.3 / math.e + 0.02)  # one Stribeck velocity
    assert f(1.0) == pytest.approx(0.5 + 2.0)  # Stribeck term gone


@pytest.mark.parametrize(
    "factory, key",
    [
        (lambda: TwoMass(m1=0.0, m2=1.0, k=1.0, d=0.0), "m1"),
        (lambda: TwoMass(m1=1.0, m2=-1.0, k=1.0, d=0.0), "m2"),
        (lambda: TwoMass(m1=1.0, m2=1.0, k=1.0, d=-1.0), "d"),
        (lambda: TwoMass(m1=1.0, m2=1.0, k=math.nan, d=0.0), "k"),
        (lambda: TwoMass(m1=1.0, m2=1.0, k=1.0, d=0.0, c=0.0), "c"),
        (lambda: MassSpringDamper(m=1.0, b=1.0, k=-1.0), "k"),
        (lambda: MassSpringDamper(m="heavy", b=1.0, k=1.0), "m"),
        (lambda: StribeckFriction(Fc=-0.1, Fs=0.2, Fv=0.0, vs=0.01), "Fc"),
        (lambda: StribeckFriction(Fc=0.1, Fs=0.2, Fv=0.0, vs=0.0), "vs"),
        (lambda: Plant(GANTRY, max_substep_s=0.0), "max_substep_s"),
    ],
)
def test_invalid_parameters_name_their_key(factory, key):
    with pytest.raises(ConfigError) as info:
        factory()
    assert info.value.key == key


# -- linear integration ----------------------------------------------------------


def test_free_vibration_frequency_and_damping():
    plant = Plant(GANTRY)
    plant.reset(p1=0.0, p2=5e-3)  # load deflected by 5 mm, everything at rest
    dt = 1e-4
    x = simulate(plant, 0.0, dt, 10000)
    t = np.arange(len(x)) * dt
    e = x[:, 0] - x[:, 2]

    f_n, zeta = modes(GANTRY)[0]
    f_d = f_n * math.sqrt(1 - zeta**2)
    zc = zero_crossings(t, e)
    f_measured = (len(zc) - 1) / (2 * (zc[-1] - zc[0]))
    assert f_measured == pytest.approx(f_d, rel=1e-3)

    # Successive maxima of a damped oscillation shrink by exp(-zeta w_n T_d).
    i = np.nonzero((e[1:-1] > e[:-2]) & (e[1:-1] >= e[2:]))[0] + 1
    slope = np.polyfit(t[i], np.log(e[i]), 1)[0]
    assert -slope / (2 * math.pi * f_n) == pytest.approx(zeta, rel=0.05)

    # No external force: the centre of mass stays where it was.
    com = (GANTRY.m1 * x[:, 0] + GANTRY.m2 * x[:, 2]) / (GANTRY.m1 + GANTRY.m2)
    assert np.max(np.abs(com - com[0])) < 1e-12


def test_mass_spring_damper_step_matches_lsim():
    model = MassSpringDamper(m=5.0, b=1.0, k=10.0)
    plant = Plant(model)
    dt = 0.01
    x = simulate(plant, 1.0, dt, 3000)
    t = np.arange(len(x)) * dt
    _, y = signal.step(signal.lti([1.0], [5.0, 1.0, 10.0]), T=t)
    assert np.max(np.abs(x[:, 0] - y)) <= 1e-6 * np.max(np.abs(y))
    # p2/v2 mirror p1/v1 for the single mass.
    assert np.array_equal(x[:, 2], x[:, 0]) and np.array_equal(x[:, 3], x[:, 1])


def test_substep_count_does_not_change_exact_solution():
    coarse = Plant(GANTRY, max_substep_s=1e-3)
    fine = Plant(GANTRY, max_substep_s=1e-5)
    assert fine.substeps(1e-3) == 100 and coarse.substeps(1e-3) == 1
    for p in (coarse, fine):
        p.reset(v1=0.1, p2=1e-3)
        for i in range(200):
            p.step(math.sin(0.05 * i), 1e-3)
    assert np.allclose(coarse.state, fine.state, rtol=1e-9, atol=1e-12)


# -- friction and stiction -------------------------------------------------------

FRICTION = StribeckFriction(Fc=0.5, Fs=0.8, Fv=2.0, vs=0.01)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_below_breakaway_stays_exactly_stopped_while_load_swings(sign):
    plant = Plant(GANTRY, FRICTION)
    # Load deflected by 10 um: spring force 0.8 N plus c*tau = 7.1 N stays below c*Fs = 8 N.
    plant.reset(p1=0.0, p2=sign * 1e-5)
    x = simulate(plant, sign * 0.71, 1e-3, 3000)
    assert np.all(x[:, 1] == 0.0)
    assert np.all(x[:, 0] == 0.0)
    e = x[:, 2] - x[:, 0]
    assert sign_changes(e) > 100  # m2 keeps ringing on the spring while m1 is held


def test_breakaway_threshold_is_c_times_Fs():
    dt = 1e-3
    below = Plant(GANTRY, FRICTION)
    simulate(below, 0.8 * (1 - 1e-6), dt, 500)
    assert below.v1 == 0.0 and below.p1 == 0.0
    above = Plant(GANTRY, FRICTION)
    simulate(above, 0.8 * (1 + 1e-3), dt, 500)
    assert above.v1 > 0.0 and above.p1 > 0.0
    reverse = Plant(GANTRY, FRICTION)
    simulate(reverse, -1.0, dt, 500)
    assert reverse.v1 < 0.0


def test_decelerating_mass_stops_without_chatter():
    plant = Plant(GANTRY, FRICTION)
    plant.reset(v1=0.2)  # both masses coasting at 0.2 m/s, no torque
    x = simulate(plant, 0.0, 1e-4, 30000)
    v1 = x[:, 1]
    assert sign_changes(v1) == 0
    stopped = np.nonzero(v1 == 0.0)[0]
    first = stopped[0]
    assert first < 10000
    # Once stopped it stays stopped at one position (the load's swing is within breakaway).
    tail = slice(first + 2000, None)
    assert np.all(v1[tail] == 0.0)
    assert np.ptp(x[tail, 0]) == 0.0


def test_coulomb_oscillator_loses_2F_over_k_per_half_cycle():
    # Classic result for a mass on a spring with Coulomb friction F: extremes shrink by
    # 2F/k each half cycle and the mass sticks once inside the band |y| <= F/k.
    model = MassSpringDamper(m=5.0, b=0.0, k=10.0, c=1.0)
    coulomb = StribeckFriction(Fc=0.1, Fs=0.1, Fv=0.0, vs=0.01)
    plant = Plant(model, coulomb)
    plant.reset(p1=0.105)
    x = simulate(plant, 0.0, 1e-3, 16000)
    y, v = x[:, 0], x[:, 1]
    # Extremes 0.105, -0.085, 0.065, -0.045, 0.025, then stop at -0.005.
    assert sign_changes(v) == 4
    assert y[-1] == pytest.approx(-0.005, abs=1e-5)
    assert v[-1] == 0.0
    stop = np.nonzero(v != 0.0)[0][-1] + 1
    assert np.all(y[stop:] == y[-1])
    minima = [y[i] for i in range(1, len(y) - 1) if y[i] < y[i - 1] and y[i] <= y[i + 1]]
    assert minima[0] == pytest.approx(-0.085, abs=1e-5)


def test_friction_free_plant_coasts():
    plant = Plant(MassSpringDamper(m=2.0, b=0.0, k=0.0))
    plant.reset(v1=0.5)
    plant.step(0.0, 1.0)
    assert plant.p1 == pytest.approx(0.5, rel=1e-12) and plant.v1 == pytest.approx(0.5, rel=1e-12)


def test_step_rejects_bad_arguments():
    plant = Plant(GANTRY)
    with pytest.raises(ValueError):
        plant.step(math.nan, 1e-3)
    with pytest.raises(ValueError):
        plant.step(1.0, -1e-3)


# -- three masses ------------------------------------------------------------------

# A light cart (10 kg) so that the second mode, the third mass against the load, moves it visibly.
CHAIN = ThreeMass(m1=10.0, m2=10.0, m3=5.0, k=1.5e5, d=40.0, k2=3e5, d2=20.0, c=10.0)


def test_three_mass_modes_are_the_state_matrix_eigenvalues_and_the_frf_peaks():
    A, _ = state_matrices(CHAIN)
    lam = np.linalg.eigvals(A)
    flexible = sorted(lam[np.abs(lam) > 1e-3], key=abs)[::2]  # one of each conjugate pair
    got = modes(CHAIN)
    assert len(got) == 2
    for (f, zeta), z in zip(got, flexible, strict=False):
        assert f == pytest.approx(abs(z) / (2 * np.pi), rel=1e-9)
        assert zeta == pytest.approx(-z.real / abs(z), rel=1e-6)
    f = np.linspace(5.0, 100.0, 19001)
    mag = np.abs(frf(CHAIN, f, "velocity"))
    peaks, _ = signal.find_peaks(20 * np.log10(mag), prominence=3.0)
    assert len(peaks) == 2  # each mode peaks in the cart's response, near it (its neighbours shift it a little)
    for i, (fm, _) in zip(peaks, got, strict=False):
        assert f[i] == pytest.approx(fm, rel=0.02)


def test_three_mass_with_a_vanishing_third_mass_is_the_two_mass_axis():
    tiny = ThreeMass(m1=40.0, m2=10.0, m3=1e-6, k=1.5e5, d=40.0, k2=1e3, d2=0.0, c=10.0)  # its own mode: 5 kHz
    ((f, zeta),) = [m for m in modes(tiny) if m[0] < 100.0]
    ((f2, zeta2),) = modes(TwoMass(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0))
    assert f == pytest.approx(f2, rel=1e-6) and zeta == pytest.approx(zeta2, rel=1e-5)


@pytest.mark.parametrize("output", ["velocity", "position", "load_position"])
def test_three_mass_frf_equals_state_space_response(output):
    A, B = state_matrices(CHAIN)
    row = {"velocity": 1, "position": 0, "load_position": 2}[output]
    f = np.array([0.3, 5.0, 20.0, 56.0, 400.0])
    expected = [CHAIN.c * np.linalg.solve(2j * np.pi * fi * np.eye(6) - A, B)[row] for fi in f]
    assert np.allclose(frf(CHAIN, f, output), expected, rtol=1e-9, atol=0)


def test_three_mass_step_matches_lsim_and_friction_holds_it_below_breakaway():
    A, B = state_matrices(CHAIN)
    plant = Plant(CHAIN)
    dt, n = 1e-3, 500
    x = simulate(plant, 1.0, dt, n)
    t = np.arange(n + 1) * dt
    _, y, _ = signal.lsim((A, (CHAIN.c * B)[:, None], np.eye(6), np.zeros((6, 1))), np.ones(n + 1), t, interp=False)
    assert np.max(np.abs(x[:, :4] - y[:, :4])) <= 1e-9 * np.max(np.abs(y[:, :4]))
    held = Plant(CHAIN, FRICTION)
    x = simulate(held, 0.79, dt, 300)
    assert np.all(x[:, 0] == 0.0) and np.all(x[:, 1] == 0.0)
    moving = Plant(CHAIN, FRICTION)
    assert simulate(moving, 0.81, dt, 300)[-1, 1] > 0.0


# -- backlash ------------------------------------------------------------------------

AXIS = TwoMass(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0)


def test_inside_the_play_the_load_moves_freely_and_outside_it_bounces_back():
    plant = Plant(AXIS, backlash_m=1e-3)
    plant.reset(p1=0.0, p2=0.0, v2=0.01)  # the load drifts at 10 mm/s, 0.5 mm from either side
    x = simulate(plant, 0.0, 1e-3, 40)
    assert np.all(x[:, 1] == 0.0)  # the cart feels nothing while the load crosses the gap ...
    assert x[40, 2] == pytest.approx(0.0004, rel=1e-9)
    x = simulate(plant, 0.0, 1e-3, 200)
    assert x[-1, 1] != 0.0 and np.min(x[:, 3]) < 0.0  # ... then hits its side, pushes the cart, comes back
    momentum = AXIS.m1 * x[:, 1] + AXIS.m2 * x[:, 3]
    assert np.allclose(momentum, AXIS.m2 * 0.01, rtol=1e-9)  # only internal forces


def test_a_vanishing_play_is_the_linear_coupling_and_play_rejects_a_single_mass():
    linear, played = Plant(AXIS), Plant(AXIS, backlash_m=1e-15)
    for i in range(400):
        torque = math.sin(0.05 * i)
        linear.step(torque, 2.5e-4)
        played.step(torque, 2.5e-4)
    assert np.allclose(played.state, linear.state, rtol=1e-6, atol=1e-12)
    with pytest.raises(ConfigError, match="backlash_m"):
        Plant(MassSpringDamper(m=5.0, b=1.0, k=10.0), backlash_m=1e-3)
