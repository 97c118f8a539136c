"""The loop's figures from a measured response: lines only, either output, and what is refused."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.control import Cascade, loop_margins
from hilident.control.sampled import _tick_path
from hilident.emulator.plant import TwoMass
from hilident.errors import DataError
from hilident.ident.frequency import FrequencyResponse
from hilident.pipeline.loop_analysis import analyse_loop
from hilident.pipeline.plant import PlantResult
from support.loop_truth import plant_position

LOOP_RATE, SAMPLE_RATE = 4000.0, 1000.0
MODEL = TwoMass(m1=40.0, m2=10.0, k=1.5e5, d=40.0, c=10.0)
PARAMETERS = {
    "kv_nm_per_mps": 300.0,
    "ti_s": 0.02,
    "kp_pos_per_s": 40.0,
    "velocity_filter_hz": 400.0,
    "current_loop_hz": 1000.0,
    "delay_ticks": 1,
}
F = np.arange(0.5, 450.0, 0.25)  # a dense set of measured lines, up to 0.45 of the sample rate


def recorded(output: str) -> PlantResult:
    """The response recorded every 4 ticks (images of the output left out, as the correction assumes)."""
    cascade = Cascade.from_parameters(PARAMETERS, LOOP_RATE)
    h = plant_position(MODEL, F, LOOP_RATE)
    seen = h * cascade.velocity_estimate(F) if output == "velocity_mps" else h
    path, _ = _tick_path(F, LOOP_RATE, 1000.0, 1, 4)
    folded = sum(_tick_path(F + k * SAMPLE_RATE, LOOP_RATE, 1000.0, 1, 4)[0] for k in range(4))
    frf = FrequencyResponse(F, seen * path / folded, np.ones_like(F), 4, "periodic")
    return PlantResult(plant=frf, loop=frf, resonances=[])


@pytest.mark.parametrize("output", ["velocity_mps", "position_m"])
def test_the_measured_lines_give_the_true_figures(output):
    analysis = analyse_loop(recorded(output), PARAMETERS, LOOP_RATE, SAMPLE_RATE, [], "instant", output)
    assert analysis.source == "lines" and analysis.mechanics_fit is None
    cascade = Cascade.from_parameters(PARAMETERS, LOOP_RATE)
    h = plant_position(MODEL, F, LOOP_RATE)
    for loop in ("velocity", "position"):
        truth = loop_margins(F, cascade.open_loop(F, h, loop))
        got = analysis.figures[loop]["without_notch"].margins
        assert got.phase_margin_deg == pytest.approx(truth.phase_margin_deg, abs=0.01)
        assert got.crossover_hz == pytest.approx(truth.crossover_hz, rel=1e-4)
        assert analysis.figures[loop]["with_notch"] is None


def test_a_response_to_another_channel_is_refused():
    with pytest.raises(DataError, match="load_position_m"):
        analyse_loop(recorded("position_m"), PARAMETERS, LOOP_RATE, SAMPLE_RATE, [], "instant", "load_position_m")
