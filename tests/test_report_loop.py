"""The report's section on the drive's loop shows summary.json["loop"], and says when there is none."""

from __future__ import annotations

import json
from types import SimpleNamespace

from hilident.html_report.loop_section import loop
from hilident.html_report.sections import SECTIONS

FIGURES = {
    "gain_margin_db": 12.5,
    "gain_margin_hz": 300.0,
    "phase_margin_deg": 48.5,
    "crossover_hz": 21.0,
    "sensitivity_peak": 1.6,
    "sensitivity_peak_hz": 25.0,
    "sensitivity_peak_db": 4.08,
    "bandwidth_hz": 30.0,
}
LOOP = {
    "parameters": {"kv_nm_per_mps": 100.0, "ti_s": 0.05},
    "grid_hz": [1.0, 1800.0],
    "measured_band_hz": [2.0, 80.0],
    "source": "model",
    "mechanics_fit": {"gain_db_rms": 0.15, "phase_rms_deg": 0.8},
    "velocity": {"without_notch": FIGURES, "with_notch": {**FIGURES, "phase_margin_deg": 41.5}},
    "position": {"without_notch": FIGURES, "with_notch": None},
    "tuning": {
        "targets": {"gain_margin_db": 10.0, "phase_margin_deg": 50.0, "sensitivity_peak": 1.7},
        "plants": 3,
        "without_notch": {
            "gains": {"kv_nm_per_mps": 2062.0, "ti_s": 0.0073, "kp_pos_per_s": 98.1},
            "velocity": FIGURES,
            "position": FIGURES,
        },  # fmt: skip
        "with_notch": None,
        "verdict": "the notch leaves no gains that keep the targets; without it: 30.0 Hz",
    },
    "notes": ["loop: the gain margins (300-300 Hz) lie beyond the measured band 2-80 Hz"],
}


def test_the_loop_section_shows_the_margins_the_proposal_and_the_verdict():
    html = loop(SimpleNamespace(summary={"loop": json.loads(json.dumps(LOOP))}))
    assert 'id="loop"' in html
    assert "48.5 deg" in html and "41.5 deg" in html  # without and with the notch
    assert "2062" in html and "98.1" in html  # the gains proposed
    assert "the notch leaves no gains that keep the targets" in html
    assert "lie beyond the measured band" in html


def test_a_run_without_a_described_loop_says_so():
    html = loop(SimpleNamespace(summary={}))
    assert "describes no loop" in html


def test_the_section_is_part_of_the_page():
    assert "loop" in [anchor for anchor, _, _ in SECTIONS]


def test_the_section_shows_the_gains_uploaded_and_the_closed_loop_against_its_prediction():
    check = {
        "band_hz": [2.0, 80.0],
        "lines": 304,
        "lines_left_out": 9,
        "max_gain_error_db": 1.7,
        "max_gain_error_hz": 20.0,
        "max_phase_error_deg": -8.5,
        "max_phase_error_hz": 20.75,
        "rms_gain_error_db": 0.32,
        "rms_phase_error_deg": 2.5,
        "tolerance_db": 2.0,
        "tolerance_deg": 10.0,
        "lines_outside": 0,
        "within_tolerance": True,
        "amplitude_mps": 0.0248,
        "measured_bandwidth_hz": 14.9,
        "predicted_bandwidth_hz": 15.1,
    }
    upload = {
        "uploaded": True,
        "kept": True,
        "before": {"kv_nm_per_mps": 100.0, "ti_s": 0.05, "kp_pos_per_s": 20.0},
        "readback": {"kv_nm_per_mps": 446.7, "ti_s": 0.164, "kp_pos_per_s": 24.07},
        "check": {"worst": {"loop": "position", "gain_margin_db": 10.02, "phase_margin_deg": 73.7}},
        "closed_loop": check,
    }
    html = loop(SimpleNamespace(summary={"loop": {**json.loads(json.dumps(LOOP)), "upload": upload}}))
    assert "kept" in html and "446.7" in html and "24.07" in html
    assert "304 lines" in html and "9 below the coherence threshold" in html and "-8.5 deg" in html
    assert "measured 14.9 Hz, predicted 15.1 Hz" in html
    refused = {"uploaded": False, "kept": False, "reason": "refused before upload: the gains ... would leave ..."}
    html = loop(SimpleNamespace(summary={"loop": {**json.loads(json.dumps(LOOP)), "upload": refused}}))
    assert "not written" in html and "refused before upload" in html


def test_the_section_shows_the_loop_measured_by_injection_beside_the_prediction():
    measured = {
        "loop": "torque",
        "lines": 309,
        "measured_lines": 140,
        "measured": {**FIGURES, "phase_margin_deg": 19.28},
        "predicted": {**FIGURES, "phase_margin_deg": 19.47},
        "rms_gain_difference_db": 1.2,
        "rms_phase_difference_deg": 7.1,
        "note": "measured: the margins on the lines where |L| >= 0.1",
    }
    html = loop(SimpleNamespace(summary={"loop": {**json.loads(json.dumps(LOOP)), "measured": measured}}))
    assert "measured (torque injection)" in html and "19.3 deg" in html and "19.5 deg" in html
    assert "140 lines" in html


def test_the_section_shows_the_feedforward_proposed_and_the_steps_against_their_prediction():
    tuning = {
        **LOOP["tuning"],
        "feedforward": {
            "terms": {"accel_feedforward_nm_per_mps2": 5.01, "velocity_feedforward": 1.0},
            "left_out": {"friction_feedforward_nm": "no friction test ([friction_test]) identified the friction"},
        },
    }
    figures = {"final": 0.95, "overshoot_percent": 36.9, "rise_time_s": 0.019, "settling_time_s": None}
    step = {
        "amplitude_mps": 0.0185,
        "hold_s": 0.1,
        "periods": 4,
        "rms_error_percent": 1.28,
        "prediction_spread_percent": 0.01,
        "tolerance_percent": 10.0,
        "within_tolerance": True,
        "measured": figures,
        "predicted": {**figures, "overshoot_percent": 35.1},
    }
    upload = {"uploaded": True, "kept": True, "step": step}
    html = loop(SimpleNamespace(summary={"loop": {**json.loads(json.dumps(LOOP)), "tuning": tuning, "upload": upload}}))
    assert "accel_feedforward_nm_per_mps2 5.01" in html and "friction_feedforward_nm left out" in html
    assert "1.28 %" in html and "overshoot 36.9 %" in html and "overshoot 35.1 %" in html
    no_step = {"uploaded": True, "kept": True, "step": {"reason": "the plant is known only on its measured lines"}}
    html = loop(SimpleNamespace(summary={"loop": {**json.loads(json.dumps(LOOP)), "upload": no_step}}))
    assert "known only on its measured lines" in html
