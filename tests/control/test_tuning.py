"""Proposed gains keep their targets on every plant given, and widen the loop as far as the targets allow."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.control import Cascade, bandwidth_hz, loop_margins
from hilident.control.tuning import PRESETS, Targets, propose_gains
from hilident.emulator.plant import TwoMass
from support.loop_truth import plant_position

RATE = 4000.0
F = np.geomspace(0.5, 1800.0, 3000)
PLANT = plant_position(TwoMass(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0), F, RATE)
CASCADE = Cascade(RATE, kv_nm_per_mps=100.0, ti_s=0.05, kp_pos_per_s=20.0, velocity_filter_hz=400.0,
                  current_loop_hz=1000.0, delay_ticks=1)  # fmt: skip


@pytest.mark.parametrize("preset", list(PRESETS))
def test_the_proposal_keeps_the_targets_and_is_the_widest_nearby(preset):
    targets = PRESETS[preset]
    proposal = propose_gains(CASCADE, F, [PLANT], targets)
    assert proposal is not None
    for loop in ("velocity", "position"):
        m = loop_margins(F, proposal.cascade.open_loop(F, PLANT, loop))
        assert targets.met_by(m), (loop, m)
    # a little more velocity gain breaks a target or narrows the loop: the search went as far as it could
    bolder = proposal.cascade.with_gains(kv_nm_per_mps=proposal.cascade.kv_nm_per_mps * 1.3)
    m = loop_margins(F, bolder.open_loop(F, PLANT, "velocity"))
    wider = bandwidth_hz(F, bolder.closed_loop(F, PLANT, "velocity")) > proposal.velocity_bandwidth_hz * 1.02
    assert not (targets.met_by(m) and wider)


def test_softer_targets_give_a_narrower_loop():
    bandwidths = [propose_gains(CASCADE, F, [PLANT], PRESETS[p]).velocity_bandwidth_hz for p in ("stiff", "soft")]
    assert bandwidths[0] > bandwidths[1]


def test_the_targets_hold_on_every_variant_of_the_plant():
    variants = [plant_position(TwoMass(40.0, 10.0, k, 40.0, 10.0), F, RATE) for k in (1.2e5, 1.8e5)]
    proposal = propose_gains(CASCADE, F, [PLANT, *variants], PRESETS["medium"])
    assert proposal is not None
    for h in [PLANT, *variants]:
        assert PRESETS["medium"].met_by(loop_margins(F, proposal.cascade.open_loop(F, h, "velocity")))


def test_targets_no_gain_can_keep_give_no_proposal():
    assert propose_gains(CASCADE, F, [PLANT], Targets(60.0, 89.0, 1.01)) is None


def test_no_loop_is_proposed_to_cross_over_beyond_the_band_the_plant_was_measured_in():
    free = propose_gains(CASCADE, F, [PLANT], PRESETS["soft"])
    top = 0.5 * free.velocity.crossover_hz
    capped = propose_gains(CASCADE, F, [PLANT], PRESETS["soft"], max_crossover_hz=top)
    assert capped is not None and capped.velocity_bandwidth_hz < free.velocity_bandwidth_hz
    for loop in ("velocity", "position"):
        assert loop_margins(F, capped.cascade.open_loop(F, PLANT, loop)).crossover_hz <= top
