"""Reading columns: headerless numeric files, columns by position, formats by extension, run attributes."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from hilident.config.tables import DataConfig
from hilident.datafile import load_dataset, read_columns, read_run_info
from hilident.errors import ConfigError, DataError

ROWS = np.column_stack([np.arange(100.0), np.sin(np.arange(100.0)), np.cos(np.arange(100.0))])


@pytest.mark.parametrize("suffix, delimiter", [(".csv", ","), (".dat", " "), (".tsv", "\t"), (".txt", ";")])
def test_a_headerless_file_is_read_by_position_whatever_its_delimiter(tmp_path, suffix, delimiter):
    path = tmp_path / f"d{suffix}"
    np.savetxt(path, ROWS, delimiter=delimiter)
    raw = read_columns(path, names={"2": "data.output", "0": "data.torque"})
    assert raw.available == ["0", "1", "2"]
    np.testing.assert_allclose(raw.columns["2"], ROWS[:, 2])
    np.testing.assert_allclose(raw.columns["0"], ROWS[:, 0])  # the first line is data, not a header
    assert any("no header row" in n for n in raw.notes)


def test_column_names_name_a_headerless_file_and_must_match_its_width(tmp_path):
    path = tmp_path / "d.csv"
    np.savetxt(path, ROWS, delimiter=",")
    raw = read_columns(path, names=["b"], column_names=("a", "b", "c"))
    np.testing.assert_allclose(raw.columns["b"], ROWS[:, 1])
    with pytest.raises(ConfigError, match=r"data\.column_names.*2 column\(s\).*3 per line"):
        read_columns(path, names=["a"], column_names=("a", "b"))


def test_a_position_picks_a_column_of_a_file_with_a_header_unless_a_column_has_that_name(tmp_path):
    path = tmp_path / "d.csv"
    np.savetxt(path, ROWS, delimiter=",", header="t,1,y", comments="")
    raw = read_columns(path, names=["2", "1"])
    np.testing.assert_allclose(raw.columns["2"], ROWS[:, 2])  # the third column, y
    np.testing.assert_allclose(raw.columns["1"], ROWS[:, 1])  # the column named "1"
    with pytest.raises(DataError, match="no column '7'"):
        read_columns(path, names={"7": "data.torque"})


def test_an_unknown_extension_names_the_format_key_and_an_explicit_format_reads_it(tmp_path):
    path = tmp_path / "record.asc"
    np.savetxt(path, ROWS, delimiter=",")
    with pytest.raises(ConfigError, match=r"data\.format.*csv"):
        read_columns(path)
    ds = load_dataset(path, DataConfig(format="csv", torque="1", output="2", sample_rate_hz=100.0))
    assert len(ds) == 100 and "velocity" not in ds.signals  # a response needs no velocity column


def test_a_configured_period_keeps_whole_periods_only(tmp_path):
    path = tmp_path / "p.csv"
    t = np.arange(250)
    np.savetxt(path, np.column_stack([np.sin(2 * np.pi * t / 50), np.cos(2 * np.pi * t / 50 + 0.3)]), delimiter=",")
    ds = load_dataset(path, DataConfig(torque="0", output="1", sample_rate_hz=100.0, period_samples=80))
    assert (len(ds), ds.period_samples) == (240, 80)
    assert any("10 samples after the last whole period" in n for n in ds.notes)
    with pytest.raises(DataError, match="less than one excitation period"):
        load_dataset(path, DataConfig(torque="0", output="1", sample_rate_hz=100.0, period_samples=300))


def test_run_info_only_for_hilident_run_files(tmp_path):
    np.savetxt(tmp_path / "d.csv", ROWS, delimiter=",")
    assert read_run_info(tmp_path / "d.csv") is None
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = ROWS
    assert read_run_info(tmp_path / "other.h5") is None
