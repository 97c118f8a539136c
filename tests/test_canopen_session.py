"""Whole sessions on the emulated CiA 402 drive: the other acquisition mode, the fixed-point drive, and the
drive in another process behind a socketcand server. Its fault switches, limit trip and lost PDOs are scenarios
of ``test_scenarios.py``, run over every transport."""

from __future__ import annotations

import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import jsonschema
import numpy as np

from hilident.config.tables import load_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import true_modes
from hilident.io.recording import read_run
from hilident.schemas import summary_schema
from hilident.session.run import Session
from support.loop_truth import (
    assert_loop_figures_match,
    assert_proposal_keeps_targets_on_the_truth,
    true_loop_figures,
)

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CONFIG = CONFIGS / "emulated-canopen-gantry.toml"


def short_config(acquisition="buffered", time_scale=20.0, period_s=1.0, duration_s=2.0, **faults):
    """The shipped CANopen gantry without the friction test and with a short multisine."""
    cfg = load_config(CONFIG)
    emu = replace(cfg.emulator, time_scale=time_scale, faults=replace(cfg.emulator.faults, **faults))
    return replace(
        cfg,
        device=replace(cfg.device, acquisition=acquisition),
        emulator=emu,
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, period_s=period_s, duration_s=duration_s, amplitude_nm=8.0),
    )


def test_streamed_session_on_the_fixed_point_drive(tmp_path):
    # the drive produces SYNC, the host streams a set-point per cycle (at 250 Hz: in time even on a busy machine);
    # the notch goes into Q2.29 INTEGER32 slots; three periods, so that a few set-points a busy host held back
    # (each a held torque that sets the mode ringing) do not hide the resonance; at ten times real time (2500
    # cycles a second), where twenty left a CI run's host enough late set-points to miss the loop's figures
    cfg = short_config("streamed", time_scale=10.0, duration_s=4.0)
    cfg = replace(
        cfg, device=replace(cfg.device, driver="canopen-servo-fixed"), run=replace(cfg.run, sample_rate_hz=250.0)
    )
    session = Session(cfg, tmp_path)
    summary = session.run()
    ((true_f, true_zeta),) = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.01
    assert abs(res["damping_ratio"] - true_zeta) / true_zeta < 0.3
    assert summary["upload"]["verified_readback"] and summary["upload"]["slots"][0]["matches"]
    assert summary["verification"]["peak_reduction_db"] >= 20.0
    stream = summary["stream"]
    n = read_run(tmp_path / "identification.h5").n_samples
    assert stream["samples"] == 2 * n and stream["lost_samples"] == 0
    # the drive keeps the clock: a set-point the host could not send in time is held (and recorded as held)
    assert stream["setpoints_skipped"] <= stream["underruns"] <= stream["setpoints_skipped"] + 0.01 * 2 * n
    assert [c["source"] for c in summary["clock"]] == ["drive", "drive"]
    biquad, enabled = session.emulator.drive.filters.read(0)
    assert enabled and biquad.b == tuple(summary["upload"]["slots"][0]["readback_b"])
    assert not session.emulator.drive.enabled
    # the drive's loop read from its objects, around the plant recorded every 16 loop ticks: the margins as the
    # twin's own plant and gains give them (a short record without friction legs: 1.5 dB; the shipped sessions
    # meet 1 dB, test_session_e2e.py)
    truth = true_loop_figures(cfg.emulator, session.emulator.drive.tuning, [biquad])
    assert_loop_figures_match(summary["loop"], truth, db=1.5)
    # the proposal is made on this short record's plant: on the twin's own it keeps the targets within 1.5 dB and 8
    # degrees (a crossover near the mode feels its frequency and damping as measured in four seconds)
    tuning = session.emulator.drive.tuning
    assert_proposal_keeps_targets_on_the_truth(summary["loop"], cfg.emulator, tuning, [biquad], db=1.5, deg=8.0)
    jsonschema.validate(summary, summary_schema())
    for name in summary["recordings"]:
        run = read_run(tmp_path / name)
        assert run.complete and np.array_equal(run.samples["sample_index"], np.arange(n))


def _bench_config(tmp_path, port, **replacements) -> Path:
    text = CONFIG.read_text().replace('port = "emulator"', f'port = "{port}"')
    text = text.replace('can_interface = "socketcan"', 'can_interface = "socketcand"')
    text = text.replace('amplitude_nm = "auto"', "amplitude_nm = 8.0")  # the session, not the trials, is the point
    for old, new in replacements.items():
        text = text.replace(old, new)
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return path


def test_standalone_drive_over_socketcand_runs_a_session_like_hardware(tmp_path, standalone_emulator):
    port = standalone_emulator("canopen", CONFIG, "--time-scale", "10")
    assert port.startswith("127.0.0.1:") and port.endswith("/can0")
    cfg = _bench_config(
        tmp_path,
        port,
        **{"[friction_test]": "[friction_test]\nenabled = false", "duration_s = 16.0": "duration_s = 8.0"},
    )
    out = subprocess.run(
        [sys.executable, "-m", "hilident.cli", "run", str(cfg), "--out", str(tmp_path / "o"), "-q", "--yes"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "resonances: 21." in out.stdout and "0 lost blocks" in out.stdout
    assert (tmp_path / "o" / "summary.json").is_file()


def test_a_session_on_the_hosts_clock_reads_its_periods_around_the_cycles_it_skipped(tmp_path, monkeypatch):
    """Every cycle the host's clock misses is a sample that does not exist: none of the runs keeps a whole
    period, and each period is read by least squares on the samples it has (nothing filled in)."""
    from hilident.adapters.canopen.streamed import StreamedRun

    send_due = StreamedRun._send_due

    def miss_every_97th_cycle(self, now):
        if int((now - self.t0) / self.period) % 97 == 50:
            return  # the host's thread did not get to this cycle within its window
        send_due(self, now)

    monkeypatch.setattr(StreamedRun, "_send_due", miss_every_97th_cycle)
    # the shipped drive without SYNC timing monitoring: the host then sends within 0.4 of a period, and a machine
    # as busy as the test suite skips few cycles of its own (each one a held torque that sets the mode ringing)
    folder = tmp_path / "canopen-servo"
    shutil.copytree(find_driver("canopen-servo").folder, folder)
    toml = folder / "driver.toml"
    assert "window_us = 400" in toml.read_text()
    toml.write_text(toml.read_text().replace("window_us = 400", "window_us = 0"))
    cfg = short_config("streamed", duration_s=4.0)
    cfg = replace(
        cfg,
        device=replace(cfg.device, driver=str(folder), canopen=replace(cfg.device.canopen, sync_source="host")),
        run=replace(cfg.run, sample_rate_hz=250.0),
    )
    session = Session(cfg, tmp_path / "out")
    summary = session.run()
    ((true_f, _),) = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.01
    assert [c["source"] for c in summary["clock"]] == ["host", "host"]
    n = int(round(cfg.excitation.duration_s * 250.0))
    assert all(c["setpoints_skipped"] >= n // 97 for c in summary["clock"])
    index = read_run(tmp_path / "out" / "identification.h5").samples["sample_index"]
    period = int(round(cfg.excitation.period_s * 250.0))
    for p in range(1, n // period):  # no whole period was recorded
        assert np.count_nonzero((index >= p * period) & (index < (p + 1) * period)) < period
    assert any("read by least squares" in w for w in summary["warnings"])
    assert summary["upload"]["verified_readback"] and summary["verification"]["peak_reduction_db"] >= 20.0
