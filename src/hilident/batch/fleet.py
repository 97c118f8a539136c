"""``hilident emulate fleet``: nightly identification recordings of many emulated axes over many days.

A fleet is test data for identifying many recordings at once and telling a
drifting axis from a healthy one. Every axis is a two-mass twin built from a
base configuration (its ``[emulator.plant]``, ``[excitation]`` and
``[identification]``) with masses and stiffness varied by up to
:data:`PARAMETER_SPREAD` (seeded), a sample rate from :data:`SAMPLE_RATES_HZ` in
turn, and one recording a night at :data:`NIGHTLY_UTC` plus a few minutes of
seeded jitter. A share of the axes has a stiffness that falls linearly in time
(a loosening belt); the others vary a little from day to day
(:data:`HEALTHY_WOBBLE`), as temperature would. A few files are damaged on
purpose (truncated, overwritten header bytes, empty, a crashed writer).

Nothing runs over a wire: each recording is the twin's plant simulated
directly, which is what makes hundreds of recordings a matter of seconds.
The plant (friction off, or viscous only: an offline identification has no
friction test) is discretised exactly (zero-order hold on the torque) at the
axis's sample rate and driven in open-loop torque by the whole periods of the
base configuration's periodic excitation, one lead-in period first, as a
run's identification experiment plays it. Unmeasured process torque noise
(the twin's ``[emulator]`` preset level, coloured), torque sensor noise,
encoder quantisation and the drive's filtered velocity estimate make it as
noisy as the twin. The file has the channels and root attributes of a
session's ``identification.h5`` (its configuration included), so
``hilident identify FILE`` needs nothing else.

The truth goes to ``DIR/fleet.json`` (:func:`truth_rate_percent_per_day`
defines the drift rate a batch estimate is compared with).

This module sits beside :mod:`hilident.io.recording` rather than in
``emulator/`` because it writes files: the emulator package is the device
side (physics and wire servers) and does no file I/O. It uses the emulator's
plant physics and truth, never an adapter.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hilident.config.tables import Config, parse_config, parse_toml
from hilident.errors import ConfigError, DataError, UsageError

__all__ = [
    "AXIS_PREFIX",
    "BASE_TOML",
    "DAMAGE_KINDS",
    "DEFAULT_START",
    "FLEET_FORMAT",
    "FleetResult",
    "SAMPLE_RATES_HZ",
    "AxisPlan",
    "plan_fleet",
    "truth_rate_percent_per_day",
    "write_fleet",
]

FLEET_FORMAT = "hilident-fleet"
FLEET_VERSION = 1
#: The first simulated day when ``--start`` is not given.
DEFAULT_START = _dt.date(2026, 1, 1)
#: Nightly recording time; each recording adds a seeded jitter of up to :data:`JITTER_S`.
NIGHTLY_UTC = _dt.time(2, 0)
JITTER_S = 600
#: The axes' sample rates, in turn: axis 1 at the first, axis 2 at the second, ...
SAMPLE_RATES_HZ = (500.0, 1000.0, 2000.0)
#: Largest relative deviation of an axis's m1, m2 and k from the base configuration's (uniform, seeded).
PARAMETER_SPREAD = 0.10
#: Range of a drifting axis's stiffness rate, percent per day (negative: the stiffness falls).
DRIFT_PERCENT_PER_DAY = (-1.5, -0.3)
#: A healthy axis's day-to-day relative stiffness variation (uniform within +-, seeded).
HEALTHY_WOBBLE = 0.001
#: Share of the recordings damaged on purpose, and the least number damaged in a fleet of 20 recordings or more.
DAMAGED_SHARE = 0.02
MIN_DAMAGED = 2
DAMAGE_KINDS = ("truncated", "header", "empty", "running")
AXIS_PREFIX = "axis-"
#: Rows of a ``running`` damaged file: below the 64 samples ``hilident identify`` needs, far below a period.
CRASHED_ROWS = 32
#: A session's identification channels (the myrio-board's, without the command and load channels).
CHANNELS = ("sample_index", "time_s", "excitation", "torque_nm", "position_m", "velocity_mps")
UNITS = ("1", "s", "N*m", "N*m", "m", "m/s")
#: Longest recording a fleet simulates (in memory, whole), s.
MAX_DURATION_S = 600.0
#: The excitation's peak when the base configuration says ``amplitude_nm = "auto"``: this share of its ceiling.
AUTO_AMPLITUDE_SHARE = 0.5

#: The base configuration when ``--config`` is not given: ``configs/emulated-gantry.toml``'s axis, without friction.
BASE_TOML = """\
# A gantry axis like the thesis's: a heavy cart (m1), a lighter load (m2) on a flexible beam (k, d).
[device]
driver = "myrio-board"
port = "emulator"

[run]
sample_rate_hz = 1000.0
seed = 7

[limits]
torque_nm = 19.0
velocity_mps = 0.4
position_min_m = -0.6
position_max_m = 0.6

[friction_test]
enabled = false

[excitation]
kind = "multisine"
mode = "torque"
amplitude_nm = 6.0
f_min_hz = 2.0
f_max_hz = 80.0
period_s = 4.0
duration_s = 8.0

[identification]
output = "velocity_mps"
coherence_threshold = 0.8
max_resonances = 1

[notch]
depth_db = 40.0
width_factor = 2.0
min_width_ratio = 0.3

[emulator]
seed = 3

[emulator.plant]
model = "two_mass"
m1 = 40.0
m2 = 10.0
k = 1.5e5
d = 40.0
c = 10.0

[emulator.friction]
model = "none"

[emulator.drive]
velocity_filter_hz = 400.0
torque_max_nm = 20.0

[emulator.sensors]
encoder_resolution_m = 1e-6
torque_noise_nm = 0.01
"""


# ---------------------------------------------------------------------- the plan (pure)


@dataclass(frozen=True)
class AxisPlan:
    """One axis of the fleet: its identity, plant and recording times.

    Attributes
    ----------
    axis, serial : str
        Axis id (``axis-01``) and the serial number its device reports.
    sample_rate_hz : float
        Sample rate of its recordings, Hz.
    m1, m2, k0 : float
        Cart and load mass (kg), stiffness on the first day (N/m, at 00:00 UTC of the start date).
    drifting : bool
        Whether its stiffness changes linearly in time.
    stiffness_percent_per_day : float
        That change, percent of ``k0`` per day (0 for a healthy axis).
    times : list of datetime
        Recording times (UTC), one a day.
    stiffness : list of float
        Stiffness at each recording, N/m.
    noise_seeds : list of int
        Seed of each recording's noise (its ``[emulator] seed``).
    """

    axis: str
    serial: str
    sample_rate_hz: float
    m1: float
    m2: float
    k0: float
    drifting: bool
    stiffness_percent_per_day: float
    times: list[_dt.datetime] = field(default_factory=list)
    stiffness: list[float] = field(default_factory=list)
    noise_seeds: list[int] = field(default_factory=list)


def axis_ids(n: int) -> list[str]:
    """``axis-01`` ... ``axis-NN``, zero-padded to the width of ``n`` (at least two digits)."""
    width = max(2, len(str(n)))
    return [f"{AXIS_PREFIX}{i:0{width}d}" for i in range(1, n + 1)]


def drifting_count(axes: int, share: float) -> int:
    """How many of ``axes`` drift: ``round(share * axes)``, at least one when ``axes >= 2`` and ``share > 0``."""
    n = int(round(share * axes))
    if share > 0 and axes >= 2:
        n = max(n, 1)
    return min(n, axes)


def days_since(start: _dt.date, when: _dt.datetime) -> float:
    """Time from 00:00 UTC of ``start`` to ``when``, days."""
    origin = _dt.datetime.combine(start, _dt.time(0, 0), tzinfo=_dt.UTC)
    return (when - origin).total_seconds() / 86400.0


def plan_fleet(
    base: Config,
    axes: int,
    days: int,
    seed: int,
    start: _dt.date = DEFAULT_START,
    drifting_share: float = 0.3,
    sample_rates_hz: tuple[float, ...] = SAMPLE_RATES_HZ,
) -> list[AxisPlan]:
    """Every axis of a fleet, deterministic given ``seed``.

    Parameters
    ----------
    base : Config
        The base configuration; its ``[emulator.plant]`` ``m1``, ``m2``, ``k`` are varied.
    axes, days : int
        Number of axes and of days (one recording per axis per day).
    seed : int
        Seed of everything random in the fleet.
    start : datetime.date
        The first day; day ``i`` is ``start + i`` days.
    drifting_share : float
        Share of the axes whose stiffness drifts (:func:`drifting_count`).
    sample_rates_hz : tuple of float
        Sample rates, Hz, given to the axes in turn.
    """
    p = base.emulator.plant
    root = np.random.SeedSequence(seed)
    choose_ss, *axis_ss = root.spawn(axes + 1)
    drifting = set(
        np.random.default_rng(choose_ss).choice(axes, drifting_count(axes, drifting_share), replace=False).tolist()
    )
    if not isinstance(p.k, float):
        raise ConfigError("emulator.plant.k", "a fleet needs k as a number, not a function of position", base.source)
    plans = []
    for i, (name, ss) in enumerate(zip(axis_ids(axes), axis_ss, strict=True)):
        rng = np.random.default_rng(ss)
        m1, m2, k0 = (v * (1.0 + float(rng.uniform(-PARAMETER_SPREAD, PARAMETER_SPREAD))) for v in (p.m1, p.m2, p.k))
        rate = float(rng.uniform(*DRIFT_PERCENT_PER_DAY)) if i in drifting else 0.0
        serial = f"HX{int(rng.integers(0, 16**6)):06X}-{i + 1:03d}"
        times, stiffness, seeds = [], [], []
        for day in range(days):
            night = _dt.datetime.combine(start + _dt.timedelta(days=day), NIGHTLY_UTC, tzinfo=_dt.UTC)
            when = night + _dt.timedelta(seconds=int(rng.integers(0, JITTER_S + 1)))
            wobble = float(rng.uniform(-HEALTHY_WOBBLE, HEALTHY_WOBBLE))
            t = days_since(start, when)
            k = k0 * (1.0 + rate / 100.0 * t) if i in drifting else k0 * (1.0 + wobble)
            times.append(when)
            stiffness.append(k)
            seeds.append(int(rng.integers(0, 2**32 - 1)))
        if min(stiffness) <= 0.0:
            raise UsageError(
                f"--days {days}: {name}'s stiffness would fall to zero at {rate:.2f} %/day; simulate fewer days"
            )
        plans.append(
            AxisPlan(
                name,
                serial,
                sample_rates_hz[i % len(sample_rates_hz)],
                m1,
                m2,
                k0,
                i in drifting,
                rate,
                times,
                stiffness,
                seeds,
            )
        )
    return plans


def truth_rate_percent_per_day(t_days, frequencies_hz) -> float:
    """The drift rate of a resonance, percent per day, as a batch estimates it.

    An ordinary least-squares line ``f(t) = a + b t`` through the frequencies
    (Hz) at the recording times ``t`` (days), and ``100 b / (a + b t_first)``:
    the slope relative to the line's value at the first recording.

    Examples
    --------
    >>> round(truth_rate_percent_per_day([0.0, 1.0, 2.0], [20.0, 19.8, 19.6]), 6)
    -1.0
    """
    t = np.asarray(t_days, dtype=float)
    f = np.asarray(frequencies_hz, dtype=float)
    if t.size < 2 or np.ptp(t) == 0.0:
        return math.nan
    b, a = np.polyfit(t, f, 1)
    return float(100.0 * b / (a + b * t.min()))


def damaged_count(recordings: int) -> int:
    """About :data:`DAMAGED_SHARE` of ``recordings``, at least :data:`MIN_DAMAGED` from 20 recordings on."""
    n = int(round(DAMAGED_SHARE * recordings))
    return max(n, MIN_DAMAGED) if recordings >= 20 else n


# ---------------------------------------------------------------------- configuration text


def _toml_key(key: str) -> str:
    """A bare TOML key where it may be one, else a quoted one."""
    return key if key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


def toml_text(tables: dict[str, Any]) -> str:
    """``tables`` (as :func:`tomllib.loads` returns them) as TOML text: scalars first, then one table each.

    A list of tables is written as an inline array of inline tables.
    """
    lines: list[str] = []

    def emit(prefix: str, table: dict[str, Any]) -> None:
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
        subtables = {k: v for k, v in table.items() if isinstance(v, dict)}
        if prefix and (scalars or not subtables):
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
        if scalars:
            lines.append("")
        for k, v in subtables.items():
            emit(f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k), v)

    emit("", tables)
    return "\n".join(lines).rstrip() + "\n"


def recording_config(
    base: dict[str, Any],
    plan: AxisPlan,
    day: int,
    amplitude_nm: float,
    duration_s: float,
    viscous_nm_per_mps: float | None,
) -> str:
    """The configuration stored in one recording: the base with this axis's rate, plant and noise seed that day."""
    raw = json.loads(json.dumps(base))  # a deep copy of plain data
    raw.setdefault("run", {})["sample_rate_hz"] = plan.sample_rate_hz
    raw.setdefault("friction_test", {})["enabled"] = False
    exc = raw.setdefault("excitation", {})
    exc.update(amplitude_nm=amplitude_nm, duration_s=duration_s)
    emu = raw.setdefault("emulator", {})
    emu["seed"] = plan.noise_seeds[day]
    emu.setdefault("plant", {}).update(m1=plan.m1, m2=plan.m2, k=plan.stiffness[day])
    if viscous_nm_per_mps is None:
        emu["friction"] = {"model": "none"}
    else:  # Stribeck without its Coulomb and static parts: viscous only
        emu["friction"] = {"model": "stribeck", "Fc": 0.0, "Fs": 0.0, "Fv": viscous_nm_per_mps, "delta_v": 1.0}
    when = plan.times[day].strftime("%Y-%m-%dT%H:%M:%SZ")
    return f"# hilident emulate fleet: {plan.axis} ({plan.serial}), the recording of {when}\n\n" + toml_text(raw)


def check_base(cfg: Config, sample_rates_hz: tuple[float, ...] = SAMPLE_RATES_HZ) -> None:
    """Refuse a base configuration the fleet cannot simulate at ``sample_rates_hz`` (Hz), naming the key."""
    p, e = cfg.emulator.plant, cfg.excitation
    if p.model != "two_mass":
        raise ConfigError("emulator.plant.model", f"a fleet simulates a two_mass plant, got {p.model!r}", cfg.source)
    if not isinstance(p.k, float) or not isinstance(p.d, float):
        raise ConfigError("emulator.plant.k", "a fleet needs k and d as numbers, not functions of position", cfg.source)
    if p.backlash_m:
        raise ConfigError("emulator.plant.backlash_m", "a fleet simulates a linear plant: set it to 0", cfg.source)
    if e.kind != "multisine" or e.mode != "torque":
        raise ConfigError(
            "excitation",
            f'a fleet plays a multisine in open-loop torque (kind = "multisine", '
            f'mode = "torque"), got kind {e.kind!r}, mode {e.mode!r}',
            cfg.source,
        )
    top = min(sample_rates_hz)
    if e.f_max_hz >= 0.4 * top:
        raise ConfigError(
            "excitation.f_max_hz",
            f"{e.f_max_hz:g} Hz: a fleet records at {top:g} Hz too, so it must stay below {0.4 * top:g} Hz",
            cfg.source,
        )


# ---------------------------------------------------------------------- physics


@dataclass(frozen=True)
class Recorded:
    """One simulated recording: its rows (columns in :data:`CHANNELS` order) and the excitation's period, samples."""

    rows: np.ndarray
    period_samples: int


def simulate(cfg: Config, amplitude_nm: float) -> Recorded:
    """One identification experiment of ``cfg``'s twin, simulated directly.

    The torque command is the excitation (N·m, one lead-in period and the
    whole periods of ``[excitation]``), held over each sample; the motor
    torque applied is that command plus an unmeasured coloured process
    torque (the ``[emulator]`` preset's level and corner); the measured
    torque adds ``[emulator.sensors] torque_noise_nm``. The plant state is
    sampled at each sample's start; the encoder position (with its
    interpolation noise) is floored to counts and the velocity is the drive's
    estimate: the backward difference of encoder positions through a
    first-order low-pass at ``[emulator.drive] velocity_filter_hz``. The
    drive's computation delay and current loop are left out: the motor torque
    is the command (a delay would only add phase, never move the mode).
    """
    from scipy.linalg import expm
    from scipy.signal import lfilter

    from hilident.emulator.device import friction_model, plant_model
    from hilident.emulator.plant import TwoMass, state_matrices
    from hilident.emulator.preset import realism
    from hilident.session.excitation import build_excitation

    fs = cfg.run.sample_rate_hz
    excitation = build_excitation(cfg, amplitude_nm)
    u = excitation.samples
    n = u.size
    ss = np.random.SeedSequence(cfg.emulator.seed)
    torque_rng, process_rng, encoder_rng = (np.random.default_rng(s) for s in ss.spawn(3))
    r = realism(cfg.emulator, fs)
    process = np.zeros(n)
    if r.torque_noise_nm:
        # first-order low-pass of white noise, scaled to the wanted rms
        a = math.exp(-2.0 * math.pi * r.torque_noise_corner_hz / fs)
        process = lfilter([math.sqrt(1.0 - a * a)], [1.0, -a], process_rng.standard_normal(n)) * r.torque_noise_nm

    model = plant_model(cfg.emulator)
    if not isinstance(model, TwoMass):  # check_base refused it already
        raise ConfigError("emulator.plant.model", "a fleet simulates a two_mass plant", cfg.source)
    A, B = state_matrices(model)
    friction = friction_model(cfg.emulator)
    if friction is not None:  # viscous only (check_base): a force c Fv v1 against the cart's motion
        A = A.copy()
        A[1, 1] -= model.c * friction.Fv / model.m1
    # exact zero-order-hold discretisation of x' = A x + B c tau
    M = np.zeros((5, 5))
    M[:4, :4] = A
    M[:4, 4] = B * model.c
    E = expm(M / fs)
    Ad, Bd = E[:4, :4], E[:4, 4]
    applied = u + process
    x = _state_response(Ad, Bd, applied)
    p1, v1 = x[:, 0], x[:, 1]
    del v1  # the drive does not see the true velocity

    res = cfg.emulator.sensors.encoder_resolution_m
    encoder = p1 + r.encoder_noise_m * encoder_rng.standard_normal(n) if r.encoder_noise_m else p1
    position = np.floor(encoder / res) * res if res else encoder
    alpha = -math.expm1(-2.0 * math.pi * cfg.emulator.drive.velocity_filter_hz / fs)
    difference = np.diff(position, prepend=position[0]) * fs
    velocity = lfilter([alpha], [1.0, alpha - 1.0], difference)
    torque = u + cfg.emulator.sensors.torque_noise_nm * torque_rng.standard_normal(n)
    index = np.arange(n, dtype=float)
    rows = np.column_stack([index, index / fs, u, torque, position, velocity])
    return Recorded(rows, excitation.period)


def _state_response(Ad: np.ndarray, Bd: np.ndarray, u: np.ndarray) -> np.ndarray:
    """States ``x[i]`` (at each sample's start, ``x[0] = 0``) of ``x[i+1] = Ad x[i] + Bd u[i]``.

    One :func:`scipy.signal.lfilter` per state (in C, about 20x faster than a
    Python loop); it agrees with the loop to about 1e-6 of the state's range,
    far below an encoder count.
    """
    from scipy.signal import lfilter

    n = u.size
    # Cayley-Hamilton: every state obeys the recursion of Ad's characteristic polynomial, so each state is
    # a linear filter of u (denominator: that polynomial; numerator: it times the impulse response Ad^(i-1) Bd).
    coeffs = np.poly(Ad)
    out = np.empty((n, 4))
    h = np.zeros((5, 4))
    power = np.eye(4)
    for i in range(1, 5):
        h[i] = power @ Bd
        power = Ad @ power
    for s in range(4):
        b = np.convolve(coeffs, h[:, s])[:5]
        out[:, s] = lfilter(b, coeffs, u)
    return out


# ---------------------------------------------------------------------- files


def _write_recording(
    path: Path,
    rec: Recorded,
    cfg_text: str,
    base_source: str,
    plan: AxisPlan,
    day: int,
    seed: int,
    versions: dict,
    rows: int | None = None,
) -> None:
    from hilident.io.recording import RunWriter

    attrs = {
        "experiment": "identification",
        "mode": "torque",
        "seed": seed,
        "config_toml": cfg_text,
        "config_source": f"{base_source} (hilident emulate fleet, {plan.axis})",
        "versions": versions,
        "device": {
            "name": "myrio-board",
            "firmware": "hilident-board 1.0 (fleet twin)",
            "port": "emulator",
            "serial": plan.serial,
        },
        "period_samples": rec.period_samples,
        "axis": plan.axis,
    }
    data = rec.rows if rows is None else rec.rows[:rows]
    started = plan.times[day]
    writer = RunWriter(
        path, list(CHANNELS), list(UNITS), plan.sample_rate_hz, attrs, overwrite=True, created_utc=started
    )
    try:
        writer.append(data)
        writer.event("finished", "fleet recording complete", sample_index=len(data))
    except BaseException as exc:
        writer.close("aborted", str(exc) or type(exc).__name__)
        raise
    # the simulated end, so that the same arguments write the same bytes
    writer.close(closed_utc=started + _dt.timedelta(seconds=len(data) / plan.sample_rate_hz))


def damage_file(path: Path, kind: str, rng: np.random.Generator) -> None:
    """Damage a recording on disk as ``kind`` (one of :data:`DAMAGE_KINDS`).

    ``truncated``: cut to 30-70 % of its bytes; ``header``: 64 bytes of the
    superblock after its signature overwritten with random bytes; ``empty``:
    no bytes; ``running``: a crashed writer's file, ``status = "running"``,
    without ``n_samples`` and ``closed_utc`` (the caller writes it with only
    :data:`CRASHED_ROWS` rows).
    """
    if kind == "truncated":
        size = path.stat().st_size
        with open(path, "r+b") as f:
            f.truncate(int(size * rng.uniform(0.3, 0.7)))
    elif kind == "header":
        with open(path, "r+b") as f:
            junk = rng.integers(0, 256, 64, dtype=np.uint8)
            junk[0] = 0xFF  # the superblock version: no HDF5 version has it
            f.seek(8)
            f.write(junk.tobytes())
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "running":
        import h5py

        with h5py.File(path, "r+") as f:
            f.attrs["status"] = "running"
            for key in ("n_samples", "closed_utc"):
                if key in f.attrs:
                    del f.attrs[key]
    else:
        raise ValueError(f"unknown damage {kind!r}; one of {DAMAGE_KINDS}")


@dataclass
class FleetResult:
    """What :func:`write_fleet` wrote."""

    out: Path
    recordings: int
    damaged: int
    drifting: int
    total_bytes: int
    truth: dict


def _amplitude(cfg: Config) -> float:
    e = cfg.excitation
    if e.amplitude_auto:
        from hilident.config.tables import amplitude_ceiling_nm

        return AUTO_AMPLITUDE_SHARE * (amplitude_ceiling_nm(cfg) or 1.0)
    return float(e.amplitude)


def _fleet_folder(out: Path, overwrite: bool) -> Path:
    """``out`` created, or emptied of an earlier fleet's files with ``overwrite``; refused when it holds files."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: is a file, not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise UsageError(f"--out {out}: holds files already; pass --overwrite to replace an earlier fleet there")
        # only what a fleet writes: its recordings, fleet.json, and axis folders left empty
        for old in out.glob(f"{AXIS_PREFIX}*/{AXIS_PREFIX}*_*Z.h5"):
            old.unlink()
        for folder in out.glob(f"{AXIS_PREFIX}*"):
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        (out / "fleet.json").unlink(missing_ok=True)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"--out {out}: cannot create the folder: {exc}") from None
    return out


@dataclass(frozen=True)
class _RecordingRecipe:
    """What every recording of a fleet shares.

    Attributes
    ----------
    base_raw : dict
        The base configuration's tables, without ``[data]``.
    base_source : str
        Where the base configuration came from.
    run_seed : int
        The base's ``[run] seed``, stored in each recording.
    amplitude_nm : float
        Peak of the excitation, N·m.
    duration_s : float
        Analysed length of each recording, s.
    viscous_fv : float or None
        The cart's viscous friction ``Fv`` kept from the base; None: no friction.
    versions : dict
        Package versions stored in each recording.
    """

    base_raw: dict[str, Any]
    base_source: str
    run_seed: int
    amplitude_nm: float
    duration_s: float
    viscous_fv: float | None
    versions: dict


@dataclass
class _FleetTally:
    """What has been written so far: recordings done of ``total``, their bytes, and the damaged files."""

    total: int
    progress: Callable[[float], None] | None
    done: int = 0
    total_bytes: int = 0
    damaged: list[dict[str, str]] = field(default_factory=list)

    def count(self, path: Path) -> None:
        """One more recording written at ``path``: its bytes counted, the progress told."""
        self.total_bytes += path.stat().st_size
        self.done += 1
        if self.progress is not None:
            self.progress(self.done / self.total)


def write_fleet(
    out: str | os.PathLike,
    axes: int,
    days: int,
    *,
    seed: int = 1,
    base: Config | None = None,
    start: _dt.date = DEFAULT_START,
    duration_s: float | None = None,
    drifting_share: float = 0.3,
    sample_rates_hz: tuple[float, ...] = SAMPLE_RATES_HZ,
    damaged: int | None = None,
    viscous: bool = False,
    overwrite: bool = False,
    progress: Callable[[float], None] | None = None,
    say: Callable[[str], None] | None = None,
) -> FleetResult:
    """Write a fleet's recordings and ``fleet.json`` into ``out``.

    Parameters
    ----------
    out : path
        The fleet folder: ``fleet.json`` and one folder per axis.
    axes, days : int
        Axes, and days of one nightly recording each.
    seed : int
        Seed of everything random; the same arguments write the same bytes.
    base : Config, optional
        The base configuration (default :data:`BASE_TOML`).
    start : datetime.date
        The first day.
    duration_s : float, optional
        Analysed length of each recording, s, in whole excitation periods
        (default: the base's ``[excitation] duration_s``); one lead-in period more is recorded.
    drifting_share : float
        Share of drifting axes (0..1).
    sample_rates_hz : tuple of float
        Sample rates, Hz, given to the axes in turn (default :data:`SAMPLE_RATES_HZ`); each must divide
        into whole excitation periods as the base's own rate does.
    damaged : int, optional
        Number of damaged recordings (default :func:`damaged_count`).
    viscous : bool
        Keep the base's viscous friction ``Fv`` (its Coulomb and static parts are dropped); default no friction.
    overwrite : bool
        Write into an ``out`` that holds files: an earlier fleet's recordings and ``fleet.json`` are removed
        first (nothing else is). Without it such a folder is refused.
    progress : callable, optional
        Called with the fraction done.
    say : callable, optional
        Called with a line saying what is written, once the arguments are checked.
    """
    from hilident.session.experiment import package_versions

    base = base if base is not None else parse_config(BASE_TOML, "hilident.batch.fleet.BASE_TOML")
    check_base(base, tuple(sample_rates_hz))
    _check_fleet_arguments(axes, days, seed, drifting_share)
    duration = _checked_duration(base, duration_s)
    base_raw = _base_tables(base)
    amplitude = _amplitude(base)
    viscous_fv = _viscous_fv(base, viscous)
    _check_sample_rates(base, sample_rates_hz)
    plans = plan_fleet(base, axes, days, seed, start, drifting_share, tuple(sample_rates_hz))
    total = axes * days
    n_damaged = _checked_damaged_count(damaged, total)
    damage_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1 << 20,)))
    damage_of = _damage_plan(damage_rng, total, n_damaged)

    drifting = sum(p.drifting for p in plans)
    out = _fleet_folder(Path(out), overwrite)
    if say is not None:
        say(
            f"writing a fleet of {axes} axes x {days} days ({total} recordings, "
            f"{drifting} drifting axes, {n_damaged} damaged files) into {out}"
        )
    source = base.source or "hilident.batch.fleet.BASE_TOML"
    recipe = _RecordingRecipe(base_raw, source, base.run.seed, amplitude, duration, viscous_fv, package_versions())
    tally = _FleetTally(total, progress)
    truth_axes = []
    for a, plan in enumerate(plans):
        kinds = [damage_of.get(a * days + day) for day in range(days)]
        truth_axes.append(_write_axis(out, plan, kinds, recipe, damage_rng, tally, start))
    truth = {
        "format": FLEET_FORMAT,
        "version": FLEET_VERSION,
        "start": start.isoformat(),
        "days": days,
        "seed": seed,
        "base_config": source,
        "duration_s": duration,
        "amplitude_nm": amplitude,
        "friction": "viscous" if viscous_fv is not None else "none",
        "axes": truth_axes,
        "damaged": tally.damaged,
    }
    (out / "fleet.json").write_text(json.dumps(truth, indent=1) + "\n")
    return FleetResult(out, total, len(tally.damaged), drifting, tally.total_bytes, truth)


def _check_fleet_arguments(axes: int, days: int, seed: int, drifting_share: float) -> None:
    """Refuse a fleet of no axis or no day, a seed out of range or a drifting share outside 0..1."""
    if axes < 1 or days < 1:
        raise UsageError(f"--axes {axes} --days {days}: both must be at least 1")
    if not 0 <= seed < 2**63:
        raise UsageError(f"--seed {seed}: must be a non-negative integer")
    if not 0.0 <= drifting_share <= 1.0:
        raise UsageError(f"--drifting-share {drifting_share:g}: must be between 0 and 1")


def _base_tables(base: Config) -> dict[str, Any]:
    """The base configuration's tables as parsed from its text (none without text), its ``[data]`` dropped."""
    base_raw = parse_toml(base.text, base.source) if base.text else {}
    base_raw.pop("data", None)
    return base_raw


def _viscous_fv(base: Config, viscous: bool) -> float | None:
    """The base's viscous friction ``Fv`` when kept (``viscous`` and the base has friction), else None."""
    return base.emulator.friction.Fv if viscous and base.emulator.friction.model != "none" else None


def _checked_duration(base: Config, duration_s: float | None) -> float:
    """Analysed length of each recording, s (None: the base's); refused under half a period or over the limit."""
    period = base.excitation.period_s
    duration = base.excitation.duration_s if duration_s is None else duration_s
    if not (math.isfinite(duration) and period * 0.5 <= duration <= MAX_DURATION_S):
        raise UsageError(
            f"--duration-s {duration:g}: must be at least one excitation period ({period:g} s) and at "
            f"most {MAX_DURATION_S:g} s"
        )
    return duration


def _check_sample_rates(base: Config, sample_rates_hz: tuple[float, ...]) -> None:
    """Refuse a sample rate, Hz, that is not positive or does not give whole excitation periods."""
    for rate in sample_rates_hz:
        if not (math.isfinite(rate) and rate > 0 and float(base.excitation.period_s * rate).is_integer()):
            raise UsageError(
                f"--sample-rate-hz {rate:g}: must be positive and give whole excitation periods "
                f"({base.excitation.period_s:g} s)"
            )


def _checked_damaged_count(damaged: int | None, total: int) -> int:
    """Number of damaged recordings among ``total`` (None: :func:`damaged_count`), refused outside 0..total."""
    n_damaged = damaged_count(total) if damaged is None else damaged
    if not 0 <= n_damaged <= total:
        raise UsageError(f"--damaged {n_damaged}: must be between 0 and the {total} recordings")
    return n_damaged


def _damage_plan(damage_rng: np.random.Generator, total: int, n_damaged: int) -> dict[int, str]:
    """The damage of each damaged recording by its index (axis by axis, day by day): the kinds taken in turn."""
    picked = sorted(damage_rng.choice(total, n_damaged, replace=False).tolist())
    offset = int(damage_rng.integers(len(DAMAGE_KINDS)))
    return {r: DAMAGE_KINDS[(offset + j) % len(DAMAGE_KINDS)] for j, r in enumerate(picked)}


def _write_axis(
    out: Path,
    plan: AxisPlan,
    kinds: list[str | None],
    recipe: _RecordingRecipe,
    damage_rng: np.random.Generator,
    tally: _FleetTally,
    start: _dt.date,
) -> dict[str, Any]:
    """Write one axis's recordings into its folder, damaging those ``kinds`` names; return its truth.

    ``kinds`` holds the damage of each day's recording (None: intact).
    """
    folder = out / plan.axis
    folder.mkdir(exist_ok=True)
    files, frequencies, damping, intact = [], [], [], []
    for day, kind in enumerate(kinds):
        path, f_hz, zeta = _write_day(folder, plan, day, recipe, kind, damage_rng)
        rel = f"{plan.axis}/{path.name}"
        if kind is not None:
            tally.damaged.append({"path": rel, "damage": kind})
        else:
            intact.append(day)
        tally.count(path)
        files.append(rel)
        frequencies.append(f_hz)
        damping.append(zeta)
    t = [days_since(start, plan.times[d]) for d in intact]
    f_rate = truth_rate_percent_per_day(t, [frequencies[d] for d in intact])
    return {
        "axis": plan.axis,
        "serial": plan.serial,
        "sample_rate_hz": plan.sample_rate_hz,
        "drifting": plan.drifting,
        "stiffness_percent_per_day": plan.stiffness_percent_per_day,
        "frequency_percent_per_day": None if math.isnan(f_rate) else f_rate,
        "m1": plan.m1,
        "m2": plan.m2,
        "k0": plan.k0,
        "times_utc": [w.isoformat() for w in plan.times],
        "days": [days_since(start, w) for w in plan.times],
        "stiffness": plan.stiffness,
        "frequencies_hz": frequencies,
        "damping_ratios": damping,
        "files": files,
    }


def _write_day(
    folder: Path,
    plan: AxisPlan,
    day: int,
    recipe: _RecordingRecipe,
    kind: str | None,
    damage_rng: np.random.Generator,
) -> tuple[Path, float, float]:
    """Simulate and write one axis's recording of ``day``, damaged as ``kind`` (None: intact).

    Returns
    -------
    path : pathlib.Path
        The recording written.
    frequency_hz, damping_ratio : float
        The twin's true first mode that day, Hz and 1.
    """
    from hilident.emulator.device import true_modes

    text = recording_config(recipe.base_raw, plan, day, recipe.amplitude_nm, recipe.duration_s, recipe.viscous_fv)
    cfg = parse_config(text, f"{plan.axis} day {day + 1}")
    rec = simulate(cfg, recipe.amplitude_nm)
    f_hz, zeta = true_modes(cfg.emulator)[0]
    path = folder / f"{plan.axis}_{plan.times[day].strftime('%Y%m%dT%H%M%SZ')}.h5"
    # a crashed writer's file: fewer rows than identify accepts at all (and far fewer than a period)
    rows = CRASHED_ROWS if kind == "running" else None
    _write_recording(path, rec, text, recipe.base_source, plan, day, recipe.run_seed, recipe.versions, rows)
    if kind is not None:
        damage_file(path, kind, damage_rng)
    return path, f_hz, zeta
