"""A session with too weak an excitation: the mode within 1 %, or no notch and a warning that says what to change."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from hilident.config.tables import load_config
from hilident.emulator.factory import true_modes
from hilident.errors import DataError
from hilident.session.run import Session
from support.schema_check import schema_errors

pytestmark = pytest.mark.twin  # sessions on the gantry twin

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_weak_excitation_never_notches_where_there_is_no_mode(tmp_path):
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    cfg = replace(
        cfg,
        excitation=replace(cfg.excitation, amplitude_nm=0.5),
        friction_test=replace(cfg.friction_test, enabled=False),
        emulator=replace(cfg.emulator, link="pipe", time_scale=6.0),
    )
    ((true_f, _),) = true_modes(cfg.emulator)
    summary = Session(cfg, tmp_path, plots=False).run()
    written = json.loads((tmp_path / "summary.json").read_text())
    assert "rejected_peaks" in written and all(p["reason"] for p in written["rejected_peaks"])
    if summary["upload"]["written"]:
        (notch,) = summary["notch_filters"]
        assert abs(notch["center_hz"] - true_f) / true_f < 0.01
        assert summary["verification"]["band_reduction_db"] is not None
        return
    reason = summary["upload"]["skipped_reason"]
    assert "excitation.amplitude_nm to " in reason  # a value computed from the measurement
    suggested = float(reason.split("excitation.amplitude_nm to ")[1].split()[0])
    assert suggested > 0.5
    assert summary["notch_filters"] == [] and summary["verification"]["band_reduction_db"] is None
    assert any(reason in w for w in summary["warnings"])
    # the fitted model's modes and the reported resonances tell one story
    model = written["plant_model"]  # None when too few bins were coherent enough to fit one
    reported = {r["frequency_hz"] for r in written["resonances"]}
    assert {m["resonance_hz"] for m in (model or {"resonances": []})["resonances"] if m["reported"]} == reported


def test_an_axis_too_weakly_excited_to_move_keeps_the_friction_test_and_names_what_to_change(tmp_path):
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    ft = replace(cfg.friction_test, speeds_mps=[0.01, 0.04, 0.1, 0.2], hold_s=0.6)
    cfg = replace(
        cfg,
        excitation=replace(cfg.excitation, amplitude_nm=0.05, period_s=2.0, duration_s=4.0),
        friction_test=ft,
        emulator=replace(cfg.emulator, preset="clean", link="pipe", time_scale=8.0),
    )
    with pytest.raises(DataError, match=r"did not move.*excitation\.amplitude_nm") as err:
        Session(cfg, tmp_path, plots=False).run()
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["failed_step"] == "identification" and written["error"] == str(err.value)
    assert schema_errors(written) == []  # a partial summary is still a summary.json of its kind
    assert written["friction"]["params"]["Fc"] > 0  # what the friction test found is kept
    assert written["resonances"] == [] and written["notch_filters"] == []
    params = written["friction"]["params"]
    breakaway = max(params["Fs"], params["Fc"])  # a fitted curve may dip below its Coulomb level near standstill
    assert f"{3 * breakaway:.3g} N*m" in str(err.value)  # a value computed from the measurement
