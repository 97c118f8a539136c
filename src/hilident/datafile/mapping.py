"""Columns mapped onto named signals in SI units, checked, and cut to the gap-free rows: :func:`load_dataset`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hilident.config.tables import DataConfig
from hilident.datafile.columns import read_columns
from hilident.datafile.raw import RawColumns, listed_names
from hilident.errors import ConfigError, DataError

#: Fewest samples an identification is attempted on.
MIN_SAMPLES = 64

#: Time stamps checked per chunk.
_TIME_CHUNK = 1 << 20

_SIGNAL_KEYS = ("torque", "velocity", "position", "output", "excitation")

#: Largest relative difference between two sample rates of one record (or of two records) accepted as one
#: clock: a crystal is good to 1e-4 and time stamps rounded to microseconds add a little.
RATE_TOLERANCE = 1e-4


@dataclass
class Dataset:
    """Named signals in SI units at one sample rate.

    Attributes
    ----------
    signals : dict of str to ndarray
        Any of ``torque`` (N·m), ``velocity`` (m/s), ``position`` (m),
        ``output``, ``excitation``, all the same length: the rows analysed.
    sample_rate_hz : float
    source : str
        The file they were read from.
    notes : list of str
        What was derived, assumed or left out (e.g. velocity from position,
        periods with lost samples, a recording that did not complete).
    info : dict
        What the file held and what was used: ``rows``, ``used_rows``,
        ``segments``, ``gaps``, ``n_gaps``, ``missing_samples``,
        ``period_samples``, ``status`` (hilident files; None otherwise),
        ``reason``, ``flushed_samples``.
    period_samples : int or None
        Period of the excitation when the analysed rows are whole periods.
    segments : list of (int, int)
        ``(start, stop)`` ranges of the signals recorded without a break
        (whole periods of one stretch join seamlessly; across two stretches
        the signals jump).
    """

    signals: dict[str, np.ndarray]
    sample_rate_hz: float
    source: str
    notes: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    period_samples: int | None = None
    segments: list[tuple[int, int]] = field(default_factory=list)

    def longest_segment(self) -> Dataset:
        """The longest stretch recorded without a break (this dataset when it has one segment)."""
        if len(self.segments) <= 1:
            return self
        a, b = max(self.segments, key=lambda r: r[1] - r[0])
        return Dataset(
            {k: v[a:b] for k, v in self.signals.items()},
            self.sample_rate_hz,
            self.source,
            list(self.notes),
            dict(self.info),
            None,
            [(0, b - a)],
        )

    def __len__(self) -> int:
        return len(next(iter(self.signals.values())))


def load_dataset(path: str | Path, cfg: DataConfig, config_source: str = "") -> Dataset:
    """Read ``path``, map its columns as ``cfg`` says, and keep the gap-free rows.

    Raises
    ------
    DataError
        Unknown column, NaN or infinite values, mismatched lengths, too few
        samples, irregular time stamps, a sample rate that disagrees with
        them, too few whole gap-free periods, or a damaged or oversized file.
    ConfigError
        No sample rate anywhere, or no torque column configured.
    """
    path = Path(path)
    wanted = _wanted(cfg)
    if not cfg.inputs and "torque" not in wanted:
        raise ConfigError("data.torque", "names no column", config_source)
    _check_config_rate(cfg, config_source)
    labels = {name: f"data.{key}" for key, (name, _) in wanted.items()}
    if cfg.time:
        labels.setdefault(cfg.time, "data.time")
    raw = read_columns(path, cfg.format, labels, cfg.column_names)
    signals = _mapped(path, raw, wanted)
    n = len(next(iter(signals.values())))
    if n < MIN_SAMPLES:
        raise DataError(f"{path}: {n} samples; at least {MIN_SAMPLES} are needed")
    index, time_rate = _row_index(path, cfg, raw, n)
    rate, rates = _sample_rate(path, cfg, time_rate, raw.sample_rate_hz, config_source)
    notes = list(raw.notes) + _status_notes(path, raw)
    configured = _configured_period(cfg, rate, config_source)
    period = raw.period_samples if raw.indexed and not configured else None
    if period and index is not None:  # an indexed recording always has its row index
        period = _recorded_period_checked(path, raw, index, period, notes)
    raw.columns.clear()  # the mapped signals hold what is still needed
    used, segments, info = _gap_free(path, signals, index, period)
    notes += info.pop("warnings")
    if configured:
        used, segments = _whole_periods_of(path, used, segments, configured, info, notes)
    info["sample_rates_hz"] = rates
    info["sample_rate_spread"] = (max(rates.values()) - min(rates.values())) / rate
    if info["used_rows"] < MIN_SAMPLES:
        raise DataError(f"{path}: {info['used_rows']} gap-free samples; at least {MIN_SAMPLES} are needed")
    _check_varying(path, used, wanted)
    if not cfg.inputs:  # a torque-to-motion record: the velocity from the position where it is missing
        _complete_motion(used, segments, rate, notes, config_source)
    info.update(status=raw.status, reason=raw.reason, flushed_samples=raw.flushed_samples)
    return Dataset(used, rate, str(path), notes, info, info["period_samples"], segments)


def _wanted(cfg: DataConfig) -> dict[str, tuple[str, float]]:
    """Signal key -> (column, scale): ``inputs[i]`` and ``outputs[j]`` for several channels
    (:func:`channel_keys`), else the named signals (torque, velocity, ...)."""
    if cfg.inputs:
        inputs, outputs = channel_keys(cfg)
        scales = [*(cfg.input_scales or [1.0] * len(inputs)), *(cfg.output_scales or [1.0] * len(outputs))]
        columns = [*cfg.inputs, *cfg.outputs]
        return {key: (name, float(k)) for key, name, k in zip([*inputs, *outputs], columns, scales, strict=True)}
    return {key: (getattr(cfg, key), getattr(cfg, f"{key}_scale")) for key in _SIGNAL_KEYS if getattr(cfg, key)}


def channel_keys(cfg: DataConfig) -> tuple[list[str], list[str]]:
    """The signal keys of ``data.inputs`` and ``data.outputs`` in a :class:`Dataset`: ``inputs[0]``, ...,
    ``outputs[0]``, ... (each names its config key in messages: ``data.inputs[0]``)."""
    return [f"inputs[{i}]" for i in range(len(cfg.inputs))], [f"outputs[{j}]" for j in range(len(cfg.outputs))]


def _recorded_period_checked(
    path: Path, raw: RawColumns, index: np.ndarray, period: int, notes: list[str]
) -> int | None:
    """The period a hilident recording states, if its excitation confirms it (else None and a note)."""
    confirmed, why = _confirmed_period(index, raw.columns.get("excitation"), period)
    if why and raw.underruns:
        why = (
            f"the run had {raw.underruns} underrun samples (the device ran out of excitation and played "
            f"zeros), so the recorded excitation does not repeat every {period} samples: whole periods are "
            "not used, and the run's own result, which averaged them, is not to be trusted"
        )
    notes += [f"{path.name}: {why}"] if why else []
    return confirmed


def _check_varying(path: Path, used: dict[str, np.ndarray], wanted: dict) -> None:
    """Refuse a mapped column that is constant over the rows analysed."""
    for key, values in used.items():
        if np.ptp(values) == 0.0:
            raise DataError(
                f"{path}: column {wanted[key][0]!r} (data.{key}) is constant ({values[0]:g}): it excites nothing"
            )


def _complete_motion(used: dict[str, np.ndarray], segments, rate: float, notes: list[str], config_source: str) -> None:
    """Velocity from position when only position is mapped; the output is the velocity when not mapped."""
    if "velocity" not in used and "position" in used:
        used["velocity"] = _derivative(used["position"], segments, rate)
        notes.append("velocity derived from position by central differences (within each gap-free segment)")
    if "output" not in used:
        if "velocity" not in used:
            raise ConfigError(
                "data.output",
                "names no column, and neither data.velocity nor data.position does: "
                "give the response column (a torque-to-output response needs no "
                "velocity)",
                config_source,
            )
        used["output"] = used["velocity"]


def _gap_free(path: Path, signals: dict[str, np.ndarray], index: np.ndarray | None, period: int | None):
    """The rows to analyse, their gap-free segments (in the returned arrays) and what was used.

    Without an index (no ``sample_index``, no time column) every row is
    taken as one gap-free record, without copying.
    """
    n = len(next(iter(signals.values())))
    if index is None:
        info = {
            "rows": n,
            "used_rows": n,
            "segments": 1,
            "gaps": [],
            "n_gaps": 0,
            "missing_samples": 0,
            "period_samples": None,
            "warnings": [],
        }
        return signals, [(0, n)], info
    from hilident.pipeline.selection import select_gap_free

    try:
        selection = select_gap_free(index, period, path.name)
        notes = []
    except DataError:
        if not period:
            raise
        # too few whole periods: a stretch without a break can still be analysed (Welch averaging)
        selection = select_gap_free(index, None, path.name)
        notes = [
            f"{path.name}: fewer than two whole gap-free excitation periods of {period} samples; "
            "the longest gap-free stretch is analysed instead"
        ]
    info = dict(selection.to_dict(), warnings=notes + selection.warnings)
    if selection.used_rows == n:
        return signals, selection.segments, info
    used = {key: v[selection.keep] for key, v in signals.items()}
    edges = np.cumsum([0] + [b - a for a, b in selection.segments])
    return used, [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)], info


def _confirmed_period(index: np.ndarray, excitation: np.ndarray | None, period: int) -> tuple[int | None, str]:
    """``period`` if the recorded excitation repeats with it (or was not recorded), else None and why.

    A stored configuration can describe another run than the one recorded
    (edited, or replaced in a script); joining "periods" that are not would
    splice. Of the first three pairs of consecutive whole periods recorded
    without a break (the lead-in counts: it is the first period played
    again), one must repeat to 10⁻⁶ of the peak; an underrun may have
    changed another. With no such pair the period is kept unconfirmed.
    """
    if excitation is None:
        return period, ""
    from hilident.pipeline.selection import contiguous_runs

    pairs = 0
    for a, b in contiguous_runs(index):
        first = -(-int(index[a]) // period)
        start = a + first * period - int(index[a])
        while start + 2 * period <= b and pairs < 3:
            one, two = excitation[start : start + period], excitation[start + period : start + 2 * period]
            scale = float(np.max(np.abs(one))) or 1.0
            if np.max(np.abs(one - two)) <= 1e-6 * scale:
                return period, ""
            pairs += 1
            start += period
        if pairs == 3:
            break
    if not pairs:
        return period, ""
    return None, (
        f"the recorded excitation does not repeat every {period} samples as the stored configuration "
        "says: whole periods are not used"
    )


def _check_config_rate(cfg: DataConfig, source: str) -> None:
    rate = cfg.sample_rate_hz
    if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate < 0:
        raise ConfigError("data.sample_rate_hz", f"must be a finite number >= 0, got {rate!r}", source)


def _mapped(path: Path, raw: RawColumns, wanted: dict) -> dict[str, np.ndarray]:
    """Scaled signals of the mapped columns, all finite and equally long."""
    signals = {}
    uses: dict[str, int] = {}
    for name, _ in wanted.values():
        uses[name] = uses.get(name, 0) + 1
    for key, (name, scale) in wanted.items():
        if name not in raw.columns:
            if name in raw.available:
                raise DataError(f"{path}: column {name!r} (data.{key}) is not numeric")
            raise DataError(f"{path}: no column {name!r} (data.{key}); the file has: {listed_names(raw.available)}")
        values = np.asarray(raw.columns[name], dtype=float)
        if scale != 1.0:
            # the column is ours: scale it in place unless another signal maps it too
            values = values * scale if uses[name] > 1 else np.multiply(values, scale, out=values)
        signals[key] = values
    lengths = {key: len(v) for key, v in signals.items()}
    if len(set(lengths.values())) > 1:
        raise DataError(f"{path}: columns of different lengths: {lengths}")
    for key, values in signals.items():
        if np.isfinite(values).all():
            continue
        bad = np.flatnonzero(~np.isfinite(values))
        if len(bad):
            raise DataError(
                f"{path}: column {wanted[key][0]!r} (data.{key}) has {len(bad)} NaN or infinite values, "
                f"the first at row {bad[0]}"
            )
    return signals


def _status_notes(path: Path, raw: RawColumns) -> list[str]:
    if raw.status in (None, "complete"):
        return []
    if raw.status == "running":
        why = "the recording process ended without closing it, or is still writing"
    elif raw.status == "aborted":
        why = f"aborted: {raw.reason or 'no reason recorded'}"
    else:
        why = f"status {raw.status!r}"
    return [f"{path.name}: the recording did not complete ({why}); it may end early"]


def _row_index(path: Path, cfg: DataConfig, raw: RawColumns, n: int) -> tuple[np.ndarray | None, float | None]:
    """Index of each row on the sample clock (None: no way to tell), and the rate the time column gives."""
    index = None
    if "sample_index" in raw.columns:
        si = raw.columns["sample_index"][:n]
        if len(si) != n or not np.all(np.isfinite(si)) or np.any(si != np.round(si)) or np.any(np.abs(si) > 2**53):
            raise DataError(f"{path}: sample_index column is not whole numbers")
        index = si.astype(np.int64)
    time_rate = None
    if cfg.time:
        t_index, time_rate = _time_index(path, cfg.time, raw, n)
        if index is None:
            index = t_index
    return index, time_rate


def _time_index(path: Path, name: str, raw: RawColumns, n: int) -> tuple[np.ndarray | None, float]:
    """Sample numbers from a time column whose steps are whole multiples of one sample period.

    A step of two periods or more is a gap; a step that is no whole
    multiple (within 0.1 % of a period) is an irregular time stamp. The
    column is checked a chunk at a time (bounded temporaries); without a
    gap no index is built at all (None: every row follows the one before).
    The period is the median step of the first chunk.
    """
    if name not in raw.columns:
        raise DataError(f"{path}: no time column {name!r} (data.time); the file has: {listed_names(raw.available)}")
    t = np.asarray(raw.columns[name], dtype=float)
    if len(t) != n or not np.isfinite(t).all():
        raise DataError(f"{path}: time column {name!r} is not finite or not as long as the data")
    step = float(np.median(np.diff(t[: _TIME_CHUNK + 1])))
    rows, lengths = [], []
    for a in range(0, n - 1, _TIME_CHUNK):
        dt = np.diff(t[a : a + _TIME_CHUNK + 1])
        back = np.flatnonzero(dt <= 0)
        if len(back):
            i = a + int(back[0])
            raise DataError(
                f"{path}: time column {name!r} does not increase at row {i + 1} "
                f"(step {dt[i - a]:.6g} s); sort the data first"
            )
        steps = dt / step
        whole = np.rint(steps)
        off = np.flatnonzero(np.abs(steps - whole) > 1e-3)
        if len(off):
            i = a + int(off[0])
            raise DataError(
                f"{path}: time stamps are not uniform (step {dt[i - a]:.6g} s at row {i + 1}, median {step:.6g} s, "
                "not a whole number of sample periods); resample the data first"
            )
        jumps = np.flatnonzero(whole != 1)
        rows.append(a + 1 + jumps)
        lengths.append(whole[jumps].astype(np.int64) - 1)
    rows_after = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    missing = np.concatenate(lengths) if lengths else np.zeros(0, np.int64)
    rate = float((n - 1 + int(missing.sum())) / (t[-1] - t[0]))
    if not len(rows_after):
        return None, rate
    skip = np.zeros(n, dtype=np.int64)
    skip[rows_after] = missing
    return np.arange(n, dtype=np.int64) + np.cumsum(skip), rate


def _sample_rate(path, cfg: DataConfig, from_time, file_rate, source) -> tuple[float, dict]:
    """The sample rate, Hz, and where it came from (``{source: rate}``, for ``summary.json``).

    ``data.sample_rate_hz`` wins when it is set; else the file's recorded
    rate, else the time column's. Rates from several sources must agree to
    :data:`RATE_TOLERANCE` (relative): the message names the keys the user
    can change, never one that was not set.
    """
    rates = {}
    if cfg.sample_rate_hz:
        rates["data.sample_rate_hz"] = float(cfg.sample_rate_hz)
    if file_rate:
        rates["recorded sample_rate_hz attribute"] = float(file_rate)
    if from_time:
        rates[f"time column {cfg.time!r} (data.time)"] = float(from_time)
    if not rates:
        raise ConfigError(
            "data.sample_rate_hz", "is needed: the data have no time column (data.time) and no recorded rate", source
        )
    if any(not math.isfinite(r) or r <= 0 for r in rates.values()):
        raise DataError(f"{path}: sample rate {list(rates.values())} is not a positive finite number")
    (first, rate), *others = rates.items()
    for what, r in others:
        spread = abs(r - rate) / rate
        if spread > RATE_TOLERANCE:
            fix = (
                "correct data.sample_rate_hz or leave it out"
                if first == "data.sample_rate_hz"
                else "check the time unit of data.time (seconds), or leave data.time out"
            )
            raise DataError(
                f"{path}: {first} gives {rate:.9g} Hz, the {what} {r:.9g} Hz: they differ by "
                f"{spread:.2g} (relative; {RATE_TOLERANCE:g} is accepted): {fix}"
            )
    return float(rate), rates


def _configured_period(cfg: DataConfig, rate: float, source: str) -> int | None:
    """``data.period_samples``, or ``data.period_s`` in whole samples at ``rate`` (None: not set)."""
    if cfg.period_samples:
        return int(cfg.period_samples)
    if not cfg.period_s:
        return None
    exact = cfg.period_s * rate
    period = int(round(exact))
    if period < 4 or abs(exact - period) > 1e-3:
        raise ConfigError(
            "data.period_s",
            f"{cfg.period_s:g} s is {exact:.6g} samples at {rate:.9g} Hz, not a whole "
            "number (>= 4): give data.period_samples",
            source,
        )
    return period


def _whole_periods_of(path: Path, used: dict, segments, period: int, info: dict, notes: list[str]):
    """The whole periods of the longest gap-free stretch (a periodic signal's periods can start anywhere)."""
    a, b = max(segments, key=lambda r: r[1] - r[0])
    count = (b - a) // period
    if count < 1:
        raise DataError(
            f"{path}: {b - a} gap-free samples are less than one excitation period of {period} "
            "samples (data.period_s / data.period_samples)"
        )
    stop = a + count * period
    if (a, stop) != (0, len(next(iter(used.values())))):
        used = {k: v[a:stop] for k, v in used.items()}
        notes.append(
            f"{path.name}: {count} whole period(s) of {period} samples analysed"
            + (f"; {b - stop} samples after the last whole period left out" if b > stop else "")
        )
    info.update(used_rows=count * period, segments=1, period_samples=period)
    return used, [(0, count * period)]


def _derivative(x: np.ndarray, segments: list[tuple[int, int]], rate: float) -> np.ndarray:
    """Central differences within each gap-free segment (never across a join)."""
    from hilident.ident.preprocess import central_difference

    out = np.empty_like(x)
    for a, b in segments:
        out[a:b] = central_difference(x[a:b], rate) if b - a >= 2 else 0.0
    return out
