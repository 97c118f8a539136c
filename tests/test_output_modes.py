"""The modes several recorded outputs of one axis see (``[identification] outputs``) and the notch taken from them.

A motor output and a load sensor share their poles; the mode every output sees is the one a notch is designed
for (:mod:`hilident.pipeline.output_modes`). Checked on exact responses with a mode only the motor output sees,
and end to end on the serial gantry twin with its load sensor (``load_position_m``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from hilident.config.tables import load_config
from hilident.emulator.factory import true_modes
from hilident.errors import ConfigError
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.resonance import Resonance
from hilident.pipeline.output_modes import joint_output_modes, notch_resonances
from hilident.schemas import summary_schema
from hilident.session.run import Session

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _pair(f_hz: float, zeta: float, residue: complex, s: np.ndarray) -> np.ndarray:
    w = 2 * np.pi * f_hz
    lam = complex(-zeta * w, w * np.sqrt(1 - zeta**2))
    return residue / (s - lam) + np.conj(residue) / (s - np.conj(lam))


def _responses(noise: float, seed: int = 0) -> dict[str, FrequencyResponse]:
    """Motor output: modes at 31 and 57 Hz; load output: the 31 Hz mode only. Noise relative to each output's
    largest response, with the coherence it implies over 8 averages."""
    f = np.arange(5.0, 100.0, 0.125)
    s = 2j * np.pi * f
    motor = _pair(31.0, 0.02, 1.0 + 0.4j, s) + _pair(57.0, 0.015, 0.8j, s)
    load = _pair(31.0, 0.02, -2.0 - 0.5j, s) + 1e-4
    rng = np.random.default_rng(seed)
    out = {}
    for name, h in (("velocity_mps", motor), ("load_position_m", load)):
        sigma = noise * np.abs(h).max()
        noisy = h + sigma * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) / np.sqrt(2)
        coherence = np.abs(h) ** 2 / (np.abs(h) ** 2 + sigma**2 / 8 * 2)
        out[name] = FrequencyResponse(f, noisy, coherence, n_averages=8, method="reference")
    return out


def test_the_mode_both_outputs_see_is_found_once_and_the_motor_only_mode_is_told_apart():
    joint = joint_output_modes(_responses(noise=0.002), (10.0, 90.0))
    assert joint is not None
    frequencies = np.array(joint.frequency_hz)
    assert len(frequencies) == 2, joint.part["modes"]
    assert abs(frequencies[0] / 31.0 - 1) < 0.001 and abs(frequencies[1] / 57.0 - 1) < 0.001
    assert abs(joint.damping_ratio[0] / 0.02 - 1) < 0.05
    assert joint.seen_by[0] == ["velocity_mps", "load_position_m"]
    assert joint.seen_by[1] == ["velocity_mps"]
    assert joint.common() == [0]
    shape = joint.part["modes"][0]["shape_magnitude"]
    assert shape[1] == pytest.approx(1.0) and 0.3 < shape[0] < 0.6  # |-2 - 0.5j| against |1 + 0.4j|


def test_a_notch_takes_the_common_mode_and_a_resonance_only_the_motor_sees_keeps_its_own_estimate():
    joint = joint_output_modes(_responses(noise=0.002), (10.0, 90.0))
    motor_only = Resonance(56.9, 0.016, 10.0, 0.99)
    both = Resonance(31.2, 0.03, 20.0, 0.99)  # a rougher single-output estimate of the 31 Hz mode
    far = Resonance(45.0, 0.01, 5.0, 0.99)
    resonances, notes = notch_resonances([both, motor_only, far], joint)
    assert resonances[0].frequency_hz == pytest.approx(joint.frequency_hz[0])
    assert resonances[0].damping_ratio == pytest.approx(joint.damping_ratio[0])
    assert resonances[1] is motor_only and resonances[2] is far
    taken = {"frequency_hz": joint.frequency_hz[0], "damping_ratio": joint.damping_ratio[0]}
    assert joint.part["notch_modes"] == [{"resonance_hz": 31.2, "mode": 0, **taken}]
    assert "seen by every output" in notes[1] and "56.9" in notes[1]
    # a common mode no resonance took is said
    _, notes = notch_resonances([motor_only], joint)
    assert any("31" in n and "no resonance of the plant output was notched" in n for n in notes)


def test_one_output_gives_no_joint_estimate():
    responses = _responses(noise=0.002)
    assert joint_output_modes({"velocity_mps": responses["velocity_mps"]}, (10.0, 90.0)) is None
    assert notch_resonances([Resonance(31.0, 0.02, 1.0, 1.0)], None)[1] == []


def test_outputs_naming_the_output_or_a_channel_twice_is_a_config_error(tmp_path):
    text = (CONFIGS / "emulated-gantry.toml").read_text()
    for outputs, words in (('["velocity_mps"]', "again"), ('["load_position_m", "load_position_m"]', "twice")):
        path = tmp_path / "c.toml"
        path.write_text(text.replace('output = "velocity_mps"', f'output = "velocity_mps"\noutputs = {outputs}'))
        with pytest.raises(ConfigError, match=words) as err:
            load_config(path)
        assert "identification.outputs" in str(err.value) and "c.toml" in str(err.value)


@pytest.mark.twin
def test_the_serial_gantry_with_its_load_sensor_notches_the_mode_both_see(tmp_path):
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    cfg = replace(
        cfg,
        emulator=replace(cfg.emulator, link="pipe", time_scale=8.0),
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, amplitude_nm=8.0, duration_s=18.0, period_s=2.0),
        identification=replace(cfg.identification, outputs=["load_position_m", "position_m", "no_such_channel"]),
        notch=replace(cfg.notch, verify=False),
    )
    summary = Session(cfg, tmp_path).run()
    part = summary["mimo"]
    assert [o["column"] for o in part["outputs"]] == ["velocity_mps", "load_position_m", "position_m"]
    assert [o["unit"] for o in part["outputs"]] == ["m/s", "m", "m"]
    assert any("no_such_channel was not recorded" in w for w in summary["warnings"])
    (true_hz, _), *_ = true_modes(cfg.emulator)
    common = [m for m in part["modes"] if len(m["seen_by"]) == 3]
    assert len(common) == 1, part["modes"]
    assert abs(common[0]["frequency_hz"] / true_hz - 1) < 0.005
    # its 95 % interval from the record's periods in independent groups, holding the truth (within two half-widths:
    # the truth is one draw)
    half = common[0]["frequency_ci95_hz"]
    assert half is not None and common[0]["interval_groups"] >= 4
    assert abs(common[0]["frequency_hz"] - true_hz) < 2 * half < 0.02 * true_hz
    assert any("independent groups" in n for n in part["modal_notes"])
    (pair,) = part["notch_modes"]
    assert summary["notch_filters"][0]["center_hz"] == pytest.approx(pair["frequency_hz"])
    assert pair["frequency_hz"] == pytest.approx(common[0]["frequency_hz"])
    jsonschema.validate(summary, summary_schema())
    assert (tmp_path / "stabilisation.png").stat().st_size > 10_000  # the joint fit's diagram, in the report
    assert "stabilisation.png" in (tmp_path / "report.html").read_text()
