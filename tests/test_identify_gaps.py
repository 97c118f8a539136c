"""`hilident identify` never splices: gaps are found and only gap-free data is analysed."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilident.cli.main import main
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import build_drive, true_modes
from hilident.errors import DataError
from hilident.io.recording import RunWriter
from hilident.pipeline.selection import excitation_period_samples, select_gap_free
from hilident.signals import multisine
from test_identify_offline import GANTRY  # the same frictionless gantry

RATE = 1000.0
PERIOD_S = 4.0
PERIOD = int(PERIOD_S * RATE)
#: the configuration a bench run stores in its recording: a multisine of 4 s periods at 1 kHz
RUN_CONFIG = f"""
[run]
sample_rate_hz = {RATE}
[excitation]
kind = "multisine"
amplitude_nm = 4.0
f_min_hz = 2.0
f_max_hz = 80.0
period_s = {PERIOD_S}
duration_s = 16.0
"""
CHANNELS = ["sample_index", "time_s", "excitation", "torque_nm", "velocity_mps", "position_m"]
UNITS = ["1", "s", "N*m", "N*m", "m/s", "m"]


@pytest.fixture(scope="module")
def bench_run():
    """An identification run as the session records it: one lead-in period, then four periods."""
    cfg = parse_config(GANTRY)
    drive = build_drive(cfg.emulator, find_driver("myrio-board"))
    drive.set_limits(100.0, 10.0, -10.0, 10.0)
    drive.set_mode("torque")
    drive.enable()
    ms = multisine(4.0, 2.0, 80.0, PERIOD_S, 5, RATE)
    rows = drive.run(np.repeat(ms.samples, 4))[::4]
    col = {name: rows[:, i] for i, name in enumerate(drive.CHANNELS)}
    n = len(rows)
    table = np.column_stack(
        [np.arange(n), np.arange(n) / RATE, ms.samples, col["torque_nm"], col["velocity_mps"], col["position_m"]]
    )
    ((true_f, _),) = true_modes(cfg.emulator)
    return table, true_f


def write_run(path, table, status="complete", flushed=None):
    with RunWriter(path, CHANNELS, UNITS, RATE, {"experiment": "identification", "config_toml": RUN_CONFIG}) as w:
        w.append(table)
    with h5py.File(path, "a") as f:
        if status != "complete":
            f.attrs["status"] = status
        if flushed is not None:
            f.attrs["flushed_samples"] = np.int64(flushed)


def identify(
    tmp_path, data, mapping='torque = "torque_nm"\nvelocity = "velocity_mps"\nexcitation = "excitation"\n', name="o"
):
    config = tmp_path / "identify.toml"
    config.write_text("[data]\n" + mapping + "\n[identification]\nmax_resonances = 1\nmodel_max_order = 0\n")
    out = tmp_path / name
    assert main(["identify", str(data), "--config", str(config), "--out", str(out), "-q"]) == 0
    return json.loads((out / "summary.json").read_text())


def test_lost_blocks_cost_only_their_periods(tmp_path, bench_run):
    table, true_f = bench_run
    # two blocks lost, both inside period 2; one block lost in the lead-in
    lost = np.r_[300:420, 2 * PERIOD + 1000 : 2 * PERIOD + 1137, 2 * PERIOD + 3000 : 2 * PERIOD + 3050]
    write_run(tmp_path / "identification.h5", np.delete(table, lost, axis=0))
    summary = identify(tmp_path, tmp_path / "identification.h5")
    data = summary["data"]
    assert data["rows"] == len(table) - len(lost)
    assert data["used_rows"] == 3 * PERIOD  # periods 1, 3 and 4: whole and gap-free
    assert data["period_samples"] == PERIOD and data["n_gaps"] == 3
    assert [g["missing_samples"] for g in data["gaps"]] == [120, 137, 50]
    assert data["gaps"][1]["sample_index"] == 2 * PERIOD + 1137
    assert data["status"] == "complete" and summary["stream"]["lost_samples"] == len(lost)
    assert any("1 of 4 excitation periods had lost samples" in w for w in summary["warnings"])
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.005


def test_a_crashed_recording_is_used_up_to_its_last_flush_and_flagged(tmp_path, bench_run):
    table, true_f = bench_run
    flushed = 3 * PERIOD + 1500  # lead-in, two whole periods, and half of the third
    garbage = table.copy()
    garbage[flushed:, 3:] = 0.0  # rows past the last flush are not data
    write_run(tmp_path / "identification.h5", garbage, status="running", flushed=flushed)
    summary = identify(tmp_path, tmp_path / "identification.h5")
    data = summary["data"]
    assert data["status"] == "running" and data["flushed_samples"] == flushed
    assert data["rows"] == flushed and data["used_rows"] == 2 * PERIOD
    assert any("did not complete" in w and "may end early" in w for w in summary["warnings"])
    assert any("not counted as recorded" in w for w in summary["warnings"])
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.005


def test_an_aborted_recording_names_its_reason(tmp_path, bench_run):
    table, _ = bench_run
    path = tmp_path / "identification.h5"
    write_run(path, table)
    with h5py.File(path, "a") as f:
        f.attrs["status"] = "aborted"
        f.attrs["reason"] = "limit trip: torque"
    summary = identify(tmp_path, path)
    assert summary["data"]["status"] == "aborted"
    assert any("aborted: limit trip: torque" in w for w in summary["warnings"])


def test_a_time_column_with_gaps_uses_the_longest_stretch(tmp_path, bench_run):
    table, true_f = bench_run
    keep = np.ones(len(table), bool)
    keep[6000:6003] = False  # a gap of three samples
    keep[9000:9001] = False
    t, tau, v = table[keep, 1], table[keep, 3], table[keep, 4]
    path = tmp_path / "gappy.csv"
    np.savetxt(path, np.column_stack([t, tau, v]), delimiter=",", header="t,tau,v", comments="", fmt="%.9g")
    summary = identify(tmp_path, path, 'time = "t"\ntorque = "tau"\nvelocity = "v"\n')
    data = summary["data"]
    assert data["n_gaps"] == 2 and data["missing_samples"] == 4
    assert data["used_rows"] == len(table) - 9001 and data["segments"] == 1
    assert summary["data"]["sample_rate_hz"] == pytest.approx(RATE)
    assert any("longest contiguous stretch" in w for w in summary["warnings"])
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.01


def test_irregular_time_stamps_stay_an_error(tmp_path, bench_run, capsys):
    table, _ = bench_run
    t = table[:, 1].copy()
    t[5000:] += 0.0015  # one step of 2.5 sample periods: not a gap, a clock fault
    path = tmp_path / "irregular.csv"
    np.savetxt(path, np.column_stack([t, table[:, 3], table[:, 4]]), delimiter=",", header="t,tau,v", comments="")
    config = tmp_path / "c.toml"
    config.write_text('[data]\ntime = "t"\ntorque = "tau"\nvelocity = "v"\n')
    assert main(["identify", str(path), "--config", str(config), "--out", str(tmp_path / "o"), "-q"]) == 3
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "not uniform" in line and "row 5000" in line


def test_velocity_from_position_is_never_differentiated_across_a_gap(tmp_path, bench_run):
    table, _ = bench_run
    cut = np.delete(table, np.r_[2 * PERIOD + 100 : 2 * PERIOD + 400], axis=0)
    write_run(tmp_path / "identification.h5", cut)
    summary = identify(
        tmp_path,
        tmp_path / "identification.h5",
        'torque = "torque_nm"\nposition = "position_m"\nexcitation = "excitation"\n',
    )
    assert summary["data"]["used_rows"] == 3 * PERIOD and summary["data"]["segments"] == 2
    from hilident.config.tables import DataConfig
    from hilident.datafile import load_dataset

    ds = load_dataset(tmp_path / "identification.h5", DataConfig(torque="torque_nm", position="position_m"))
    true_v = np.concatenate([table[PERIOD : 2 * PERIOD, 4], table[3 * PERIOD : 5 * PERIOD, 4]])
    # the derivative of the encoder position follows the true velocity everywhere, joins included
    assert np.max(np.abs(ds.signals["velocity"] - true_v)) < 0.05 * np.max(np.abs(true_v))


# ------------------------------------------------------------------ the pure selection


def test_select_gap_free_keeps_whole_periods_after_the_lead_in():
    index = np.delete(np.arange(50), [13, 14, 41])  # lost in period 1 and period 4 (period 10)
    sel = select_gap_free(index, 10, "r")
    kept = index[sel.keep]
    assert list(kept) == list(range(20, 40))
    assert sel.n_gaps == 2 and sel.missing_samples == 3 and sel.segments == [(18, 38)]
    assert sel.warnings == ["r: 2 of 4 excitation periods had lost samples and were left out"]


def test_select_gap_free_never_counts_a_repeated_period_twice():
    index = np.concatenate([np.arange(0, 40), np.arange(20, 30), np.arange(40, 50)])  # period 2 replayed
    sel = select_gap_free(index, 10)
    assert sorted(index[sel.keep]) == list(range(10, 50))
    assert sel.gaps[0] == {"row": 40, "sample_index": 20, "missing_samples": -20}


def test_select_gap_free_needs_two_whole_periods():
    with pytest.raises(DataError, match="only 1 complete excitation period"):
        select_gap_free(np.delete(np.arange(30), [25]), 10, "r")


def test_select_gap_free_without_period_keeps_the_longest_stretch():
    index = np.r_[0:10, 12:40, 41:45]
    sel = select_gap_free(index)
    assert list(index[sel.keep]) == list(range(12, 40)) and sel.period_samples is None
    assert "2 gap(s)" in sel.warnings[0]
    with pytest.raises(DataError, match="no samples"):
        select_gap_free(np.array([], dtype=np.int64))


def test_period_of_the_configured_excitation():
    cfg = parse_config(RUN_CONFIG)
    assert excitation_period_samples(cfg.excitation, RATE) == PERIOD
    prbs = parse_config('[excitation]\nkind = "prbs"\nregister_length = 7\nclock_divider = 2\nduration_s = 1.0\n')
    assert excitation_period_samples(prbs.excitation, RATE) == 254  # 1 s holds 4 sequences of 254
    short = parse_config('[excitation]\nkind = "prbs"\nregister_length = 9\nclock_divider = 1\nduration_s = 1.0\n')
    assert excitation_period_samples(short.excitation, RATE) is None  # 2 sequences: not averaged
    chirp = parse_config('[excitation]\nkind = "chirp"\n')
    assert excitation_period_samples(chirp.excitation, RATE) is None


def test_select_gap_free_segments_break_where_the_clock_jumps():
    index = np.r_[0:30, 40:60]  # periods 1, 2 from the first run and 4, 5 from the second sit on adjacent rows
    sel = select_gap_free(index, 10)
    assert sel.segments == [(10, 30), (30, 50)]
    assert sel.warnings == ["recording: 1 of 5 excitation periods had lost samples and were left out"]


@pytest.mark.parametrize(
    "excitation",
    [
        'kind = "multisine"\nperiod_s = 0.5\nduration_s = 2.0\nf_min_hz = 4.0\nf_max_hz = 80.0',
        'kind = "multisine"\nperiod_s = 0.2503\nduration_s = 1.0\nf_min_hz = 8.0\nf_max_hz = 80.0',
        'kind = "prbs"\nregister_length = 6\nclock_divider = 3\nduration_s = 0.6',
        'kind = "prbs"\nregister_length = 8\nclock_divider = 1\nduration_s = 0.6',
        'kind = "chirp"\nduration_s = 1.0',
        'kind = "noise"\nduration_s = 1.0',
    ],
)
def test_the_period_identify_assumes_is_the_one_a_bench_run_plays(excitation):
    from hilident.session.excitation import build_excitation

    cfg = parse_config(f"[run]\nsample_rate_hz = {RATE}\n[excitation]\n{excitation}\n")
    assert excitation_period_samples(cfg.excitation, RATE) == build_excitation(cfg).period_samples


def test_time_stamps_are_checked_chunk_by_chunk_with_the_right_rows(tmp_path, monkeypatch):
    from hilident.datafile import mapping as datafile

    monkeypatch.setattr(datafile, "_TIME_CHUNK", 7)  # many chunks, gaps and faults on their borders
    n = 200
    sample = np.delete(np.arange(n + 5), [7, 8, 13, 150])  # gaps before rows 7 and 11, and one at row 146
    t = sample / RATE
    raw = datafile.RawColumns({"t": t}, ["t"])
    index, rate = datafile._time_index(tmp_path / "x.csv", "t", raw, len(t))
    assert np.array_equal(index, sample) and rate == pytest.approx(RATE)
    index, _ = datafile._time_index(tmp_path / "x.csv", "t", datafile.RawColumns({"t": T_UNIFORM}, ["t"]), 50)
    assert index is None  # no gap: no index built
    bad = t.copy()
    bad[141:] += 0.0003
    with pytest.raises(DataError, match="at row 141"):
        datafile._time_index(tmp_path / "x.csv", "t", datafile.RawColumns({"t": bad}, ["t"]), len(t))
    bad = t.copy()
    bad[70] = bad[69]
    with pytest.raises(DataError, match="does not increase at row 70"):
        datafile._time_index(tmp_path / "x.csv", "t", datafile.RawColumns({"t": bad}, ["t"]), len(t))


T_UNIFORM = np.arange(50) / RATE


def test_a_grey_box_fit_never_runs_across_a_lost_block(tmp_path, bench_run):
    table, _ = bench_run
    write_run(tmp_path / "identification.h5", np.delete(table, np.r_[2 * PERIOD + 10 : 2 * PERIOD + 20], axis=0))
    summary = identify(
        tmp_path,
        tmp_path / "identification.h5",
        'torque = "torque_nm"\nvelocity = "velocity_mps"\nposition = "position_m"\n'
        '[model]\nkind = "rigid_axis"\nc = 10.0\ncutoff_hz = 8.0\n',
    )
    assert summary["data"]["segments"] == 2 and summary["data"]["used_rows"] == 3 * PERIOD
    model = summary["model"]
    # periods 3 and 4 are the longest stretch (the fit trims its filters' start-up from both parts)
    fitted = model["estimation"]["samples"] + model["validation"]["holdout"]["samples"]
    assert 0.7 * 2 * PERIOD < fitted <= 2 * PERIOD
    assert any("longest gap-free stretch (8000 samples)" in w for w in summary["warnings"])


def test_the_period_comes_from_an_attribute_or_the_stored_configuration(tmp_path, bench_run):
    from hilident.config.tables import DataConfig
    from hilident.datafile import load_dataset

    table, _ = bench_run
    cut = np.delete(table, np.r_[2 * PERIOD + 10 : 2 * PERIOD + 20], axis=0)
    mapping = DataConfig(torque="torque_nm", velocity="velocity_mps")
    path = tmp_path / "identification.h5"
    write_run(path, cut)
    assert load_dataset(path, mapping).period_samples == PERIOD
    with h5py.File(path, "a") as f:
        f.attrs["config_toml"] = ""
    ds = load_dataset(path, mapping)  # no way to tell the period: the longest stretch, and a note why
    assert ds.period_samples is None and len(ds) == len(table) - 2 * PERIOD - 20
    assert any("excitation period is unknown" in n for n in ds.notes)
    with h5py.File(path, "a") as f:
        f.attrs["period_samples"] = np.int64(PERIOD)
    assert load_dataset(path, mapping).period_samples == PERIOD


@settings(max_examples=200, deadline=None)
@given(
    period=st.integers(2, 12),
    n=st.integers(0, 150),
    edits=st.lists(
        st.tuples(st.sampled_from(["drop", "repeat", "swap"]), st.integers(0, 149), st.integers(1, 9)), max_size=5
    ),
)
def test_select_gap_free_keeps_only_whole_gap_free_periods_once(period, n, edits):
    index = list(range(n))
    for kind, at, length in edits:
        at = min(at, len(index))
        if kind == "drop":
            del index[at : at + length]
        elif kind == "repeat":
            index[at:at] = index[at : at + length]
        elif index[at : at + 2]:
            index[at : at + 2] = index[at : at + 2][::-1]
    index = np.array(index, dtype=np.int64)
    try:
        sel = select_gap_free(index, period)
    except DataError:
        return
    kept = index[sel.keep]
    assert len(kept) == len(set(kept.tolist())) and len(kept) % period == 0 and len(kept) >= 2 * period
    assert kept.min() >= period  # never the lead-in
    for a, b in sel.segments:
        assert np.all(np.diff(index[a:b]) == 1) and index[a] % period == 0 and (b - a) % period == 0
    longest = select_gap_free(index) if len(index) else None
    assert longest is None or np.all(np.diff(index[longest.keep]) == 1)


def test_a_stored_configuration_that_does_not_match_the_played_excitation_is_not_trusted(tmp_path, bench_run):
    from hilident.config.tables import DataConfig
    from hilident.datafile import load_dataset

    table, _ = bench_run
    path = tmp_path / "identification.h5"
    with RunWriter(
        path,
        CHANNELS,
        UNITS,
        RATE,
        {"experiment": "identification", "config_toml": RUN_CONFIG.replace("period_s = 4.0", "period_s = 3.0")},
    ) as w:
        w.append(np.delete(table, np.r_[2 * PERIOD + 10 : 2 * PERIOD + 20], axis=0))
    ds = load_dataset(path, DataConfig(torque="torque_nm", velocity="velocity_mps"))
    assert ds.period_samples is None and len(ds) == 3 * PERIOD - 20  # the longest stretch, not 3 s "periods"
    assert any("does not repeat every 3000 samples" in n for n in ds.notes)


def test_too_few_whole_periods_fall_back_to_the_longest_stretch(tmp_path, bench_run):
    from hilident.config.tables import DataConfig
    from hilident.datafile import load_dataset

    table, _ = bench_run
    # a lost block in each of periods 1, 2 and 3: only period 4 is whole
    lost = np.concatenate([np.arange(p * PERIOD + 500, p * PERIOD + 510) for p in (1, 2, 3)])
    write_run(tmp_path / "identification.h5", np.delete(table, lost, axis=0))
    ds = load_dataset(tmp_path / "identification.h5", DataConfig(torque="torque_nm", velocity="velocity_mps"))
    assert ds.period_samples is None and len(ds) == 2 * PERIOD - 510  # from period 3's gap to the end
    assert any("fewer than two whole gap-free excitation periods of 4000 samples" in n for n in ds.notes)


def test_identify_on_a_bench_recording_finds_what_the_run_found(tmp_path):
    from pathlib import Path

    from hilident.session.run import Session

    text = (Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml").read_text()
    text = text.replace('link = "pty"', 'link = "pipe"').replace("time_scale = 4.0", "time_scale = 8.0")
    text = text.replace("[friction_test]", "[friction_test]\nenabled = false").replace(
        "duration_s = 16.0", "duration_s = 8.0"
    )
    text = text.replace('amplitude_nm = "auto"', "amplitude_nm = 8.0")
    run = Session(parse_config(text, "gantry"), tmp_path / "run").run()
    summary = identify(tmp_path, tmp_path / "run" / "identification.h5")
    assert summary["data"]["period_samples"] == PERIOD and summary["data"]["used_rows"] == 2 * PERIOD
    assert summary["data"]["status"] == "complete" and summary["data"]["n_gaps"] == 0
    # the same rows through the same pipeline: the same resonance, to the last digit
    assert summary["resonances"][0]["frequency_hz"] == run["resonances"][0]["frequency_hz"]
