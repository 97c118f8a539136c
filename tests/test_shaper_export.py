"""``hilident export --format klipper | marlin | shaper``: the input shaper a summary's resonances favour, in the
forms motion firmwares take, and the Klipper round trip: the exported type, frequency and damping ratio, put
through the firmware's published definitions, give hilident's impulses."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from hilident.cli.main import main
from hilident.errors import DataError
from hilident.io.shaper_export import klipper_section, shaper_document, summary_modes
from hilident.motion.input_shapers import residual_vibration, zv_shaper
from motion.test_input_shapers import REFERENCES


def _summary(*resonances) -> dict:
    """A summary as a run or an identify writes one, with these ``(frequency_hz, damping_ratio, frequency_ci95_hz,
    peak_magnitude_db)`` resonances."""
    return {
        "notch_filters": [],
        "resonances": [
            {
                "frequency_hz": f,
                "damping_ratio": z,
                "frequency_ci95_hz": ci,
                "damping_ci95": None,
                "peak_magnitude_db": p,
            }
            for f, z, ci, p in resonances
        ],
    }


@pytest.mark.parametrize(
    "resonance",
    [(21.79, 0.018, 0.05, -20.0), (37.5, 0.06, 3.0, -30.0), (61.0, 0.1, None, -10.0)],
    ids=["narrow", "wide", "no-interval"],
)
def test_the_klipper_section_round_trips_through_the_firmwares_definitions(tmp_path, resonance):
    summary = _summary(resonance)
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert main(["export", str(tmp_path), "--format", "klipper", "--axis", "y"]) == 0
    text = (tmp_path / "input_shaper.cfg").read_text()
    fields = dict(re.findall(r"^(\w+): (\S+)$", text, re.M))
    kind, f, z = fields["shaper_type_y"], float(fields["shaper_freq_y"]), float(fields["damping_ratio_y"])
    assert "[input_shaper]" in text and kind in REFERENCES
    amplitudes, times = (np.asarray(v, dtype=float) for v in REFERENCES[kind](f, z))
    doc = shaper_document(summary, "summary.json")
    assert doc["chosen"] == kind
    np.testing.assert_allclose(doc["times_s"], times, atol=1e-6)
    np.testing.assert_allclose(doc["amplitudes"], amplitudes / amplitudes.sum(), atol=1e-6)


def test_a_wide_interval_gets_a_more_robust_shaper_than_a_narrow_one():
    narrow = shaper_document(_summary((30.0, 0.03, 0.05, 0.0)), "s")
    wide = shaper_document(_summary((30.0, 0.03, 4.5, 0.0)), "s")
    assert wide["candidates"][0]["duration_s"] > narrow["candidates"][0]["duration_s"]
    assert narrow["candidates"][0]["worst_vibration"] <= narrow["target_vibration"]


def test_several_modes_are_shaped_together_in_json_and_the_strongest_in_klipper():
    summary = _summary((18.0, 0.02, 0.1, -40.0), (44.0, 0.03, 0.2, -25.0))
    assert [m[0] for m in summary_modes(summary)] == [44.0, 18.0]  # strongest first
    doc = shaper_document(summary, "s")
    chosen = doc["candidates"][0]
    assert "*" in chosen["kind"] and chosen["worst_vibration"] <= doc["target_vibration"]
    text = klipper_section(summary, "s")
    assert "shaper_freq_x: 44.000" in text and "not shaped: the mode at 18.000 Hz" in text


def test_marlin_gets_zv_at_the_strongest_mode(tmp_path):
    (tmp_path / "summary.json").write_text(json.dumps(_summary((25.0, 0.04, 0.2, -12.0))))
    assert main(["export", str(tmp_path), "--format", "marlin"]) == 0
    line = (tmp_path / "input_shaper.gcode").read_text().strip().splitlines()[-1]
    f, z = (float(v) for v in re.fullmatch(r"M593 X F([\d.]+) D([\d.]+)", line).groups())
    assert residual_vibration(zv_shaper(f, z), 25.0, 0.04) < 1e-3


def test_a_summary_without_resonances_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "summary.json").write_text(json.dumps(_summary()))
    assert main(["export", str(tmp_path), "--format", "shaper"]) != 0
    assert "no resonance" in capsys.readouterr().err
    with pytest.raises(DataError, match="nothing to shape"):
        summary_modes({"resonances": [], "mimo": {"modes": []}})


def test_the_scheduled_shaper_exports_as_a_position_table_and_in_the_json(tmp_path, capsys):
    from hilident.pipeline.input_shaper import move_shapers

    travel = [
        {"position_m": p, "frequency_hz": 20.0 + 10.0 * p, "damping_ratio": 0.02, "frequency_ci95_hz": 0.05}
        for p in (-0.2, 0.0, 0.2, 0.4)
    ]
    summary = _summary((21.0, 0.02, 0.05, -20.0))
    summary["input_shaper"] = {"over_travel": move_shapers([], travel).over_travel()}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert main(["export", str(tmp_path), "--format", "shaper-table"]) == 0
    lines = (tmp_path / "input_shaper_schedule.csv").read_text().splitlines()
    kind = summary["input_shaper"]["over_travel"]["scheduled"]["kind"]
    assert lines[0].startswith("#") and f"kind {kind}" in lines[1]
    assert lines[2] == "position_m,frequency_hz,damping_ratio"
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[3:]])
    np.testing.assert_allclose(rows, [[m["position_m"], m["frequency_hz"], m["damping_ratio"]] for m in travel])
    doc = shaper_document(summary, "summary.json")
    assert doc["scheduled"]["kind"] == kind and len(doc["scheduled"]["table"]) == 4
    assert doc["fixed_for_travel"]["worst_residual"] > 0
    # a run without [map] has no schedule to export: said, nothing written
    (tmp_path / "summary.json").write_text(json.dumps(_summary((21.0, 0.02, 0.05, -20.0))))
    (tmp_path / "input_shaper_schedule.csv").unlink()
    assert main(["export", str(tmp_path), "--format", "shaper-table"]) != 0
    assert "[map]" in capsys.readouterr().err and not (tmp_path / "input_shaper_schedule.csv").exists()


def test_klipper_gets_the_one_shaper_for_the_whole_travel_of_a_mapped_mode_and_it_round_trips(tmp_path):
    from hilident.motion.input_shapers import Shaper
    from hilident.motion.input_shapers import residual_vibration as closed_form
    from hilident.pipeline.input_shaper import move_shapers

    travel = [
        {"position_m": p, "frequency_hz": 20.0 + 20.0 * p, "damping_ratio": 0.02, "frequency_ci95_hz": 0.05}
        for p in np.linspace(0.0, 0.3, 7)
    ]  # 20 -> 26 Hz
    summary = _summary((21.0, 0.02, 0.05, -20.0))
    summary["input_shaper"] = {"over_travel": move_shapers([], travel).over_travel()}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert main(["export", str(tmp_path), "--format", "klipper"]) == 0
    text = (tmp_path / "input_shaper.cfg").read_text()
    fields = dict(re.findall(r"^(\w+): (\S+)$", text, re.M))
    kind, f, z = fields["shaper_type_x"], float(fields["shaper_freq_x"]), float(fields["damping_ratio_x"])
    assert kind == summary["input_shaper"]["over_travel"]["fixed"]["kind"] and "shaper-table" in text
    amplitudes, times = (np.asarray(v, dtype=float) for v in REFERENCES[kind](f, z))
    exported = Shaper(kind, times, amplitudes / amplitudes.sum(), f, z)
    # Klipper's shaper from the exported line keeps every mapped frequency within the 5 % target
    assert max(float(closed_form(exported, m["frequency_hz"], 0.02)) for m in travel) <= 0.05 + 1e-3
