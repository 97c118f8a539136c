"""Physics: the thesis's gantry follows a move without and with a host-shaped notch; the load rings >= 10 dB less.

The plant is the emulator's two-mass model (thesis eqs. 2.1-2.2, m1 40 kg, m2 10 kg,
k 1.5e5 N/m, d 40 N·s/m, c 10 N/(N·m); coupled mode 21.8 Hz), integrated exactly.
The cascade is the emulated drive's (P position -> PI velocity -> torque, its
default gains) plus the velocity and acceleration feed-forward a servo drive
uses to follow a trajectory: the feed-forward puts the profile's acceleration
steps into the torque, which is what makes a trapezoid ring. (Without
feed-forward the cascade itself low-passes the set-point; the emulator's
``DriveLoop`` has none, which is why it is not used here.)
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import find_peaks

from hilident.emulator.drive import DriveTuning
from hilident.emulator.plant import Plant, TwoMass, modes
from hilident.filters.notch import design_notch, notch_from_resonance
from hilident.motion.profiles import MoveProfile, s_curve, trapezoid
from hilident.motion.residual import compare_moves
from hilident.motion.shaping import shape_move

GANTRY = TwoMass(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0)
FS = 4000.0
DWELL_S = 1.0


def follow(move: MoveProfile) -> tuple[np.ndarray, np.ndarray]:
    """Cart and load positions (m) at each set-point sample, the cascade closed on the cart's exact state."""
    tuning = DriveTuning(loop_rate_hz=FS)
    kp, kv, ti = tuning.kp_pos_per_s, tuning.kv_nm_per_mps, tuning.ti_s
    inertia = (GANTRY.m1 + GANTRY.m2) / GANTRY.c  # N·m per m/s^2 of both masses' acceleration
    plant = Plant(GANTRY, max_substep_s=1.0 / 8000.0)
    integral = 0.0
    cart, load = [], []
    for p_ref, v_ref, a_ref in zip(
        move.position_m.tolist(), move.velocity_mps.tolist(), move.accel_mps2.tolist(), strict=True
    ):
        p1, v1, p2, _ = plant.state
        cart.append(p1)
        load.append(p2)
        velocity_error = v_ref + kp * (p_ref - p1) - v1
        integral += kv / ti / FS * velocity_error
        plant.step(inertia * a_ref + kv * velocity_error + integral, 1.0 / FS)
    return np.array(cart), np.array(load)


@pytest.fixture(scope="module")
def notch():
    frequency_hz, damping = modes(GANTRY)[0]
    assert frequency_hz == pytest.approx(21.8, abs=0.05)
    return design_notch(notch_from_resonance(frequency_hz, damping), FS)  # the project's own notch rule


@pytest.mark.parametrize("profile", ["trapezoid", "s-curve"])
def test_a_host_shaped_notch_cuts_the_loads_residual_vibration_by_10_db(profile, notch):
    move = (
        trapezoid(0.2, 0.3, 2.0, FS, DWELL_S) if profile == "trapezoid" else s_curve(0.2, 0.3, 2.0, 200.0, FS, DWELL_S)
    )
    shaped = shape_move(move, [notch])
    cart_a, load_a = follow(move)
    cart_b, load_b = follow(shaped.profile)
    # the laser rides on the cart: it sees the load's deflection p2 - p1
    deflection_a, deflection_b = load_a - cart_a, load_b - cart_b

    # without the notch the load rings at the coupled mode after the move
    end = move.move_end_index
    peaks, _ = find_peaks(deflection_a[end : end + int(0.3 * FS)])
    assert FS / np.median(np.diff(peaks)) == pytest.approx(21.8, rel=0.05)

    c = compare_moves(
        (move.time_s, deflection_a, move.move_end_s),
        (shaped.profile.time_s, deflection_b, shaped.profile.move_end_s),
        DWELL_S,
    )
    assert c.rms_reduction_db >= 10.0, c.as_dict()
    assert c.peak_to_peak_reduction_db >= 10.0, c.as_dict()
    assert c.with_notch.settling_time_s is not None and c.without.settling_time_s is not None
    assert c.with_notch.settling_time_s < c.without.settling_time_s
    # both moves end where asked: the load within a micrometre of 0.2 m at the dwell's end
    assert abs(load_a[-1] - 0.2) < 1e-6 and abs(load_b[-1] - 0.2) < 1e-6
    assert 0.0 < shaped.added_delay_s < 0.5
