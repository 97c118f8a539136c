"""`hilident emulate fleet`: layout and truth of a small fleet, determinism, damaged files, and a clean file
identified to the twin's truth by `hilident identify`'s own pipeline."""

from __future__ import annotations

import datetime as dt
import json
import math
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest

from hilident.batch.fleet import (
    BASE_TOML,
    DAMAGE_KINDS,
    FLEET_FORMAT,
    SAMPLE_RATES_HZ,
    axis_ids,
    damaged_count,
    drifting_count,
    toml_text,
    truth_rate_percent_per_day,
    write_fleet,
)
from hilident.cli.main import main
from hilident.config.tables import load_config, parse_config
from hilident.errors import DataError, UsageError
from hilident.io.recording import RunWriter, read_run
from hilident.session.offline import identify_recording

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
AXES, DAYS = 3, 4
ARGS = ["emulate", "fleet", "--axes", str(AXES), "--days", str(DAYS), "--seed", "11", "--damaged", "4", "-q"]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fleet") / "fleet"
    assert main([*ARGS, "--out", str(out)]) == 0
    return out


def truth(folder: Path) -> dict:
    return json.loads((folder / "fleet.json").read_text())


def intact(t: dict) -> list[tuple[dict, int]]:
    """(axis entry, day) of every recording not damaged on purpose."""
    bad = {d["path"] for d in t["damaged"]}
    return [(a, i) for a in t["axes"] for i, f in enumerate(a["files"]) if f not in bad]


def test_layout_and_fleet_json(fleet, capsys):
    t = truth(fleet)
    assert (t["format"], t["version"], t["start"], t["days"], t["seed"]) == (FLEET_FORMAT, 1, "2026-01-01", DAYS, 11)
    assert [a["axis"] for a in t["axes"]] == ["axis-01", "axis-02", "axis-03"]
    assert sorted(p.name for p in fleet.iterdir()) == ["axis-01", "axis-02", "axis-03", "fleet.json"]
    assert [a["sample_rate_hz"] for a in t["axes"]] == list(SAMPLE_RATES_HZ)
    assert len({a["serial"] for a in t["axes"]}) == AXES
    for a in t["axes"]:
        assert set(a) >= {
            "axis",
            "serial",
            "sample_rate_hz",
            "drifting",
            "stiffness_percent_per_day",
            "frequency_percent_per_day",
            "frequencies_hz",
            "files",
        }
        assert len(a["files"]) == len(a["frequencies_hz"]) == DAYS
        for day, rel in enumerate(a["files"]):
            folder, name = rel.split("/")
            assert folder == a["axis"] and (fleet / rel).is_file()
            when = dt.datetime.strptime(name, f"{a['axis']}_%Y%m%dT%H%M%SZ.h5").replace(tzinfo=dt.UTC)
            night = dt.datetime(2026, 1, 1 + day, 2, 0, tzinfo=dt.UTC)
            assert night <= when <= night + dt.timedelta(minutes=10)
    kinds = sorted(d["damage"] for d in t["damaged"])
    assert kinds == sorted(DAMAGE_KINDS)
    assert sum(a["drifting"] for a in t["axes"]) == 1  # round(0.3 * 3) = 1


def test_a_recording_is_a_sessions_identification_recording(fleet):
    t = truth(fleet)
    a, day = intact(t)[-1]
    run = read_run(fleet / a["files"][day], require_complete=True)
    name = Path(a["files"][day]).name
    stamp = dt.datetime.strptime(name, f"{a['axis']}_%Y%m%dT%H%M%SZ.h5").replace(tzinfo=dt.UTC)
    assert run.attrs["created_utc"] == stamp.isoformat(timespec="milliseconds")
    assert run.attrs["created_utc"].endswith("+00:00")
    assert run.attrs["axis"] == a["axis"]
    assert run.attrs["device"] == {
        "name": "myrio-board",
        "firmware": "hilident-board 1.0 (fleet twin)",
        "port": "emulator",
        "serial": a["serial"],
    }
    assert (run.attrs["experiment"], run.attrs["mode"]) == ("identification", "torque")
    assert {"seed", "config_source", "versions"} <= set(run.attrs)
    assert run.channel_names == ["sample_index", "time_s", "excitation", "torque_nm", "position_m", "velocity_mps"]
    assert run.units["excitation"] == "N*m" and run.units["velocity_mps"] == "m/s"
    assert run.sample_rate_hz == a["sample_rate_hz"]
    cfg = parse_config(run.attrs["config_toml"], "stored")
    assert cfg.run.sample_rate_hz == a["sample_rate_hz"]
    assert cfg.emulator.plant.k == pytest.approx(a["stiffness"][day])
    period = run.attrs["period_samples"]
    assert period == round(cfg.excitation.period_s * a["sample_rate_hz"])
    # one lead-in period, then the periods of duration_s, each the same samples
    assert run.n_samples == period * (1 + round(cfg.excitation.duration_s / cfg.excitation.period_s))
    u = run.channel("excitation")
    np.testing.assert_array_equal(u[:period], u[period : 2 * period])
    np.testing.assert_array_equal(run.channel("time_s"), run.channel("sample_index") / run.sample_rate_hz)


def test_the_truth_is_the_plant_and_the_rate_is_the_documented_line(fleet):
    t = truth(fleet)
    bad = {d["path"] for d in t["damaged"]}
    for a in t["axes"]:
        m1, m2 = a["m1"], a["m2"]
        k = np.array(a["stiffness"])
        f = np.sqrt(k * (m1 + m2) / (m1 * m2)) / (2 * math.pi)
        np.testing.assert_allclose(a["frequencies_hz"], f, rtol=1e-9)
        days = np.array(a["days"])
        if a["drifting"]:
            assert -1.5 <= a["stiffness_percent_per_day"] <= -0.3
            np.testing.assert_allclose(k, a["k0"] * (1 + a["stiffness_percent_per_day"] / 100 * days), rtol=1e-12)
        else:
            assert a["stiffness_percent_per_day"] == 0.0
            assert np.all(np.abs(k / a["k0"] - 1) <= 0.001) and np.ptp(k) > 0  # a small wobble, not constant
        keep = [i for i, rel in enumerate(a["files"]) if rel not in bad]
        tt, ff = days[keep], np.array(a["frequencies_hz"])[keep]
        (slope, intercept), *_ = np.linalg.lstsq(np.column_stack([tt, np.ones_like(tt)]), ff, rcond=None)
        expected = 100 * slope / (intercept + slope * tt[0])
        assert a["frequency_percent_per_day"] == pytest.approx(expected, rel=1e-9, abs=1e-12)
        if a["drifting"]:  # the frequency goes as the square root of k: about half the stiffness rate
            assert a["frequency_percent_per_day"] == pytest.approx(a["stiffness_percent_per_day"] / 2, rel=0.05)


def test_the_same_seed_gives_the_same_fleet_and_another_seed_another(fleet, tmp_path):
    again = tmp_path / "again"
    assert main([*ARGS, "--out", str(again)]) == 0
    assert truth(again) == truth(fleet)
    a, day = intact(truth(fleet))[0]
    for rel in a["files"]:  # byte for byte, damaged files included
        assert (fleet / rel).read_bytes() == (again / rel).read_bytes(), rel
    first = read_run(fleet / a["files"][day])
    span = dt.datetime.fromisoformat(first.attrs["closed_utc"]) - dt.datetime.fromisoformat(first.attrs["created_utc"])
    assert span.total_seconds() == pytest.approx(first.n_samples / first.sample_rate_hz, abs=1e-3)
    other = tmp_path / "other"
    assert main([*ARGS[:-4], "12", "--damaged", "0", "-q", "--out", str(other)]) == 0
    assert truth(other)["axes"][0]["serial"] != truth(fleet)["axes"][0]["serial"]
    assert truth(other)["axes"][0]["frequencies_hz"] != truth(fleet)["axes"][0]["frequencies_hz"]


def test_every_damaged_file_fails_to_identify_with_a_typed_error(fleet, tmp_path):
    for damaged in truth(fleet)["damaged"]:
        path = fleet / damaged["path"]
        with pytest.raises(DataError, match=path.name):
            identify_recording(None, path, tmp_path / path.stem)
    running = next(d for d in truth(fleet)["damaged"] if d["damage"] == "running")
    with h5py.File(fleet / running["path"], "r") as f:
        assert f.attrs["status"] == "running" and "n_samples" not in f.attrs
        assert f["samples"].shape[0] < f.attrs["period_samples"]
    assert (fleet / next(d["path"] for d in truth(fleet)["damaged"] if d["damage"] == "empty")).stat().st_size == 0


def test_the_cli_turns_a_damaged_file_into_one_line(fleet, tmp_path, capsys):
    truncated = next(d for d in truth(fleet)["damaged"] if d["damage"] == "truncated")
    assert main(["identify", str(fleet / truncated["path"]), "--out", str(tmp_path / "x"), "-q"]) == 3
    err = capsys.readouterr().err.strip()
    assert err.startswith("hilident: error:") and "\n" not in err and "Traceback" not in err


@pytest.mark.parametrize("rate_hz", [500.0, 2000.0])
def test_a_clean_recording_identifies_to_the_twins_mode(fleet, tmp_path, rate_hz):
    t = truth(fleet)
    a, day = next((a, i) for a, i in intact(t) if a["sample_rate_hz"] == rate_hz)
    summary = identify_recording(None, fleet / a["files"][day], tmp_path / "identify")
    (mode,) = summary["resonances"]
    true_hz = a["frequencies_hz"][day]
    assert abs(mode["frequency_hz"] - true_hz) <= mode["frequency_ci95_hz"], (mode, true_hz)
    assert abs(mode["damping_ratio"] - a["damping_ratios"][day]) <= 3 * mode["damping_ci95"]


def test_counts_ids_and_the_rate_definition():
    assert axis_ids(3) == ["axis-01", "axis-02", "axis-03"]
    assert axis_ids(120)[0] == "axis-001" and axis_ids(120)[-1] == "axis-120"
    assert (drifting_count(20, 0.3), drifting_count(2, 0.1), drifting_count(5, 0.0), drifting_count(1, 0.3)) == (
        6,
        1,
        0,
        0,
    )
    assert (damaged_count(600), damaged_count(20), damaged_count(19)) == (12, 2, 0)
    # a line through the first point: 20 Hz falling 0.2 Hz a day is -1 %/day of its first value
    assert truth_rate_percent_per_day([0.5, 1.5, 2.5], [20.0, 19.8, 19.6]) == pytest.approx(-1.0)
    assert math.isnan(truth_rate_percent_per_day([1.0], [20.0]))


def test_configuration_text_round_trips():
    raw = tomllib.loads((CONFIGS / "emulated-gantry.toml").read_text())
    assert tomllib.loads(toml_text(raw)) == raw
    assert tomllib.loads(toml_text(tomllib.loads(BASE_TOML))) == tomllib.loads(BASE_TOML)


def test_a_base_config_and_bad_arguments(tmp_path, capsys):
    out = tmp_path / "gantry"
    args = ["emulate", "fleet", "--axes", "2", "--days", "2", "--out", str(out), "--duration-s", "4", "-q"]
    assert main([*args, "--config", str(CONFIGS / "emulated-gantry.toml"), "--start", "2026-03-01", "--viscous"]) == 0
    t = truth(out)
    assert t["start"] == "2026-03-01" and t["friction"] == "viscous" and t["damaged"] == []
    assert sum(a["drifting"] for a in t["axes"]) == 1
    stored = parse_config(read_run(out / t["axes"][0]["files"][0]).attrs["config_toml"], "stored")
    gantry = load_config(CONFIGS / "emulated-gantry.toml")
    assert (stored.emulator.friction.Fc, stored.emulator.friction.Fv) == (0.0, gantry.emulator.friction.Fv)
    assert stored.excitation.duration_s == 4.0 and not stored.friction_test.enabled
    assert "wrote 4 recordings of 2 axes (1 drifting, 0 damaged on purpose)" in capsys.readouterr().out
    for bad in (
        ["--axes", "0"],
        ["--start", "2026-13-01"],
        ["--drifting-share", "1.5"],
        ["--config", str(CONFIGS / "emulated-msd.toml")],
        ["--damaged", "9"],
        ["--seed", "-1"],
        ["--duration-s", "nan"],
    ):
        assert main([*args, *bad]) == 2, bad
        err = capsys.readouterr().err.strip()
        assert err.startswith("hilident: error:") and "\n" not in err, err


def test_the_writer_stores_a_given_creation_time(tmp_path):
    when = dt.datetime(2026, 1, 2, 3, 4, 5, 678000, tzinfo=dt.timezone(dt.timedelta(hours=1)))
    w = RunWriter(tmp_path / "r.h5", ["x"], ["m"], 10.0, created_utc=when)
    w.append(np.zeros((3, 1)))
    w.close(closed_utc=when + dt.timedelta(seconds=0.3))
    attrs = read_run(tmp_path / "r.h5").attrs
    assert (attrs["created_utc"], attrs["closed_utc"]) == (
        "2026-01-02T02:04:05.678+00:00",
        "2026-01-02T02:04:05.978+00:00",
    )
    with pytest.raises(DataError, match="timezone-aware"):
        RunWriter(tmp_path / "naive.h5", ["x"], ["m"], 10.0, created_utc=dt.datetime(2026, 1, 1))


def test_write_fleet_refuses_a_fleet_whose_stiffness_would_vanish(tmp_path):
    from hilident.errors import UsageError

    with pytest.raises(UsageError, match="fall to zero"):
        write_fleet(tmp_path / "f", 2, 400, seed=1, drifting_share=1.0, duration_s=4.0)


def test_an_occupied_folder_is_refused_and_overwrite_replaces_only_the_earlier_fleet(tmp_path, capsys):
    out = tmp_path / "f"
    args = ["emulate", "fleet", "--axes", "2", "--days", "3", "--out", str(out), "--duration-s", "4", "-q"]
    assert main(args) == 0
    mine = out / "notes.txt"
    mine.write_text("kept")
    assert main([*args[:5], "2", *args[6:]]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main([*args[:5], "2", *args[6:], "--overwrite"]) == 0
    assert sorted(p.name for p in (out / "axis-01").iterdir()) == sorted(
        Path(f).name for f in truth(out)["axes"][0]["files"]
    )
    assert len(truth(out)["axes"][0]["files"]) == 2 and mine.read_text() == "kept"
    assert main([*args[:7], str(mine), *args[8:]]) == 2


def test_sample_rates_given_are_taken_in_turn_and_a_rate_without_whole_periods_is_refused(tmp_path):
    write_fleet(tmp_path / "f", 3, 1, duration_s=4.0, damaged=0, sample_rates_hz=(1000.0, 250.0))
    t = json.loads((tmp_path / "f" / "fleet.json").read_text())
    assert [a["sample_rate_hz"] for a in t["axes"]] == [1000.0, 250.0, 1000.0]
    with pytest.raises(UsageError, match="--sample-rate-hz 333.3"):
        write_fleet(tmp_path / "g", 1, 1, duration_s=4.0, sample_rates_hz=(333.3,))
