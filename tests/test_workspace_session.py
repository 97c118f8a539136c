"""The resonance over the workspace, end to end on the position-dependent gantry twin: the map against the
twin's truth at every position, the joint fit against its k(p), the covering notch on what the drive stores,
and the move test without and with the notch on every transport whose drive holds position."""

from __future__ import annotations

import json
import os
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from scipy import signal

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import true_modes
from hilident.session.run import Session
from support.report_page import check_report
from support.schema_check import schema_errors
from support.twins import quick

pytestmark = pytest.mark.twin  # map runs and moves: sessions on twins

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
MAP_CONFIG = CONFIGS / "emulated-gantry-map.toml"


def quick_map(move: bool) -> dict:
    """The shipped map config on the clean twin (its friction test identifies the friction the map then removes
    from the torque) at a fixed amplitude, in faster simulated time, the band figure measured again at every
    mapped position; with or without its move test."""
    raw = tomllib.loads(MAP_CONFIG.read_text())
    raw["excitation"]["amplitude_nm"] = 10.0
    raw["emulator"].update(preset="clean", time_scale=12.0, link="pipe")  # the line itself is the other tests'
    raw["map"]["verify"] = True
    raw["verification"]["move"]["repeats"] = 1  # the clean twin has no vibration at rest to average away
    if not move:
        del raw["verification"]
    return raw


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """One map session (verified at every position, then its move test) for the whole test run, whichever
    pytest-xdist workers run these tests: the first to get here runs it, the others wait for its summary (two
    board twins at time scale 12 starve each other on two cores)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of this test run
    out, claim, done = root / "workspace-map", root / "workspace-map.claim", root / "workspace-map.done"
    cfg = parse_config(tomli_w.dumps(quick_map(move=True)), str(MAP_CONFIG))
    try:
        os.close(os.open(claim, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        deadline = time.monotonic() + 900
        while not done.exists():
            assert time.monotonic() < deadline, "the map session on another worker did not finish in 900 s"
            time.sleep(0.5)
    else:
        try:
            Session(cfg, out).run()
        finally:
            done.touch()
    summary_file = out / "summary.json"
    assert summary_file.is_file(), "the map session failed (see the worker that ran it)"
    return cfg, json.loads(summary_file.read_text()), out


def test_the_map_finds_the_mode_at_every_position_within_half_a_percent(mapped):
    cfg, summary, _ = mapped
    points = summary["map"]
    assert [round(p["target_m"], 6) for p in points] == [-0.5, -0.25, 0.0, 0.25, 0.5]
    for p in points:
        assert abs(p["position_m"] - p["target_m"]) < 0.01  # held where it was moved
        truth_hz, _ = true_modes(cfg.emulator, p["position_m"])[0]
        assert abs(p["frequency_hz"] - truth_hz) / truth_hz < 0.005, (p, truth_hz)
        assert 0 < p["frequency_ci95_hz"] < 0.01 * truth_hz
    spread = max(p["frequency_hz"] for p in points) / min(p["frequency_hz"] for p in points)
    assert spread > 1.12  # the twin's mode moves by about +-8 % over the travel: the map sees it move


def test_the_joint_fit_recovers_the_stiffness_polynomial(mapped):
    """Within 2 %. Three things make it so (each was worth a percent or more of k1 on this twin): the board
    records the torque as its mean over the sample period (PROTOCOL.md section 7), the fit estimates the lag of
    the drive's velocity estimate, and the friction curve is not extrapolated below the friction test's slowest
    speed when it is removed from the torque."""
    cfg, summary, _ = mapped
    fit = summary["workspace"]["joint_fit"]
    configured = cfg.emulator.plant.k.poly
    found = fit["k_n_per_m"]["coefficients"]
    assert len(found) == len(configured) == 3
    for got, want in zip(found, configured, strict=True):
        assert abs(got - want) / abs(want) < 0.02, (found, configured)
    # the velocity filter (400 Hz: 0.40 ms) and the backward difference's half tick, read as one lag
    assert fit["lag_estimated"] and 0.1e-3 < fit["velocity_lag_s"] < 0.8e-3
    # the masses to 5 %: what is left of the cart's stiction near standstill biases m1 by a few percent
    assert fit["m1_kg"] == pytest.approx(cfg.emulator.plant.m1, rel=0.05)
    assert fit["m2_kg"] == pytest.approx(cfg.emulator.plant.m2, rel=0.05)
    # the joint model's mode beside each position's own estimate
    comparison = fit["comparison"]
    assert len(comparison) == len(summary["map"])
    assert all(abs(c["difference_percent"]) < 0.5 for c in comparison)


def test_the_covering_notch_holds_twenty_db_over_the_mapped_range_as_stored(mapped):
    _, summary, out = mapped
    covering = summary["workspace"]["covering_notch"]
    lo, hi = covering["range_hz"]
    upload = summary["upload"]
    assert upload["written"] and upload["verified_readback"]
    # independently of the design code: the chain the drive read back, evaluated with scipy
    rate = covering["sample_rate_hz"]
    grid = np.linspace(lo, hi, 2000)
    gain = np.ones(grid.size, dtype=complex)
    for slot in upload["slots"]:
        _, h = signal.freqz(slot["readback_b"], slot["readback_a"], worN=grid, fs=rate)
        gain *= h
    worst_db = -20 * np.log10(np.abs(gain).max())
    assert worst_db >= 20.0, (worst_db, covering["message"])
    assert covering["worst_attenuation_db"] >= 20.0 and covering["used_worst_attenuation_db"] >= 20.0
    truth = [
        true_modes(parse_config(MAP_CONFIG.read_text(), str(MAP_CONFIG)).emulator, p)[0][0] for p in (-0.5, 0.1, 0.5)
    ]
    assert lo <= min(truth) * 1.002 and hi >= max(truth) * 0.998  # the range spans the twin's whole spread

    # measured at every mapped position, the notches enabled, against the map's own record: the command entering
    # the filter slots to the velocity, as a single-position run measures it in open-loop torque
    verified = summary["workspace"]["verification"]
    assert verified["measured_on"] == "filtered_plant" and len(verified["positions"]) == 5
    assert all(r["reduction_db"] >= 20.0 for r in verified["positions"]), verified
    assert verified["worst_band_reduction_db"] == min(r["band_reduction_db"] for r in verified["positions"]) >= 20.0
    # the loop's figure (excitation to velocity) is reported beside it: the notch also takes away the damping the
    # holding loop gave the mode, so a torque disturbance sees less of the 20 dB
    loop_worst = verified["worst_loop_band_reduction_db"]
    assert loop_worst == min(r["loop_band_reduction_db"] for r in verified["positions"])
    assert 10.0 < loop_worst < verified["worst_band_reduction_db"]
    # beside each figure: what the stored sections predict on the map's own response, and the record's floor
    for row in verified["positions"]:
        assert row["predicted_band_reduction_db"] >= 20.0
        assert row["floor_limited"] == (row["floor_db"] < row["band_reduction_db"] + 6.0)
        assert row["recordings"][0] == row["recording"] and row["periods"] >= 2
        assert all((out / name).is_file() for name in row["recordings"])


def test_the_verification_figure_is_recomputed_from_the_recordings(mapped):
    """The verification's reduction at each mode's line, from the two recordings alone (command to velocity,
    period-averaged spectra with plain numpy), against the summary's."""
    _, summary, out = mapped
    rate = summary["sample_rate_hz"]
    for point, row in zip(summary["map"], summary["workspace"]["verification"]["positions"], strict=True):
        f_hz, before = line_spectra(out / point["recording"], rate)
        f_after, after = line_spectra([out / name for name in row["recordings"]], rate)
        assert np.allclose(f_hz, f_after)
        line = int(np.argmin(np.abs(f_hz - row["frequency_hz"])))
        plant = [s["velocity_mps"][line] / s["torque_cmd_nm"][line] for s in (before, after)]
        measured_db = 20 * np.log10(abs(plant[0]) / abs(plant[1]))
        assert measured_db == pytest.approx(row["reduction_db"], abs=1.0)
        # and the loop's figure, excitation to velocity, is the smaller one at the line
        loop = [s["velocity_mps"][line] / s["excitation"][line] for s in (before, after)]
        assert 20 * np.log10(abs(loop[0]) / abs(loop[1])) == pytest.approx(row["loop_reduction_db"], abs=1.0)


def line_spectra(paths, rate_hz: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Periodic records' spectra at their excited lines, averaged over every record's whole periods but its first
    (the transient), with plain numpy: ``(frequency_hz, {channel: spectrum})``. ``paths``: one record or the
    records of one excitation (a verification and its longer second record)."""
    import h5py

    periods: dict[str, list[np.ndarray]] = {}
    for path in [paths] if isinstance(paths, Path) else paths:
        with h5py.File(path) as f:
            names = [str(n) for n in f.attrs["channel_names"]]
            rows, period = f["samples"][()], int(f.attrs["period_samples"])
        whole = len(rows) // period - 1
        for i, n in enumerate(names):
            periods.setdefault(n, []).append(
                np.fft.rfft(rows[len(rows) - whole * period :, i].reshape(whole, period), axis=1)
            )
    spectra = {n: np.concatenate(x).mean(0) for n, x in periods.items()}
    lines = np.flatnonzero(np.abs(spectra["excitation"]) > 1e-3 * np.abs(spectra["excitation"]).max())
    return lines * rate_hz / period, {n: x[lines] for n, x in spectra.items()}


def loop_margins(out: Path, summary: dict) -> tuple[float, float]:
    """The holding loop's modulus margin min |1 + L| over the mapped positions, without and with the chain the
    drive read back, computed from the map's recordings alone: period-averaged spectra at the excited lines,
    ``G`` = torque to velocity, ``T`` = excitation to velocity, ``L = G / T - 1``."""
    rate = summary["workspace"]["covering_notch"]["sample_rate_hz"]
    without, with_chain = np.inf, np.inf
    for point in summary["map"]:
        f_hz, spectra = line_spectra(out / point["recording"], summary["sample_rate_hz"])
        v = spectra["velocity_mps"]
        gain = (v / spectra["torque_nm"]) / (v / spectra["excitation"]) - 1.0
        chain = np.ones(f_hz.size, dtype=complex)
        for slot in summary["upload"]["slots"]:
            chain *= signal.freqz(slot["readback_b"], slot["readback_a"], worN=f_hz, fs=rate)[1]
        without = min(without, float(np.abs(1 + gain).min()))
        with_chain = min(with_chain, float(np.abs(1 + chain * gain).min()))
    return without, with_chain


def test_the_notches_keep_half_the_holding_loops_margin(mapped):
    """Every 20 dB over a few hertz costs phase far below them, where the loop that holds the cart crosses over:
    the notches chosen for the workspace must leave it stable with room to spare."""
    _, summary, out = mapped
    margin = summary["workspace"]["covering_notch"]["loop_margin"]
    without, with_chain = loop_margins(out, summary)
    assert without == pytest.approx(margin["without_notches"], rel=0.1)
    assert with_chain == pytest.approx(margin["with_notches"], rel=0.1)
    assert with_chain >= 0.5 * without > 0.25


def test_a_loop_with_little_margin_gets_a_narrower_notch_and_says_why(tmp_path):
    """The same map with the velocity loop's integral corner at its crossover (ti 0.05 s: a modulus margin of
    0.4): the staggered set would leave about 0.06, so one narrower notch holds the mode down less and the loop
    keeps half its margin."""
    raw = quick_map(move=False)
    raw["map"].update(verify=False, count=3)  # -0.5, 0, 0.5 m: the joint model spans the travel between them
    raw["notch"]["verify"] = False  # the loop's margins are computed from the map; no second run needed
    raw["emulator"]["drive"]["ti_s"] = 0.05
    cfg = parse_config(tomli_w.dumps(raw), str(MAP_CONFIG))
    summary = Session(cfg, tmp_path, plots=False).run()
    covering = summary["workspace"]["covering_notch"]
    margin = covering["loop_margin"]
    first, used = margin["tried"][0], margin["tried"][-1]
    assert first["used"].endswith("staggered notches, enabled together") and first["worst_attenuation_db"] >= 20.0
    assert first["modulus_margin"] < 0.5 * margin["without_notches"] <= used["modulus_margin"]
    assert covering["used"] == used["used"] and "keep the holding loop" in used["used"]
    assert len(summary["upload"]["slots"]) == 1
    without, with_chain = loop_margins(tmp_path, summary)
    assert with_chain >= 0.5 * without and with_chain == pytest.approx(used["modulus_margin"], rel=0.1)
    assert any("keep_modulus_margin = 0.5 asks for" in w and "modulus margin" in w for w in summary["warnings"])
    assert covering["used_worst_attenuation_db"] == pytest.approx(used["worst_attenuation_db"])
    assert covering["used_worst_attenuation_db"] < 20.0 <= covering["worst_attenuation_db"]
    # no move test, and still the shapers for the mapped travel, for the export
    travel = summary["input_shaper"]["over_travel"]
    assert len(travel["scheduled"]["table"]) == 50 and travel["fixed"]["worst_residual"] > 0


def test_the_map_run_writes_its_plot_its_report_and_a_valid_summary(mapped):
    _, summary, out = mapped
    assert schema_errors(summary) == []
    assert (out / "map.png").is_file()
    page = check_report(out)
    assert "The mode identified at each position" in page.sections["workspace"]
    assert sum(f"map_{i}.h5" in page.sections["workspace"] for i in range(5)) == 5
    assert "stiffness k(p), N/m" in page.sections["workspace"]
    assert summary["workspace"]["covering_notch"]["used"] in page.sections["workspace"]
    # the staggered notches share one resonance: the verification compares it once
    verified = [r["frequency_hz"] for r in summary["verification"]["resonances"]]
    assert len(summary["notch_filters"]) == 2 and len(verified) == len(set(verified)) == 1
    assert "No [verification] move" not in page.sections["moves"] and (out / "moves.png").is_file()
    assert all((out / p["recording"]).is_file() for p in summary["map"])
    # the shipped map needs nothing of the user; the sampling hint is one note naming every mapped resonance
    assert summary["warnings"] == []
    (sampling,) = [n for n in summary["notes"] if n.startswith("sampling: ")]
    assert all(f"{p['frequency_hz']:.4g} Hz" in sampling for p in summary["map"])


def move_config(config: str, tmp_path: Path) -> Path:
    """A shipped gantry config made quick, with the map config's stiff servo (feed-forward), a fine laser
    and its move test. The cart keeps its friction: its stick at the stop rings the mode with a force step no
    set-point shaping removes, and the move, which excites the mode (V about 1.8), rings well above that."""
    transport = {
        "emulated-gantry.toml": "serial",
        "emulated-canopen-gantry.toml": "canopen",
        "emulated-modbus-gantry.toml": "modbus",
    }[config]
    raw = quick(tomllib.loads((CONFIGS / config).read_text()), transport)
    mapped_raw = tomllib.loads(MAP_CONFIG.read_text())
    raw["verification"] = mapped_raw["verification"]
    # the input shapers' moves once, on the board (the shipped map config makes them on every mapped position)
    raw["verification"]["move"]["shapers"] = ["fixed"] if transport == "serial" else []
    raw["verification"]["move"]["repeats"] = 1  # the clean twin: nothing at rest to average away
    raw["emulator"]["drive"].update(velocity_feedforward=1.0, accel_feedforward_nm_per_mps2=5.0)
    raw["emulator"]["sensors"]["laser_resolution_m"] = 2e-6
    driver = find_driver(raw["device"]["driver"])
    raw["run"]["channels"] = [c.name for c in driver.streamed_channels if c.name != "load_position_m"] + [
        "load_position_m"
    ]  # the CANopen and Modbus drives stream their load sensor only when asked
    path = tmp_path / "move.toml"
    path.write_text(tomli_w.dumps(json.loads(json.dumps(raw))))
    return path


@pytest.mark.parametrize(
    "config", ["emulated-gantry.toml", "emulated-canopen-gantry.toml", "emulated-modbus-gantry.toml"]
)
def test_a_move_rings_ten_db_less_with_the_notch_on_every_transport(config, tmp_path):
    path = move_config(config, tmp_path)
    cfg = parse_config(path.read_text(), str(path))
    summary = Session(cfg, tmp_path / "out").run()
    test = summary["move_test"]
    (move,) = test["moves"]
    assert move["notch_in"] == "host" and move["signal"] == "load deflection"
    assert move["rms_reduction_db"] >= 10.0 and move["peak_to_peak_reduction_db"] >= 10.0, move
    assert test["worst_rms_reduction_db"] == move["rms_reduction_db"]
    assert move["added_delay_s"] > 0  # the shaped move ends later, exactly where asked
    assert 0 <= move["standstill_rms_m"] < move["without"]["rms_m"] / 10  # the clean twin at rest barely moves
    assert move["rest_limit_db"] == pytest.approx(20 * np.log10(move["without"]["rms_m"] / move["standstill_rms_m"]))
    (mode,) = move["modes"]  # the run's resonance, where the move ends
    assert mode["frequency_hz"] == pytest.approx(summary["resonances"][0]["frequency_hz"])
    assert mode["excitation"] >= 1.0  # the shipped move excites the mode: nothing to warn about
    assert not [w for w in summary["warnings"] if "excites the mode less" in w]
    # the shaped set-point excites the mode far less, and the ringing falls by no more than that allows
    assert mode["predicted_reduction_db"] >= 20.0
    assert move["rms_reduction_db"] <= mode["predicted_reduction_db"] + 6.0
    assert schema_errors(summary) == []
    assert (tmp_path / "out" / "moves.png").is_file()
    moves = check_report(tmp_path / "out").sections["moves"]
    assert "load deflection" in moves and f"{move['rms_reduction_db']:.3g} dB" in moves
    assert "move_without.h5" in move["recordings"] and (tmp_path / "out" / "move_with.h5").is_file()
    if config == "emulated-gantry.toml":  # without a map: the shaper the run's resonance favours
        (fixed,) = move["shapers"]
        assert fixed["kind"] == summary["input_shaper"]["chosen"]["kind"]
        assert fixed["frequency_hz"] == pytest.approx(summary["resonances"][0]["frequency_hz"])
        assert fixed["rms_reduction_db"] >= 10.0 and fixed["added_delay_s"] > 0, fixed
        assert "fixed shaper" in moves and (tmp_path / "out" / "move_fixed.h5").is_file()
    else:
        assert move["shapers"] == []


def test_the_map_run_moves_at_every_mapped_position_with_the_mapped_mode_where_each_move_ends(mapped):
    """The shipped map config's move test on the clean twin (its friction kept): a move from every mapped
    position, each knowing the mode where it ends from the map, each ringing at least 10 dB less with the notch."""
    cfg, summary, _ = mapped
    assert schema_errors(summary) == []
    moves = summary["move_test"]["moves"]
    assert len(moves) == len(summary["map"])
    assert all(abs(m["start_m"] - p["target_m"]) < 0.005 for m, p in zip(moves, summary["map"], strict=True))
    for m in moves:
        end = m["start_m"] + m["distance_m"]
        assert -0.5 - 1e-3 <= end <= 0.5 + 1e-3  # within the window less the map's margin
        (mode,) = m["modes"]
        truth_hz, _ = true_modes(cfg.emulator, end)[0]
        assert abs(mode["frequency_hz"] - truth_hz) / truth_hz < 0.01, (end, mode, truth_hz)
        assert mode["excitation"] >= 1.0 and mode["predicted_reduction_db"] >= 20.0
        assert m["rms_reduction_db"] >= 10.0, m
    assert summary["move_test"]["worst_rms_reduction_db"] == min(m["rms_reduction_db"] for m in moves)
    assert not [w for w in summary["warnings"] if "excites the mode less" in w]


def test_the_map_run_makes_each_move_with_the_fixed_and_the_scheduled_shaper(mapped):
    """The shipped map config's moves with input shapers, on the clean twin (its friction kept): the scheduled
    shaper follows the twin's mode along the travel, and its moves ring at least 15 dB less than the unshaped
    ones and no more than with the notch at every mapped position."""
    cfg, summary, out = mapped
    travel = summary["input_shaper"]["over_travel"]
    for row in travel["scheduled"]["table"]:
        truth_hz, _ = true_modes(cfg.emulator, row["position_m"])[0]
        assert abs(row["frequency_hz"] - truth_hz) / truth_hz < 0.01, row
    lo, hi = travel["frequency_range_hz"]
    assert hi / lo > 1.12  # the mode moves by about +-8 % ...
    assert travel["fixed"]["worst_residual"] > travel["scheduled"]["worst_residual"]  # ... which costs the fixed one
    rate = cfg.run.sample_rate_hz
    for i, m in enumerate(summary["move_test"]["moves"]):
        fixed, scheduled = m["shapers"]
        assert (fixed["name"], scheduled["name"]) == ("fixed shaper", "scheduled shaper")
        truth_hz, _ = true_modes(cfg.emulator, m["start_m"] + m["distance_m"])[0]
        assert abs(scheduled["frequency_hz"] - truth_hz) / truth_hz < 0.01, (m["start_m"], scheduled)
        assert fixed["frequency_hz"] == pytest.approx(travel["fixed"]["frequency_hz"])
        assert scheduled["rms_reduction_db"] >= 15.0, (m["start_m"], scheduled)
        assert scheduled["rms_reduction_db"] >= m["rms_reduction_db"], (m["start_m"], scheduled, m["rms_reduction_db"])
        # the set-point's prediction: the shaped move barely excites the mode, and the ringing falls no further
        (mode,) = m["modes"]
        predicted = 20 * np.log10(mode["excitation"] / scheduled["excitations"][0])
        assert predicted >= 20.0 and scheduled["rms_reduction_db"] <= predicted + 6.0
        assert 0 < scheduled["added_delay_s"] <= travel["scheduled"]["longest_duration_s"] + 1.0 / rate
        assert (out / f"move_{i}_scheduled.h5").is_file() and (out / f"move_{i}_fixed.h5").is_file()
    page = check_report(out).sections["moves"]
    assert "The same move without shaping, with the notch and with each input shaper" in page
