"""Pinned outputs of ``load_dataset`` and ``read_columns`` for CSV and hilident files.

``test_datafile_pinned.json`` holds what the reader produced on these files
before ``datafile`` was split into one module per format; rows, rates, gaps,
notes and the mapped signals must stay the same. Regenerate only for an
intended change: ``PYTHONPATH=src:tests python tests/test_datafile_pinned.py``.
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import h5py
import numpy as np

from hilident.config.tables import DataConfig
from hilident.datafile import load_dataset, read_columns, read_run_info
from hilident.io.recording import RunWriter
from ident.pinned import assert_same, flatten, load_expected, store_expected

EXPECTED = Path(__file__).with_suffix(".json")
RATE = 500.0
N = 1200
PERIOD = 200
RUN_CONFIG = f"""
[run]
sample_rate_hz = {RATE}
[excitation]
kind = "multisine"
amplitude_nm = 1.0
f_min_hz = 5.0
f_max_hz = 50.0
period_s = {PERIOD / RATE}
duration_s = {N / RATE}
"""


def _signals():
    k = np.arange(N)
    excitation = np.tile(
        np.sin(2 * np.pi * 7 * np.arange(PERIOD) / PERIOD) + 0.3 * np.sin(2 * np.pi * 19 * np.arange(PERIOD) / PERIOD),
        N // PERIOD,
    )
    torque = excitation + 0.01 * np.cos(0.37 * k)
    velocity = np.cumsum(torque) / RATE - 0.2 * np.sin(0.011 * k)
    position = np.cumsum(velocity) / RATE
    return k, excitation, torque, velocity, position


def _summary(value):
    """Long arrays as a few sums and ends (enough to see a changed, shifted or reordered value)."""
    if isinstance(value, np.ndarray) and value.size > 12:
        ramp = np.linspace(-1.0, 2.0, value.size)
        return {
            "len": value.size,
            "sum": float(value.sum()),
            "abs": float(np.abs(value).sum()),
            "ramp": float(value @ ramp),
            "head": value[:3],
            "tail": value[-3:],
        }
    if isinstance(value, dict):
        return {k: _summary(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_summary(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _summary(getattr(value, f.name)) for f in dataclasses.fields(value)}
    return value


def _without_folder(value, folder: str):
    """Paths in messages and sources relative to the temporary folder."""
    if isinstance(value, str):
        return value.replace(folder, "<tmp>")
    if isinstance(value, dict):
        return {k: _without_folder(v, folder) for k, v in value.items()}
    if isinstance(value, list):
        return [_without_folder(v, folder) for v in value]
    return value


def _write_csv(path: Path, gap_at: int | None = None, header: bool = True) -> None:
    k, excitation, torque, velocity, position = _signals()
    t = k / RATE
    if gap_at is not None:
        t = np.r_[t[:gap_at], t[gap_at + 3 :]]
        rows = np.column_stack([t, torque[: t.size] * 1000.0, position[: t.size], excitation[: t.size]])
    else:
        rows = np.column_stack([t, torque * 1000.0, position, excitation])
    lines = ["time_s,torque_mnm,position_m,excitation"] if header else []
    lines += [",".join(repr(float(x)) for x in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")


def _write_run(
    path: Path, lost: tuple[int, int] | None = None, flushed: int | None = None, status: str = "complete"
) -> None:
    k, excitation, torque, velocity, position = _signals()
    table = np.column_stack([k, k / RATE, excitation, torque, velocity, position])
    if lost is not None:
        table = np.r_[table[: lost[0]], table[lost[1] :]]
    with RunWriter(
        path,
        ["sample_index", "time_s", "excitation", "torque_nm", "velocity_mps", "position_m"],
        ["1", "s", "N*m", "N*m", "m/s", "m"],
        RATE,
        {"experiment": "identification", "config_toml": RUN_CONFIG},
    ) as w:
        w.append(table)
    with h5py.File(path, "a") as f:
        if status != "complete":
            f.attrs["status"] = status
            f.attrs["reason"] = "limit trip: torque"
        if flushed is not None:
            f.attrs["flushed_samples"] = np.int64(flushed)


def _cases(folder: Path) -> dict:
    out = {}
    csv = folder / "bench.csv"
    _write_csv(csv)
    cfg = DataConfig(
        time="time_s", torque="torque_mnm", torque_scale=1e-3, position="position_m", excitation="excitation"
    )
    out["csv_time"] = load_dataset(csv, cfg)
    out["csv_periods"] = load_dataset(csv, dataclasses.replace(cfg, period_samples=PERIOD))
    gap = folder / "gap.csv"
    _write_csv(gap, gap_at=500)
    out["csv_gap"] = load_dataset(gap, cfg)
    bare = folder / "bare.dat"
    _write_csv(bare, header=False)
    out["csv_headerless"] = load_dataset(
        bare,
        DataConfig(sample_rate_hz=RATE, column_names=["t", "tau", "x", "e"], torque="tau", position="x", output="x"),
    )
    run = folder / "run.h5"
    _write_run(run)
    mapping = DataConfig(torque="torque_nm", velocity="velocity_mps", excitation="excitation")
    out["run"] = load_dataset(run, mapping)
    out["run_columns"] = read_columns(run, "auto", {"torque_nm": "data.torque"})
    out["run_info"] = read_run_info(run)
    lost = folder / "lost.h5"
    _write_run(lost, lost=(450, 460), flushed=1100, status="aborted")
    out["run_lost"] = load_dataset(lost, mapping)
    out["run_lost_columns"] = read_columns(lost, "hilident", None)
    return _without_folder(flatten(_summary(out)), str(folder))


def _current() -> dict:
    with tempfile.TemporaryDirectory() as folder:
        return _cases(Path(folder))


def test_read_and_mapped_data_are_those_recorded_before_the_split():
    assert_same(_current(), load_expected(EXPECTED))


if __name__ == "__main__":
    store_expected(EXPECTED, _current())
