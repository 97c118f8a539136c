"""One mechanism, two drives: the coupled plant's truth, its exact steps and the lockstep of its ports."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from scipy import signal
from scipy.linalg import eigh, expm

from hilident.emulator.coupled_plant import (
    GROUND,
    CoupledModel,
    CoupledPlant,
    PlantPort,
    coupled_frf,
    coupled_matrices,
    coupled_modes,
    coupled_state_matrices,
    dual_motor_gantry,
    mode_shapes,
    single_axis,
)
from hilident.emulator.drive import DriveLoop, DriveTuning
from hilident.emulator.plant import Plant, ThreeMass, TwoMass, frf, modes
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError

RATE = 4000.0
DT = 1.0 / RATE
COL = {name: i for i, name in enumerate(DriveLoop.CHANNELS)}
#: Unequal sides and a beam link: no symmetry helps any of the truths below.
GANTRY = dual_motor_gantry(20.0, 16.0, 10.0, 2e5, 1.5e5, 150.0, 120.0, c=10.0, k_beam=5e4, d_beam=30.0)


def hand_matrices(m_left, m_right, m_load, k_left, k_right, d_left, d_right, c, k_beam=0.0, d_beam=0.0):
    """M, D, K and the torque input of the gantry written out by hand (masses: left, right, load)."""
    M = np.diag([m_left, m_right, m_load])
    K = np.array(
        [
            [k_left + k_beam, -k_beam, -k_left],
            [-k_beam, k_right + k_beam, -k_right],
            [-k_left, -k_right, k_left + k_right],
        ]
    )
    D = np.array(
        [
            [d_left + d_beam, -d_beam, -d_left],
            [-d_beam, d_right + d_beam, -d_right],
            [-d_left, -d_right, d_left + d_right],
        ]
    )
    F = np.array([[c, 0.0], [0.0, c], [0.0, 0.0]])
    return M, D, K, F


GANTRY_HAND = hand_matrices(20.0, 16.0, 10.0, 2e5, 1.5e5, 150.0, 120.0, 10.0, 5e4, 30.0)


def block_state_space(M, D, K, F):
    """``x' = A x + B tau`` with the states ``(q, q')`` stacked (not interleaved as the module orders them)."""
    n = M.shape[0]
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ D]])
    B = np.vstack([np.zeros_like(F), Mi @ F])
    return A, B


# -- the model ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"masses": []}, "masses"),
        ({"masses": [1.0, -2.0]}, "masses[1]"),
        ({"masses": [1.0, math.nan]}, "masses[1]"),
        ({"links": [(0, 0, 1.0, 0.0)]}, "links[0].j"),
        ({"links": [(0, 5, 1.0, 0.0)]}, "links[0].j"),
        ({"links": [(-1, 0, 1.0, 0.0)]}, "links[0].i"),
        ({"links": [(0, 1, -1.0, 0.0)]}, "links[0].k"),
        ({"links": [(0, 1, 1.0, -1.0)]}, "links[0].d"),
        ({"links": [(0, 1, 0.0, 0.0)]}, "links[0]"),
        ({"links": [(0, 1, 1.0)]}, "links[0]"),
        ({"motors": []}, "motors"),
        ({"motors": [(2, 1.0)]}, "motors[0].mass"),
        ({"motors": [(True, 1.0)]}, "motors[0].mass"),
        ({"motors": [(0, 0.0)]}, "motors[0].c"),
        ({"sensors": [1, 1]}, "sensors"),
        ({"sensors": [1.0]}, "sensors[0]"),
    ],
)
def test_a_bad_model_is_refused_naming_the_field(kwargs, key):
    given = {"masses": [8.0, 2.0], "links": [(0, 1, 8e4, 20.0)], "motors": [(0, 10.0)], "sensors": [1], **kwargs}
    with pytest.raises(ConfigError) as err:
        CoupledModel(**given)
    assert err.value.key == key


def test_the_gantry_constructor_names_its_own_arguments():
    with pytest.raises(ConfigError) as err:
        dual_motor_gantry(20.0, 20.0, 10.0, 2e5, 0.0, 40.0, 40.0)
    assert err.value.key == "k_right"


def test_the_model_assembles_the_matrices_written_by_hand():
    for got, want in zip(coupled_matrices(GANTRY), GANTRY_HAND, strict=True):
        np.testing.assert_array_equal(got, want)
    A, B = coupled_state_matrices(GANTRY)
    Ab, Bb = block_state_space(*GANTRY_HAND)
    order = [0, 3, 1, 4, 2, 5]  # interleaved (q0, v0, q1, ...) from stacked (q0, q1, q2, v0, ...)
    np.testing.assert_allclose(A, Ab[np.ix_(order, order)], rtol=1e-15)
    np.testing.assert_allclose(B, Bb[order], rtol=1e-15)


# -- the truth -----------------------------------------------------------------------------


def test_the_symmetric_gantry_has_its_closed_form_modes_and_shapes():
    m, mc, k, d = 20.0, 10.0, 2e5, 40.0
    g = dual_motor_gantry(m, m, mc, k, k, d, d, c=10.0)
    # D = (d/k) K: each undamped mode w keeps its shape and has zeta = d w / (2 k).
    w1, w2 = math.sqrt(k / m), math.sqrt(k / m + 2.0 * k / mc)
    want = [(w / (2.0 * math.pi), d * w / (2.0 * k)) for w in (w1, w2)]
    np.testing.assert_allclose(coupled_modes(g), want, rtol=1e-12)
    # racking: carriages opposite, load still; then the load against both carriages (momentum: 2 m a + mc b = 0)
    want_shapes = np.array([[1.0, -1.0, 0.0, 0.0], [-mc / (2.0 * m), -mc / (2.0 * m), 1.0, 1.0]])
    np.testing.assert_allclose(mode_shapes(g), want_shapes, atol=1e-12)
    np.testing.assert_allclose(mode_shapes(g, outputs=[2, 0]), want_shapes[:, [2, 0]], atol=1e-12)


def test_undamped_frequencies_are_the_generalized_eigenvalues_of_k_and_m():
    undamped = dual_motor_gantry(20.0, 16.0, 10.0, 2e5, 1.5e5, 0.0, 0.0, c=10.0, k_beam=5e4)
    M, _, K, _ = hand_matrices(20.0, 16.0, 10.0, 2e5, 1.5e5, 0.0, 0.0, 10.0, 5e4)
    w2 = eigh(K, M, eigvals_only=True)
    want = np.sqrt(w2[1:]) / (2.0 * math.pi)  # w2[0] is the rigid motion's 0
    got = coupled_modes(undamped)
    np.testing.assert_allclose([f for f, _ in got], want, rtol=1e-12)
    np.testing.assert_allclose([z for _, z in got], 0.0, atol=1e-12)


def test_damped_modes_are_the_nonzero_eigenvalues_of_the_state_matrix():
    A, _ = block_state_space(*GANTRY_HAND)
    lam = np.linalg.eigvals(A)
    upper = sorted((z for z in lam if z.imag > 1e-6), key=abs)
    want = [(abs(z) / (2.0 * math.pi), -z.real / abs(z)) for z in upper]
    np.testing.assert_allclose(coupled_modes(GANTRY), want, rtol=1e-9)
    # each shape solves (lambda^2 M + lambda D + K) q = 0 with the mode's eigenvalue
    M, D, K, _ = GANTRY_HAND
    for z, q in zip(upper, mode_shapes(GANTRY, outputs=[0, 1, 2]), strict=True):
        residual = (z * z * M + z * D + K) @ q
        assert np.linalg.norm(residual) < 1e-9 * np.linalg.norm(K) * np.linalg.norm(q)
        assert np.max(np.abs(q)) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "axis", [TwoMass(8.0, 2.0, 8e4, 20.0, c=10.0), ThreeMass(40.0, 10.0, 2.0, 1.5e5, 40.0, 2e5, 10.0, c=10.0)]
)
def test_one_axis_has_the_plants_modes_and_frf(axis):
    model = single_axis(axis)
    np.testing.assert_allclose(coupled_modes(model), modes(axis), rtol=1e-9)
    f = np.linspace(1.0, 200.0, 97)
    for output, rows, plant_output in [
        ("position", "motor", "position"),
        ("velocity", "motor", "velocity"),
        ("position", "load", "load_position"),
    ]:
        got = coupled_frf(model, f, output=output, outputs=rows)[:, 0, 0]
        np.testing.assert_allclose(got, frf(axis, f, output=plant_output), rtol=1e-10)


def test_a_mechanism_held_by_a_damper_alone_has_no_mode_from_it():
    # mass 1 hangs on mass 0 by a damper only: a real eigenvalue and a free position, no vibration
    model = CoupledModel([5.0, 1.0], [(0, GROUND, 1e4, 2.0), (1, 0, 0.0, 3.0)], [(0, 1.0)], [1])
    (f, zeta), *rest = coupled_modes(model)
    assert not rest
    M, D, K = np.diag([5.0, 1.0]), np.array([[5.0, -3.0], [-3.0, 3.0]]), np.diag([1e4, 0.0])
    lam = np.linalg.eigvals(block_state_space(M, D, K, np.zeros((2, 1)))[0])
    z = next(v for v in lam if v.imag > 0)
    assert (f, zeta) == pytest.approx((abs(z) / (2.0 * math.pi), -z.real / abs(z)), rel=1e-9)


def test_the_frf_equals_the_state_space_response():
    A, B = block_state_space(*GANTRY_HAND)
    f = np.array([0.5, 3.0, 19.0, 19.7, 25.0, 33.6, 80.0, 400.0])
    # outputs: left and right carriage positions, then the load position twice (both lasers watch it)
    C = np.zeros((4, 6))
    C[0, 0] = C[1, 1] = C[2, 2] = C[3, 2] = 1.0
    want = np.array([C @ np.linalg.solve(2j * np.pi * fk * np.eye(6) - A, B) for fk in f])
    np.testing.assert_allclose(coupled_frf(GANTRY, f, outputs="both"), want, rtol=1e-10)
    np.testing.assert_allclose(coupled_frf(GANTRY, f), want[:, :2], rtol=1e-10)
    vel = coupled_frf(GANTRY, f, output="velocity", outputs=[2])
    np.testing.assert_allclose(vel, (2j * np.pi * f)[:, None, None] * want[:, 2:3], rtol=1e-10)
    # reciprocity: the symmetric M, D, K and equal motor constants give a symmetric matrix
    h = coupled_frf(GANTRY, f)
    np.testing.assert_allclose(h[:, 0, 1], h[:, 1, 0], rtol=1e-10)


def test_the_frf_at_zero_hz_is_infinite_for_a_free_mechanism_and_the_statics_for_a_grounded_one():
    assert np.all(np.isinf(coupled_frf(GANTRY, 0.0)))
    grounded = CoupledModel([2.0, 1.0], [(0, GROUND, 100.0, 1.0), (0, 1, 50.0, 0.0)], [(0, 2.0)], [1])
    np.testing.assert_allclose(coupled_frf(grounded, 0.0, outputs="both"), [[2.0 / 100.0], [2.0 / 100.0]])
    with pytest.raises(ValueError, match="output"):
        coupled_frf(GANTRY, 1.0, output="acceleration")
    with pytest.raises(ValueError, match="outputs"):
        coupled_frf(GANTRY, 1.0, outputs=[3])


# -- the integration -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "axis", [TwoMass(8.0, 2.0, 8e4, 20.0, c=10.0), ThreeMass(40.0, 10.0, 2.0, 1.5e5, 40.0, 2e5, 10.0, c=10.0)]
)
def test_one_port_steps_as_the_single_axis_plant(axis):
    reference = Plant(axis)
    port = CoupledPlant(single_axis(axis)).port(0)
    rng = np.random.default_rng(3)
    torques, pushes = rng.normal(0.0, 2.0, 3000), rng.normal(0.0, 5.0, 3000)
    got, want = np.empty((3000, 4)), np.empty((3000, 4))
    for k, (tau, push) in enumerate(zip(torques, pushes, strict=True)):
        for plant in (reference, port):
            plant.push_load(push, DT)
            plant.step(tau, DT)
        got[k], want[k] = port.state, reference.state
    scale = np.max(np.abs(want), axis=0)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * scale.max())
    assert port.stuck is False and port.plant.held_steps == [0]


def test_whole_steps_equal_the_zero_order_hold_discretization():
    A, B = block_state_space(*GANTRY_HAND)
    aug = np.zeros((8, 8))
    aug[:6, :6], aug[:6, 6:] = A, B
    E = expm(aug * DT)
    phi, gam = E[:6, :6], E[:6, 6:]
    plant = CoupledPlant(GANTRY)
    plant.reset(positions=[0.01, -0.02, 0.0], velocities=[0.0, 0.1, -0.1])
    x = np.array([0.01, -0.02, 0.0, 0.0, 0.1, -0.1])
    rng = np.random.default_rng(4)
    for tau in rng.normal(0.0, 1.0, (2000, 2)):
        plant.step(tau, DT)
        x = phi @ x + gam @ tau
    np.testing.assert_allclose(np.concatenate([plant.positions, plant.velocities]), x, rtol=1e-9)
    assert plant.ticks == 2000 and plant.time_s == pytest.approx(2000 * DT)


# -- two drives in two threads ------------------------------------------------------------------


def multisine(n, rng, amplitude_nm=1.0):
    """A random-phase multisine over 2-300 Hz, period n ticks, rms about ``amplitude_nm``."""
    lines = np.arange(max(1, round(2.0 * n / RATE)), round(300.0 * n / RATE) + 1)
    t = np.arange(n) / RATE
    phases = rng.uniform(0.0, 2.0 * math.pi, lines.size)
    x = np.cos(2.0 * math.pi * np.outer(t, lines * RATE / n) + phases).sum(axis=1)
    return amplitude_nm * x / np.std(x)


def torque_drive(port, seed):
    drive = DriveLoop(port, DriveTuning(loop_rate_hz=RATE), SensorModel(encoder_resolution_m=0.0, seed=seed))
    drive.set_mode("torque")
    drive.enable()
    return drive


def run_in_threads(drives, excitations, timeout_s=60.0):
    """Each drive runs its excitation in a thread of its own, all starting together; their rows."""
    rows: list = [None] * len(drives)
    barrier = threading.Barrier(len(drives))

    def play(i):
        barrier.wait()
        rows[i] = drives[i].run(excitations[i])

    threads = [threading.Thread(target=play, args=(i,), daemon=True) for i in range(len(drives))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout_s)
    assert not any(thread.is_alive() for thread in threads), "a drive did not finish: the lockstep hung"
    return rows


def reference_run(model, torques):
    """Each port's (p1, p2) before every tick, stepping the whole mechanism from one thread."""
    plant = CoupledPlant(model)
    watched = [(2 * m, 2 * s) for m, s in zip(model.motor_masses, model.sensor_masses, strict=True)]
    out = np.empty((len(torques), model.n_ports, 2))
    for k, tau in enumerate(torques):
        xs = plant.state  # (q0, v0, q1, v1, ...)
        out[k] = [(xs[i1], xs[i2]) for i1, i2 in watched]
        plant.step(tau, DT)
    return out


def test_two_drives_in_two_threads_give_exactly_the_single_threaded_run():
    n = 4000
    rng = np.random.default_rng(7)
    excitations = [multisine(n, rng), rng.normal(0.0, 1.0, n)]
    plant = CoupledPlant(GANTRY, wait_s=10.0)  # never reached: a held port would show in held_steps
    drives = [torque_drive(plant.port(p), seed=p) for p in range(2)]
    rows = run_in_threads(drives, excitations)
    assert plant.held_steps == [0, 0] and plant.ticks == n
    want = reference_run(GANTRY, np.column_stack(excitations))
    for p in range(2):
        np.testing.assert_array_equal(rows[p][:, COL["torque_nm"]], excitations[p])
        np.testing.assert_array_equal(rows[p][:, COL["position_m"]], want[:, p, 0])
        np.testing.assert_array_equal(rows[p][:, COL["load_position_m"]], want[:, p, 1])
    # the two carriages did move each other: not two independent axes
    assert np.ptp(want[:, 0, 0] - want[:, 1, 0]) > 1e-6


def test_a_port_whose_drive_stops_is_held_and_its_partner_runs_on():
    n, stop, wait_s = 3000, 1000, 0.5
    rng = np.random.default_rng(8)
    excitations = [rng.normal(0.0, 1.0, n), rng.normal(0.0, 1.0, stop)]
    plant = CoupledPlant(GANTRY, wait_s=wait_s)
    drives = [torque_drive(plant.port(p), seed=p) for p in range(2)]
    start = time.monotonic()
    rows = run_in_threads(drives, excitations)
    elapsed = time.monotonic() - start
    # one wait, then the stopped port is not waited for again (2000 waits would take 1000 s)
    assert elapsed < wait_s + 10.0
    assert plant.held_steps == [0, n - stop] and plant.ticks == n
    held = np.concatenate([excitations[1], np.full(n - stop, excitations[1][-1])])
    want = reference_run(GANTRY, np.column_stack([excitations[0], held]))
    np.testing.assert_array_equal(rows[0][:, COL["position_m"]], want[:, 0, 0])


def test_a_detached_port_has_no_torque_and_is_not_waited_for():
    plant = CoupledPlant(GANTRY, wait_s=30.0)
    left, right = plant.port(0), plant.port(1)
    assert isinstance(left, PlantPort) and plant.port(0) is left
    right.detach()
    assert not right.attached
    start = time.monotonic()
    left.step(1.5, DT)  # alone in the lockstep: advances at once
    assert time.monotonic() - start < 5.0
    reference = CoupledPlant(GANTRY)
    reference.step([1.5, 0.0], DT)
    assert plant.state == reference.state and plant.held_steps == [0, 0]
    left.detach()
    right.step(-0.5, DT)  # stepping again rejoins it
    assert right.attached and not left.attached and plant.ticks == 2


def test_detaching_the_port_a_tick_waits_for_advances_it():
    plant = CoupledPlant(GANTRY, wait_s=30.0)
    left, right = plant.port(0), plant.port(1)
    done = threading.Event()
    thread = threading.Thread(target=lambda: (left.step(1.0, DT), done.set()), daemon=True)
    thread.start()
    time.sleep(0.05)
    assert not done.is_set()  # waiting for the right port
    right.detach()
    assert done.wait(5.0)
    assert plant.ticks == 1 and plant.held_steps == [0, 0]


def test_ports_refuse_what_the_lockstep_cannot_run():
    plant = CoupledPlant(GANTRY, wait_s=0.05)
    port = plant.port(0)
    plant.port(1).detach()
    with pytest.raises(ValueError, match="finite"):
        port.step(math.nan, DT)
    with pytest.raises(ValueError, match="dt_s"):
        port.step(1.0, 0.0)
    with pytest.raises(ValueError, match="port index"):
        plant.port(2)
    with pytest.raises(ConfigError):
        CoupledPlant(GANTRY, wait_s=0.0)
    with pytest.raises(TypeError, match="Plant or a PlantPort"):
        DriveLoop(plant, DriveTuning(), SensorModel(seed=0))


# -- the truth from data --------------------------------------------------------------------------


def test_an_h1_estimate_from_two_noise_torques_matches_the_frf_around_the_modes():
    model = dual_motor_gantry(20.0, 16.0, 10.0, 2e5, 1.5e5, 300.0, 300.0, c=10.0, k_beam=5e4, d_beam=30.0)
    n, nperseg = 2**18, 2**15
    rng = np.random.default_rng(11)
    u = rng.normal(0.0, 1.0, (n, 2))
    plant = CoupledPlant(model)
    y = np.empty((n, 2))
    for k in range(n):  # each motor's position at the tick's start
        xs = plant.state
        y[k] = xs[0], xs[2]
        plant.step(u[k], DT)
    Sxx = np.empty((nperseg // 2 + 1, 2, 2), dtype=complex)
    Sxy = np.empty_like(Sxx)
    for i in range(2):
        for j in range(2):
            f, Sxx[:, i, j] = signal.csd(u[:, i], u[:, j], fs=RATE, nperseg=nperseg, detrend="linear")
            Sxy[:, i, j] = signal.csd(u[:, i], y[:, j], fs=RATE, nperseg=nperseg, detrend="linear")[1]
    # Sxy[i, j] = sum_k Sxx[i, k] H[j, k]: H1 = (Sxx^-1 Sxy)'
    h1 = np.transpose(np.linalg.solve(Sxx, Sxy), (0, 2, 1))
    band = np.zeros(f.size, dtype=bool)
    for fm, _ in coupled_modes(model):
        band |= (f > 0.8 * fm) & (f < 1.25 * fm)
    s = 2j * np.pi * f[band]
    zoh = (1.0 - np.exp(-s * DT)) / (s * DT)  # torque held over the tick, position sampled at its start
    truth = coupled_frf(model, f[band]) * zoh[:, None, None]
    err = np.linalg.norm(h1[band] - truth, axis=(1, 2)) / np.linalg.norm(truth, axis=(1, 2))
    assert np.max(err) < 0.04 and np.median(err) < 0.015
