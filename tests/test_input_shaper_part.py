"""``summary.json["input_shaper"]``: the shaper the resonances favour, and whether the measurement favours it or
it and the notch together, from where the mode lies against the velocity loop's crossover."""

from __future__ import annotations

import jsonschema
import numpy as np
import pytest

from hilident.io.summary import PlantPart, Summary
from hilident.motion.input_shapers import DESIGNS
from hilident.pipeline.input_shaper import NOTCH_COSTS_PHASE_BELOW, input_shaper_part, move_shapers
from hilident.schemas import summary_schema

RESONANCE = {"frequency_hz": 21.79, "damping_ratio": 0.018, "frequency_ci95_hz": 0.06, "damping_ci95": 0.002}


def _identify_summary() -> Summary:
    """An identify's summary that reached no resonance."""
    return Summary.of_identify(
        config="c.toml",
        data={"samples": 1000},
        plant=None,
        friction=None,
        model=None,
        designs=[],
        notch_skipped_reason=None,
        elapsed_s=0.1,
        warnings=[],
    )


def _loop(crossover_hz: float) -> dict:
    return {"velocity": {"without_notch": {"crossover_hz": crossover_hz}, "with_notch": None}}


def test_a_mode_near_the_crossover_favours_the_shaper_one_well_above_it_both():
    near = input_shaper_part([RESONANCE], _loop(RESONANCE["frequency_hz"] / (0.9 * NOTCH_COSTS_PHASE_BELOW)))
    above = input_shaper_part([RESONANCE], _loop(RESONANCE["frequency_hz"] / (1.5 * NOTCH_COSTS_PHASE_BELOW)))
    unknown = input_shaper_part([RESONANCE], None)
    assert near["favoured"] == "shaper" and "phase margin" in near["versus_notch"]
    assert above["favoured"] == "both" and "costs the loop little" in above["versus_notch"]
    assert unknown["favoured"] == "both" and "no loop described" in unknown["versus_notch"]
    chosen = near["chosen"]
    assert chosen["worst_vibration"] <= near["target_vibration"]
    assert chosen["times_s"][0] == 0.0 and sum(chosen["amplitudes"]) == pytest.approx(1.0)
    assert chosen["kind"] == near["candidates"][0]["kind"] and len(near["candidates"]) >= 5


def test_a_notch_that_leaves_a_loop_with_little_phase_margin_favours_the_shaper():
    loop = _loop(RESONANCE["frequency_hz"] / (3 * NOTCH_COSTS_PHASE_BELOW))  # well above the crossover
    loop["position"] = {"without_notch": {"phase_margin_deg": 28.3}, "with_notch": {"phase_margin_deg": 14.2}}
    part = input_shaper_part([RESONANCE], loop)
    assert (
        part["favoured"] == "shaper" and "position loop's phase margin falls from 28 to 14 deg" in part["versus_notch"]
    )
    loop["position"]["with_notch"]["phase_margin_deg"] = 26.0  # lost 2 deg only: the notch costs the loop little
    assert input_shaper_part([RESONANCE], loop)["favoured"] == "both"


def test_no_resonance_no_part_and_the_summary_leaves_it_out():
    assert input_shaper_part([], None) is None
    summary = _identify_summary().to_dict()
    assert "input_shaper" not in summary


def test_a_summary_with_a_resonance_carries_the_part_and_holds_the_schema():
    summary = _identify_summary()
    summary.plant = PlantPart([{**RESONANCE, "peak_magnitude_db": -20.0}])
    out = summary.to_dict()
    part = out["input_shaper"]
    assert part["modes"][0]["frequency_hz"] == RESONANCE["frequency_hz"] and part["favoured"] == "both"
    schema = summary_schema()
    validator = jsonschema.Draft202012Validator({**schema["properties"]["input_shaper"], "$defs": schema["$defs"]})
    assert list(validator.iter_errors(part)) == []


def _travel(spread: float) -> list[dict]:
    """A mode along 0.6 m of travel: 22 Hz +- ``spread`` (a fraction), at a damping ratio of 0.02."""
    positions = np.linspace(-0.3, 0.3, 13)
    return [
        {
            "position_m": float(p),
            "frequency_hz": 22.0 * (1.0 + spread * p / 0.3),
            "damping_ratio": 0.02,
            "frequency_ci95_hz": 0.05,
        }
        for p in positions
    ]


def test_with_a_map_the_move_test_gets_a_fixed_shaper_for_the_range_and_a_scheduled_one():
    shapers = move_shapers([{**RESONANCE, "peak_magnitude_db": -20.0}], _travel(0.15))
    fixed, scheduled = shapers.wanted(["scheduled", "fixed"])
    assert (fixed.name, scheduled.name) == ("fixed shaper", "scheduled shaper")
    assert shapers.wanted(["scheduled"]) == [scheduled] and shapers.wanted([]) == []
    travel = shapers.over_travel()
    assert travel["frequency_range_hz"] == pytest.approx([22.0 * 0.85, 22.0 * 1.15])
    # the mode moves by +-15 %: the one shaper for the range leaves more somewhere than the schedule anywhere
    assert travel["fixed"]["worst_residual"] > travel["scheduled"]["worst_residual"]
    assert travel["fixed"]["worst_residual"] == pytest.approx(max(r["fixed"] for r in travel["residuals"]))
    assert len(travel["scheduled"]["table"]) == 13 and len(travel["residuals"]) == 13
    # the schedule keeps within the target over each position's own interval
    assert travel["scheduled"]["worst_vibration"] <= 0.05
    assert scheduled.design_at(0.3).frequency_hz == pytest.approx(22.0 * 1.15)
    assert fixed.design_at(0.3) is fixed.shaper
    assert 0 < scheduled.max_accel_mps2 and 0 < fixed.max_accel_mps2


def test_without_a_map_the_fixed_shaper_is_the_one_for_the_resonances_and_nothing_is_scheduled():
    shapers = move_shapers([{**RESONANCE, "peak_magnitude_db": -20.0, "frequency_ci95_hz": float("nan")}], [])
    (fixed,) = shapers.wanted(["fixed", "scheduled"])
    part = input_shaper_part([{**RESONANCE, "peak_magnitude_db": -20.0}])
    # an interval not measured is scored over +-5 %, as the summary's 0.06 Hz one is: the same choice
    assert fixed.shaper.kind == part["chosen"]["kind"]
    np.testing.assert_allclose(fixed.shaper.times_s, part["chosen"]["times_s"])
    assert shapers.over_travel() is None
    assert move_shapers([], []).wanted(["fixed"]) == []


def test_a_run_summary_carries_the_shapers_over_the_travel_and_holds_the_schema():
    summary = _identify_summary()
    summary.plant = PlantPart([{**RESONANCE, "peak_magnitude_db": -20.0}])
    summary.extra["shaper_over_travel"] = move_shapers([], _travel(0.1)).over_travel()
    part = summary.to_dict()["input_shaper"]
    assert part["over_travel"]["scheduled"]["kind"] in DESIGNS
    schema = summary_schema()
    validator = jsonschema.Draft202012Validator({**schema["properties"]["input_shaper"], "$defs": schema["$defs"]})
    assert list(validator.iter_errors(part)) == []
