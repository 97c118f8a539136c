"""``summary.json["input_shaper"]``: the shaper the resonances favour, and whether the measurement favours it or
it and the notch together, from where the mode lies against the velocity loop's crossover."""

from __future__ import annotations

import jsonschema
import pytest

from hilident.io.summary import PlantPart, Summary
from hilident.pipeline.input_shaper import NOTCH_COSTS_PHASE_BELOW, input_shaper_part
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
