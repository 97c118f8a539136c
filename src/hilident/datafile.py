"""Recordings made elsewhere: hilident HDF5, CSV or MATLAB ``.mat``, mapped onto named signals.

The ``[data]`` table of a configuration says which column (or variable) holds
the torque, velocity, position, output and excitation, how to scale each to SI
units, and the sample rate or the time column. Everything is checked here, so
the numerics downstream only see finite, equally long, uniformly sampled
arrays; anything else is a :class:`~hilident.errors.DataError` naming the file
and the column.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hilident.config import DataConfig
from hilident.errors import ConfigError, DataError

#: Fewest samples an identification is attempted on.
MIN_SAMPLES = 64


@dataclass
class Dataset:
    """Named signals in SI units at one sample rate.

    Attributes
    ----------
    signals : dict of str to ndarray
        Any of ``torque`` (N·m), ``velocity`` (m/s), ``position`` (m),
        ``output``, ``excitation``, all the same length.
    sample_rate_hz : float
    source : str
        The file they were read from.
    notes : list of str
        What was derived or assumed (e.g. velocity from position).
    """

    signals: dict[str, np.ndarray]
    sample_rate_hz: float
    source: str
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(next(iter(self.signals.values())))


def read_columns(path: str | Path, fmt: str = "auto") -> tuple[dict[str, np.ndarray], float | None]:
    """Every numeric column of a file, and its sample rate when the file records one."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    kind = fmt if fmt != "auto" else {".h5": "hilident", ".hdf5": "hilident", ".csv": "csv", ".txt": "csv",
                                      ".mat": "mat"}.get(path.suffix.lower())
    if kind is None:
        raise ConfigError("data.format", f"cannot tell the format of {path.name}; set hilident, csv or mat", str(path))
    if kind == "hilident":
        from hilident.recording import read_run

        run = read_run(path)
        return dict(run.samples), float(run.sample_rate_hz)
    if kind == "csv":
        return _read_csv(path), None
    return _read_mat(path), None


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="", encoding="utf-8") as fh:
        sample = fh.read(4096)
        fh.seek(0)
        try:
            dialect = csv.Sniffer().sniff(sample, delimiters=",;\t ")
        except csv.Error:
            dialect = csv.excel
        rows = list(csv.reader(fh, dialect))
    if not rows:
        raise DataError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    body = [r for r in rows[1:] if any(c.strip() for c in r)]
    columns: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        values = np.empty(len(body))
        for i, r in enumerate(body):
            try:
                values[i] = float(r[j]) if j < len(r) and r[j].strip() else np.nan
            except ValueError:
                raise DataError(f"{path}: row {i + 2}, column {name!r}: {r[j]!r} is not a number") from None
        columns[name] = values
    return columns


def _read_mat(path: Path) -> dict[str, np.ndarray]:
    try:
        from scipy.io import loadmat

        raw = loadmat(path, squeeze_me=True)
        items = {k: v for k, v in raw.items() if not k.startswith("__")}
    except NotImplementedError:  # MATLAB v7.3 files are HDF5
        import h5py

        with h5py.File(path, "r") as f:
            items = {k: np.asarray(f[k]).squeeze() for k in f if isinstance(f[k], h5py.Dataset)}
    except ValueError as exc:
        raise DataError(f"{path}: not a MATLAB file ({exc})") from None
    columns = {}
    for name, value in items.items():
        arr = np.asarray(value)
        if arr.dtype.kind in "fiu" and arr.ndim == 1:
            columns[name] = arr.astype(float)
    return columns


def load_dataset(path: str | Path, cfg: DataConfig, config_source: str = "") -> Dataset:
    """Read ``path`` and map its columns as ``cfg`` says.

    Raises
    ------
    DataError
        Unknown column, NaN or infinite values, mismatched lengths, too few
        samples, non-uniform time stamps, or a sample rate that disagrees with them.
    ConfigError
        No sample rate anywhere, or no torque column configured.
    """
    path = Path(path)
    columns, file_rate = read_columns(path, cfg.format)
    available = ", ".join(sorted(columns)) or "none"

    def column(name: str, key: str) -> np.ndarray:
        if name not in columns:
            raise DataError(f"{path}: no column {name!r} (data.{key}); the file has: {available}")
        return np.asarray(columns[name], dtype=float)

    wanted = {
        key: (getattr(cfg, key), getattr(cfg, f"{key}_scale"))
        for key in ("torque", "velocity", "position", "output", "excitation")
        if getattr(cfg, key)
    }
    if "torque" not in wanted:
        raise ConfigError("data.torque", "names no column", config_source)
    signals = {key: column(name, key) * scale for key, (name, scale) in wanted.items()}
    lengths = {key: len(v) for key, v in signals.items()}
    if len(set(lengths.values())) > 1:
        raise DataError(f"{path}: columns of different lengths: {lengths}")
    n = next(iter(lengths.values()))
    if n < MIN_SAMPLES:
        raise DataError(f"{path}: {n} samples; at least {MIN_SAMPLES} are needed")
    for key, values in signals.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if len(bad):
            raise DataError(
                f"{path}: column {wanted[key][0]!r} (data.{key}) has {len(bad)} NaN or infinite values, "
                f"the first at row {bad[0]}"
            )
        if np.ptp(values) == 0.0:
            raise DataError(
                f"{path}: column {wanted[key][0]!r} (data.{key}) is constant ({values[0]:g}): it excites nothing"
            )
    rate = _sample_rate(path, cfg, columns, file_rate, n, config_source)
    notes = []
    if "velocity" not in signals:
        if "position" not in signals:
            raise ConfigError("data.velocity", "neither a velocity nor a position column is configured", config_source)
        from hilident.ident.preprocess import central_difference

        signals["velocity"] = central_difference(signals["position"], rate)
        notes.append("velocity derived from position by central differences")
    if "output" not in signals:
        signals["output"] = signals["velocity"]
    return Dataset(signals, rate, str(path), notes)


def _sample_rate(path, cfg: DataConfig, columns, file_rate, n, source) -> float:
    from_time = None
    if cfg.time:
        if cfg.time not in columns:
            raise DataError(f"{path}: no time column {cfg.time!r} (data.time); the file has: {', '.join(sorted(columns))}")
        t = np.asarray(columns[cfg.time], dtype=float)
        if len(t) != n or not np.all(np.isfinite(t)):
            raise DataError(f"{path}: time column {cfg.time!r} is not finite or not as long as the data")
        dt = np.diff(t)
        step = float(np.median(dt))
        off = np.flatnonzero(np.abs(dt - step) > 1e-3 * abs(step)) if step > 0 else np.array([0])
        if step <= 0 or len(off):
            i = int(off[0]) if len(off) else 0
            raise DataError(
                f"{path}: time stamps are not uniform (step {dt[i]:.6g} s at row {i + 1}, median {step:.6g} s); "
                "resample the data first"
            )
        from_time = 1.0 / step
    rates = [r for r in (cfg.sample_rate_hz or None, from_time, file_rate) if r]
    if not rates:
        raise ConfigError("data.sample_rate_hz", "is needed: the data have no time column and no recorded rate", source)
    if any(abs(r - rates[0]) > 1e-3 * rates[0] for r in rates):
        raise DataError(f"{path}: sample rates disagree: config {cfg.sample_rate_hz:g} Hz, data {rates}")
    return float(rates[0])
