"""`hilident batch`: inputs, identity, rows, the table, incremental re-runs, failures and Ctrl-C (in one process).

The Dask paths (a local cluster, a scheduler by address) are in test_batch_dask.py.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import shutil
import subprocess
import sys
from functools import cache
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest

from hilident.batch import runner, table
from hilident.batch.identity import name_time, recording_identity
from hilident.batch.inputs import content_sha256, expand_inputs
from hilident.batch.task import identify_row, identify_task, summary_figures
from hilident.cli.main import main
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import build_drive, true_modes
from hilident.errors import UsageError
from hilident.io.recording import RunWriter
from hilident.signals import multisine
from test_identify_offline import GANTRY, write_csv

RATE = 1000.0
CHANNELS = ["sample_index", "time_s", "excitation", "torque_nm", "velocity_mps", "position_m"]
UNITS = ["1", "s", "N*m", "N*m", "m/s", "m"]
#: the configuration a bench run stores in its recording: three 2 s multisine periods at 1 kHz, one resonance
RUN_CONFIG = f"""
[run]
sample_rate_hz = {RATE}
[excitation]
kind = "multisine"
amplitude_nm = 4.0
f_min_hz = 2.0
f_max_hz = 80.0
period_s = 2.0
duration_s = 4.0
[identification]
max_resonances = 1
model_max_order = 0
"""
#: every key the drift statistics rely on (the row contract)
CONTRACT = [
    "path",
    "content_sha256",
    "status",
    "error",
    "error_type",
    "axis",
    "device_name",
    "device_serial",
    "time_utc",
    "time_source",
    "sample_rate_hz",
    "duration_s",
    "frequency_hz",
    "frequency_ci95_hz",
    "damping_ratio",
    "damping_ci95",
    "resonances_json",
    "friction_fc_nm",
    "friction_fs_nm",
    "friction_fv_nm_per_mps",
    "friction_vs_mps",
    "model_fit_percent",
    "warnings",
    "n_warnings",
    "hilident_version",
    "config_sha256",
    "elapsed_s",
]


@cache
def simulated(k: float) -> tuple[np.ndarray, float]:
    """Three periods of a multisine through the frictionless gantry twin of stiffness ``k``; its table and mode."""
    cfg = parse_config(GANTRY.replace("k = 1.5e5", f"k = {k!r}"))
    drive = build_drive(cfg.emulator, find_driver("myrio-board"))
    drive.set_limits(100.0, 10.0, -10.0, 10.0)
    drive.set_mode("torque")
    drive.enable()
    ms = multisine(4.0, 2.0, 80.0, 2.0, 3, RATE)
    rows = drive.run(np.repeat(ms.samples, 4))[::4]
    col = {name: rows[:, i] for i, name in enumerate(drive.CHANNELS)}
    n = len(rows)
    data = np.column_stack(
        [np.arange(n), np.arange(n) / RATE, ms.samples, col["torque_nm"], col["velocity_mps"], col["position_m"]]
    )
    ((true_f, _),) = true_modes(cfg.emulator)
    return data, true_f


def write_recording(
    path: Path,
    k: float = 1.5e5,
    axis: str | None = None,
    device: dict | None = None,
    created: str | None = "2026-11-01T00:00:00.000+00:00",
) -> float:
    """A hilident identification recording of the twin of stiffness ``k`` at ``path``; the true mode, Hz."""
    data, true_f = simulated(k)
    attrs: dict = {"experiment": "identification", "mode": "torque", "config_toml": RUN_CONFIG}
    if axis is not None:
        attrs["axis"] = axis
    if device is not None:
        attrs["device"] = device  # stored as device_json
    with RunWriter(path, CHANNELS, UNITS, RATE, attrs, overwrite=True) as w:
        w.append(data)
    with h5py.File(path, "a") as f:
        if created is None:
            del f.attrs["created_utc"]
        else:
            f.attrs["created_utc"] = created
    return true_f


def batch(*args: str) -> int:
    return main(["batch", *args, "-q"])


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Two good recordings of two axes, a truncated one, an empty one and a text file named .h5."""
    root = tmp_path_factory.mktemp("fleet")
    (root / "ax1").mkdir()
    (root / "ax2").mkdir()
    truth = {
        "ax1/ax1_20261101T000000Z.h5": write_recording(
            root / "ax1" / "ax1_20261101T000000Z.h5",
            1.5e5,
            axis="ax1",
            device={"name": "twin", "serial": "SN1", "port": "emulator", "firmware": "1"},
        ),
        "ax2/b.h5": write_recording(root / "ax2" / "b.h5", 1.2e5, created="2026-11-02T06:00:00+00:00"),
    }
    whole = (root / "ax1" / "ax1_20261101T000000Z.h5").read_bytes()
    (root / "ax2" / "truncated_20261103T000000Z.h5").write_bytes(whole[: len(whole) // 3])
    (root / "ax2" / "empty.h5").write_bytes(b"")
    (root / "ax2" / "notes.h5").write_text("not hdf5\n")
    return root, truth


# --- inputs -------------------------------------------------------------------------------------------------------


def test_inputs_are_files_folders_and_globs_sorted_and_each_once(tmp_path):
    for name in ("a/x.h5", "a/deep/y.hdf5", "a/deep/z.csv", "a/w.mat", "a/readme.txt", "b/v.h5", "c.dat"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("")
    got = expand_inputs(
        [
            str(tmp_path / "a"),
            str(tmp_path / "b" / "*.h5"),
            str(tmp_path / "a" / "x.h5"),
            str(tmp_path / "c.dat"),
            str(tmp_path / "**" / "*.csv"),
        ]
    )
    expect = ["a/deep/y.hdf5", "a/deep/z.csv", "a/w.mat", "a/x.h5", "b/v.h5", "c.dat"]
    assert got == sorted((tmp_path / n).resolve() for n in expect)
    assert len(set(got)) == len(got)


@pytest.mark.parametrize(
    "given, says",
    [
        ("missing.h5", "no file, folder or glob"),
        ("nothing*.h5", "no file, folder or glob"),
        ("empty", "a folder holding no recording"),
    ],
)
def test_an_input_naming_no_recording_is_a_usage_error_naming_it(tmp_path, given, says, capsys):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("")
    with pytest.raises(UsageError, match=says) as err:
        expand_inputs([str(tmp_path / given)])
    assert str(tmp_path / given) in str(err.value)
    assert batch(str(tmp_path / given), "--out", str(tmp_path / "out"), "--scheduler", "synchronous") == 2
    stderr = capsys.readouterr().err
    assert given in stderr and "Traceback" not in stderr
    assert not (tmp_path / "out").exists()


# --- identity -----------------------------------------------------------------------------------------------------


def test_name_stamps_are_read_in_their_iso_like_forms():
    assert name_time("ax_20261124T010203Z.h5") == "2026-11-24T01:02:03.000+00:00"
    assert name_time("run-2026-11-24_01-02-03.csv") == "2026-11-24T01:02:03.000+00:00"
    assert name_time("run 2026-11-24T01:02:03.mat") == "2026-11-24T01:02:03.000+00:00"
    assert name_time("run_20261324T010203Z.h5") == ""  # month 13: no date
    assert name_time("axis7.h5") == ""


def test_identity_comes_from_the_file_then_its_name_then_its_folder(tmp_path):
    (tmp_path / "belt").mkdir()
    tagged = tmp_path / "belt" / "r_20200101T000000Z.h5"
    write_recording(tagged, axis="X7", device={"name": "servo", "serial": "SN9"}, created="2026-11-24T02:00:00+01:00")
    assert recording_identity(tagged) == {
        "axis": "X7",
        "device_name": "servo",
        "device_serial": "SN9",
        "time_utc": "2026-11-24T01:00:00.000+00:00",
        "time_source": "file",
    }
    by_serial = tmp_path / "belt" / "s_20200101T000000Z.h5"
    write_recording(by_serial, device={"name": "servo", "serial": "SN9"}, created=None)
    ident = recording_identity(by_serial)
    assert (ident["axis"], ident["time_utc"], ident["time_source"]) == ("SN9", "2020-01-01T00:00:00.000+00:00", "name")
    # a device model alone is no axis (two axes may run the same drive); with the port it is connected on it is
    by_port = tmp_path / "belt" / "p.h5"
    write_recording(by_port, device={"name": "servo", "port": "/dev/ttyUSB1"}, created=None)
    assert recording_identity(by_port)["axis"] == "servo@/dev/ttyUSB1"
    write_recording(by_port, device={"name": "servo"}, created=None)
    assert recording_identity(by_port)["axis"] == "belt"
    plain = tmp_path / "belt" / "plain.csv"
    plain.write_text("t,tau\n")
    os.utime(plain, (0, 86400.0))
    assert recording_identity(plain) == {
        "axis": "belt",
        "device_name": "",
        "device_serial": "",
        "time_utc": "1970-01-02T00:00:00.000+00:00",
        "time_source": "mtime",
    }


# --- rows ---------------------------------------------------------------------------------------------------------


def test_the_row_takes_the_lowest_resonance_and_nan_where_nothing_is_known():
    summary = {
        "data": {"sample_rate_hz": 500.0, "rows": 1500, "samples": 1000},
        "resonances": [
            {"frequency_hz": 80.0, "damping_ratio": 0.05, "frequency_ci95_hz": 0.2, "damping_ci95": 0.01},
            {"frequency_hz": 20.0, "damping_ratio": 0.02, "frequency_ci95_hz": 0.1, "damping_ci95": None},
        ],
        "friction": {"model": "stribeck", "params": {"Fc": 1.0, "Fs": 1.5, "Fv": 3.0, "vs": 0.01}},
        "model": {"estimation": {"fit_percent": 91.5}},
        "warnings": ["a", "b"],
    }
    row = summary_figures(summary)
    assert row["duration_s"] == 3.0 and row["n_resonances"] == 2
    assert (row["frequency_hz"], row["damping_ratio"], row["frequency_ci95_hz"]) == (20.0, 0.02, 0.1)
    assert math.isnan(row["damping_ci95"])
    assert [r["frequency_hz"] for r in json.loads(row["resonances_json"])] == [20.0, 80.0]
    assert (row["friction_fc_nm"], row["friction_vs_mps"], row["model_fit_percent"]) == (1.0, 0.01, 91.5)
    assert json.loads(row["warnings"]) == ["a", "b"] and row["n_warnings"] == 2
    empty = summary_figures({"data": {}, "resonances": [], "friction": None, "model": None, "warnings": []})
    assert all(math.isnan(empty[k]) for k in ("frequency_hz", "friction_fc_nm", "model_fit_percent", "duration_s"))


def test_an_unexpected_exception_becomes_a_failure_row_with_its_type(tmp_path, monkeypatch):
    import hilident.session.offline

    def broken(*args, **kwargs):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(hilident.session.offline, "analyse_recording", broken)
    path = tmp_path / "ax" / "r.h5"
    path.parent.mkdir()
    write_recording(path, axis="A1")
    row = identify_row(str(path), "h", None, "", "c")
    assert (row["status"], row["error_type"]) == ("failed", "ZeroDivisionError")
    assert row["error"] == "ZeroDivisionError: float division by zero"
    assert row["axis"] == "A1" and row["time_source"] == "file" and row["elapsed_s"] >= 0


# --- a batch in one process ---------------------------------------------------------------------------------------


def test_a_batch_identifies_every_recording_and_damaged_files_become_failure_rows(tmp_path, fleet, capsys):
    root, truth = fleet
    out = tmp_path / "out"
    assert batch(str(root), "--out", str(out), "--scheduler", "synchronous") == 0
    stdout = capsys.readouterr().out
    assert "batch: 5 recordings: 2 identified, 3 failed, 0 skipped" in stdout
    assert f"wrote {out / 'batch.parquet'} and {out / 'batch.csv'}" in stdout
    rows = pd.read_parquet(out / "batch.parquet")
    from_csv = pd.read_csv(out / "batch.csv")
    assert list(rows.columns) == list(table.COLUMNS) and set(CONTRACT) <= set(rows.columns)
    assert list(from_csv.columns) == list(rows.columns) and len(from_csv) == len(rows) == 5
    assert rows["path"].tolist() == sorted(rows["path"])
    by_name = {
        Path(p).relative_to(root).as_posix(): r for p, r in zip(rows["path"], rows.to_dict("records"), strict=True)
    }
    for name, true_f in truth.items():
        r = by_name[name]
        assert r["status"] == "ok" and r["error"] == "" and r["error_type"] == ""
        assert abs(r["frequency_hz"] - true_f) / true_f < 0.01 and 0 < r["frequency_ci95_hz"] < 1
        assert r["sample_rate_hz"] == RATE and r["duration_s"] == pytest.approx(6.0, abs=0.01)
        assert r["content_sha256"] == content_sha256(root / name) and r["time_source"] == "file"
    one, two = by_name["ax1/ax1_20261101T000000Z.h5"], by_name["ax2/b.h5"]
    assert (one["axis"], one["device_name"], one["device_serial"]) == ("ax1", "twin", "SN1")
    assert (two["axis"], two["time_utc"]) == ("ax2", "2026-11-02T06:00:00.000+00:00")
    for name in ("ax2/truncated_20261103T000000Z.h5", "ax2/empty.h5", "ax2/notes.h5"):
        r = by_name[name]
        # identify's own verdict: a damaged hilident file is a DataError; a file that is no HDF5 at all is
        # not a hilident recording, so without --config it is a UsageError
        assert r["status"] == "failed" and r["error_type"] in ("DataError", "UsageError")
        assert name.split("/")[1] in r["error"]
        assert r["axis"] == "ax2" and math.isnan(r["frequency_hz"])
        error = r["error"]  # one line per failure, naming the file once
        assert (
            f"failed: {error}" if error.startswith(str(root / name)) else f"failed: {root / name}: {error}"
        ) in stdout.splitlines()
    truncated = by_name["ax2/truncated_20261103T000000Z.h5"]
    assert truncated["error_type"] == "DataError" and truncated["time_source"] == "name"
    # each analysis's summary.json is kept beside the table, by its keys; none for data never read
    for r in (one, two):
        kept = json.loads(runner.summary_path(out, r).read_text())
        assert kept["resonances"][0]["frequency_hz"] == r["frequency_hz"]
    assert len(list((out / "summaries").iterdir())) == 2


def test_a_rerun_skips_by_content_hash_and_a_changed_file_is_done_again(tmp_path, fleet, capsys):
    root, _ = fleet
    folder = tmp_path / "fleet"
    shutil.copytree(root, folder)
    out = tmp_path / "out"
    assert batch(str(folder), "--out", str(out), "--scheduler", "synchronous") == 0
    first = pd.read_parquet(out / "batch.parquet")
    capsys.readouterr()
    assert batch(str(folder), "--out", str(out), "--scheduler", "synchronous") == 0
    assert "0 identified, 0 failed, 5 skipped" in capsys.readouterr().out
    pd.testing.assert_frame_equal(pd.read_parquet(out / "batch.parquet"), first)
    # a renamed copy has the same content: skipped too
    shutil.copy(folder / "ax2" / "b.h5", folder / "ax2" / "b_copy.h5")
    changed = folder / "ax1" / "ax1_20261101T000000Z.h5"
    true_f = write_recording(changed, 1.0e5, axis="ax1")
    assert batch(str(folder), "--out", str(out), "--scheduler", "synchronous") == 0
    assert "1 identified, 0 failed, 5 skipped" in capsys.readouterr().out
    rows = pd.read_parquet(out / "batch.parquet")
    assert len(rows) == 6
    new = rows.iloc[-1]
    assert new["path"] == str(changed.resolve()) and new["content_sha256"] == content_sha256(changed)
    assert abs(new["frequency_hz"] - true_f) / true_f < 0.01
    # --retry-failed: the three failures again, replacing their rows
    assert batch(str(folder), "--out", str(out), "--scheduler", "synchronous", "--retry-failed") == 0
    assert "0 identified, 3 failed, 3 skipped" in capsys.readouterr().out
    again = pd.read_parquet(out / "batch.parquet")
    assert len(again) == 6 and (again["status"] == "failed").sum() == 3


def test_a_table_inside_an_input_folder_is_not_taken_for_a_recording(tmp_path, fleet, capsys):
    root, _ = fleet
    folder = tmp_path / "fleet"
    shutil.copytree(root / "ax2", folder)
    (folder / "b.h5").unlink()  # the failures only: quick
    for _ in range(2):
        assert batch(str(folder), "--out", str(folder / "table"), "--scheduler", "synchronous") == 0
    assert "batch: 3 recordings: 0 identified, 0 failed, 3 skipped" in capsys.readouterr().out
    assert len(pd.read_parquet(folder / "table" / "batch.parquet")) == 3


def test_a_config_change_redoes_the_rows_but_batch_keys_do_not(tmp_path):
    base = parse_config("[identification]\nmax_resonances = 2\n", "a.toml")
    drift = parse_config("[identification]\nmax_resonances = 2\n[batch]\ndrift_percent_per_day = 0.5\n", "b.toml")
    other = parse_config("[identification]\nmax_resonances = 3\n", "a.toml")
    assert runner.config_key(base) == runner.config_key(drift) != runner.config_key(other)
    assert runner.config_key(None) != runner.config_key(base)


def test_a_csv_recording_with_a_config_gets_its_axis_from_its_folder_and_time_from_its_name(tmp_path):
    data, _ = simulated(1.5e5)
    folder = tmp_path / "spindle"
    folder.mkdir()
    write_csv(folder / "scope_2026-10-01T12-00-00.csv", {"t": data[:, 1], "tau": data[:, 3], "v": data[:, 4]})
    config = tmp_path / "csv.toml"
    config.write_text(
        '[data]\ntime = "t"\ntorque = "tau"\nvelocity = "v"\n[identification]\nmax_resonances = 1\n'
        "model_max_order = 0\n"
    )
    assert (
        batch(str(folder), "--config", str(config), "--out", str(tmp_path / "out"), "--scheduler", "synchronous") == 0
    )
    (row,) = pd.read_parquet(tmp_path / "out" / "batch.parquet").to_dict("records")
    assert (row["status"], row["axis"], row["time_source"]) == ("ok", "spindle", "name")
    assert row["time_utc"] == "2026-10-01T12:00:00.000+00:00"
    assert row["sample_rate_hz"] == pytest.approx(RATE) and row["duration_s"] == pytest.approx(6.0, abs=0.01)
    assert row["config_sha256"] == runner.config_key(parse_config(config.read_text(), str(config)))


def test_ctrl_c_keeps_the_rows_finished_so_far(tmp_path, fleet, monkeypatch, capsys):
    root, _ = fleet
    calls = []

    def interrupted_second(path, *args):
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return identify_task(path, *args)

    monkeypatch.setattr(runner, "identify_task", interrupted_second)
    out = tmp_path / "out"
    assert batch(str(root), "--out", str(out), "--scheduler", "synchronous") == 130
    assert "1 recordings finished are in" in capsys.readouterr().err
    rows = pd.read_parquet(out / "batch.parquet")
    assert rows["path"].tolist() == [calls[0]]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary file left


def test_a_failed_write_leaves_the_earlier_table_whole(tmp_path, monkeypatch):
    import pyarrow.parquet as pq

    rows = [{"path": "a.h5", "status": "ok", "frequency_hz": 20.0}]
    table.write_rows(tmp_path, rows)
    before = (tmp_path / "batch.parquet").read_bytes()

    def half_written(tbl, where):
        Path(where).write_bytes(b"PAR1 half")
        raise OSError("disk full")

    monkeypatch.setattr(pq, "write_table", half_written)
    with pytest.raises(OSError, match="disk full"):
        table.write_rows(tmp_path, rows * 2)
    assert (tmp_path / "batch.parquet").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["batch.csv", "batch.parquet"]
    assert table.read_rows(tmp_path)[0]["frequency_hz"] == 20.0


def test_a_damaged_earlier_table_is_a_data_error_naming_it(tmp_path, fleet, capsys):
    root, _ = fleet
    (tmp_path / "batch.parquet").write_bytes(b"not parquet")
    assert batch(str(root / "ax2" / "b.h5"), "--out", str(tmp_path), "--scheduler", "synchronous") == 3
    stderr = capsys.readouterr().err
    assert "batch.parquet: the earlier batch table cannot be read" in stderr and "Traceback" not in stderr


# --- [batch] and the command line ---------------------------------------------------------------------------------


def test_the_batch_table_has_its_defaults_and_checked_keys(tmp_path, capsys):
    cfg = parse_config("")
    assert (cfg.batch.drift_percent_per_day, cfg.batch.min_recordings, cfg.batch.confidence) == (0.1, 5, 0.95)
    bad = tmp_path / "bad.toml"
    for text, key in (
        ("[batch]\nmin_recordings = 2\n", "batch.min_recordings"),
        ("[batch]\ndrift_percent_per_day = 0\n", "batch.drift_percent_per_day"),
        ("[batch]\nconfidence = 1.0\n", "batch.confidence"),
        ("[batch]\nwindow_days = 3\n", "batch.window_days"),
    ):
        bad.write_text(text)
        assert batch(str(bad), "--config", str(bad), "--out", str(tmp_path / "o")) == 2
        stderr = capsys.readouterr().err
        assert key in stderr and str(bad) in stderr and "Traceback" not in stderr


def test_workers_with_a_scheduler_or_below_one_is_a_usage_error(tmp_path, fleet, capsys):
    root, _ = fleet
    for extra in (["--scheduler", "synchronous", "--workers", "2"], ["--workers", "0"]):
        assert batch(str(root), "--out", str(tmp_path / "o"), *extra) == 2
        assert "--workers" in capsys.readouterr().err


def test_a_config_error_comes_before_dask_and_the_analysis_are_imported(tmp_path):
    from test_startup import PROBE, SRC

    bad = tmp_path / "bad.toml"
    bad.write_text("[batch]\nmin_recordings = 1\n")
    heavy = ["dask", "distributed", "pyarrow", "numpy", "scipy", "h5py", "matplotlib"]
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            PROBE,
            json.dumps(["batch", "x.h5", "--config", str(bad), "--out", str(tmp_path / "o")]),
            "",
            json.dumps(heavy),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(SRC)},
    )
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["code"] == 2 and report["heavy"] == []
    assert "batch.min_recordings" in done.stderr


def test_time_stamps_are_utc_iso_strings(tmp_path, fleet):
    root, _ = fleet
    stamp = recording_identity(root / "ax2" / "b.h5")["time_utc"]
    assert dt.datetime.fromisoformat(stamp).utcoffset() == dt.timedelta(0)
