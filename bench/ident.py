"""Speed and memory of the identification pipeline on a long record.

Run by hand, never by the test suite::

    python bench/ident.py                        # 10^6 samples at 1 kHz, a few minutes
    python bench/ident.py --sippy-samples 100000 # sippy-unipi on the first 10^5 samples only
    python bench/ident.py --profile              # plus a cProfile of one pipeline run

The record
----------
The two-mass gantry (m1 = 40 kg, m2 = 10 kg, k = 1.5e5 N/m, d = 40 N·s/m,
c = 10 N/(N·m)) with Stribeck friction (Fc = 0.2, Fs = 0.35 N·m, Fv = 2
N·m/(m/s), vs = 0.005 m/s) is simulated with the emulator's physics:
:func:`hilident.emulator.factory.build_drive` on a configuration parsed with
:func:`hilident.config.tables.parse_config`, the drive loop at the record's sample rate,
in ``torque`` mode (loops open). The plant is integrated exactly between
samples (matrix exponential, zero-order hold, four substeps per sample) with
Karnopp stiction; the drive reports the measured torque (white noise of
0.02 N·m rms) and its velocity estimate from a 1 µm encoder. The torque is
band-limited noise (4th-order Butterworth band-pass 0.5-200 Hz, 2 N·m rms).
The Stribeck fit the pipeline uses comes from a friction test on the same
emulator (velocity mode, 20 constant speeds of 1 mm/s to 0.2 m/s each way,
exponents held at 1 and 2). Generating the data is not part of any timing.

What is measured
----------------
1. The pipeline, stage by stage (best and mean of ``--repeats`` runs after one
   warm-up): signal checks, friction compensation, zero-phase low-pass,
   detrend, H1 with coherence (Welch), resonances, a transfer-function fit over
   the band, notch design. For reference also
   :func:`hilident.pipeline.plant.identify_plant`, the library's own composition
   (it computes two FRFs from three signals).
2. hilident's :func:`~hilident.ident.frequency.h1_estimate` against the same
   H1 built from ``scipy.signal.welch``/``csd``/``coherence``: time ratio and
   largest difference where the coherence exceeds 0.9.
3. ARX order search: :func:`~hilident.ident.arx.arx_order_search` (one QR
   factor of the largest structure, target <= 0.3 s on 10^6 samples) against
   the per-candidate method it replaced (kept here, with a check that every
   candidate's parameters agree to 1e-10 and the choice is the same) and
   against ``sippy_unipi.system_identification(..., "ARX", IC="AIC")`` (PyPI
   ``sippy-unipi``, not a hilident dependency; skipped when not installed).
4. Peak memory of one pipeline run in a fresh process: tracemalloc peak per
   stage and overall, and the growth of the peak resident set (VmHWM, reset
   before the run; ru_maxrss is printed too, but a spawned process inherits
   its parent's ru_maxrss over exec), against the size of the input.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import dataclasses
import gc
import io
import multiprocessing as mp
import os
import platform
import pstats
import resource
import sys
import tempfile
import time
import tracemalloc
from dataclasses import dataclass
from itertools import product

import numpy as np
import scipy
from scipy import signal

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.config.tables import IdentificationConfig, NotchConfig, parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.drive import DriveLoop
from hilident.emulator.factory import build_drive, true_modes
from hilident.errors import DataError
from hilident.ident import arx
from hilident.ident import friction as fr
from hilident.ident.arx import arx_order_search, fit_arx
from hilident.ident.frequency import h1_estimate
from hilident.ident.preprocess import check_signals, detrend, lowpass
from hilident.ident.resonance import find_resonances
from hilident.ident.tffit import fit_transfer_function, modal_form
from hilident.pipeline.notches import design_notches
from hilident.pipeline.plant import identify_plant

TIME_TARGET_S = 1.0
ARX_TARGET_S = 0.3  # the order search below on 10^6 samples
MEMORY_TARGET = 10.0  # peak memory over the input's size
COHERENCE_GATE = 0.9

_CONFIG = """\
[emulator]
seed = {seed}

[emulator.plant]
model = "two_mass"
m1 = 40.0
m2 = 10.0
k = 1.5e5
d = 40.0
c = 10.0

[emulator.friction]
model = "stribeck"
Fc = 0.2
Fs = 0.35
Fv = 2.0
vs = 0.005

[emulator.sensors]
torque_noise_nm = 0.02
encoder_resolution_m = 1e-6

[identification]
segment_s = 4.0
lowpass_hz = 250.0
coherence_threshold = 0.8
min_prominence_db = 6.0
max_resonances = 2

[notch]
depth_db = 30.0
"""
_EXCITATION_RMS_NM = 2.0
_EXCITATION_BAND_HZ = (0.5, 200.0)
_FIT_BAND_HZ = (2.0, 150.0)
_TF_ORDERS = (2, 2)  # numerator, denominator besides the rigid-body integrator
_FILTER_RATE_HZ = 4000.0
_SLOTS = [0, 1]


# --- the record -----------------------------------------------------------------------------


@dataclass
class Record:
    """What a run on the bench hands the identification."""

    sample_rate_hz: float
    excitation: np.ndarray  # torque command, N·m
    torque: np.ndarray  # measured torque, N·m
    velocity: np.ndarray  # drive's velocity estimate, m/s (also the FRF output)

    @property
    def n(self) -> int:
        return self.torque.size


@dataclass
class Setup:
    """Everything the pipeline needs besides the record."""

    sample_rate_hz: float
    ident: IdentificationConfig
    notch: NotchConfig
    friction: fr.StribeckParams
    band_hz: tuple[float, float] = _FIT_BAND_HZ
    tf_orders: tuple[int, int] = _TF_ORDERS
    filter_rate_hz: float = _FILTER_RATE_HZ


def _drive(cfg, sample_rate_hz: float) -> DriveLoop:
    driver = dataclasses.replace(find_driver("myrio-board"), loop_rate_hz=float(sample_rate_hz))
    return build_drive(cfg.emulator, driver)


def friction_test(cfg, sample_rate_hz: float) -> fr.FrictionFit:
    """Constant-speed test on the emulator and a Stribeck fit with exponents 1 and 2."""
    drive = _drive(cfg, sample_rate_hz)
    drive.set_mode("velocity")
    drive.enable()
    speeds = np.geomspace(0.001, 0.2, 10)
    speeds = np.concatenate([speeds, -speeds])
    hold = int(round(2.0 * sample_rate_hz))
    rows = drive.run(np.repeat(speeds, hold))
    v = rows[:, DriveLoop.CHANNELS.index("velocity_mps")]
    tau = rows[:, DriveLoop.CHANNELS.index("torque_nm")]
    windows = [(i * hold + hold // 2, (i + 1) * hold, s) for i, s in enumerate(speeds)]
    # At a few mm/s the velocity estimate jumps by whole encoder counts per sample:
    # a larger relative std than the default still means a steady window.
    points = fr.steady_state_points(v, tau, windows, max_relative_std=0.5)
    return fr.fit_stribeck(points.v_mean, points.tau_mean, fix_delta_v=1.0, fix_delta_s=2.0)


def make_record(cfg, n: int, sample_rate_hz: float, seed: int) -> Record:
    """Open-loop record: band-limited noise torque into the emulated drive."""
    rng = np.random.default_rng(seed)
    sos = signal.butter(4, _EXCITATION_BAND_HZ, btype="bandpass", fs=sample_rate_hz, output="sos")
    settle = int(sample_rate_hz)
    e = signal.sosfilt(sos, rng.standard_normal(n + settle))[settle:]
    e *= _EXCITATION_RMS_NM / e.std()
    drive = _drive(cfg, sample_rate_hz)
    drive.set_mode("torque")
    drive.enable()
    rows = drive.run(e)
    if drive.fault:
        raise RuntimeError(f"the emulated drive tripped: {drive.fault}")
    col = DriveLoop.CHANNELS.index
    return Record(
        sample_rate_hz,
        np.ascontiguousarray(rows[:, col("excitation")]),
        np.ascontiguousarray(rows[:, col("torque_nm")]),
        np.ascontiguousarray(rows[:, col("velocity_mps")]),
    )


# --- the pipeline ---------------------------------------------------------------------------------

STAGES = (
    "check_signals",
    "friction compensation",
    "low-pass (zero-phase)",
    "detrend",
    "H1 + coherence",
    "resonances",
    "transfer-function fit",
    "notch design",
)


@dataclass
class PipelineResult:
    u: np.ndarray
    y: np.ndarray
    frf: object
    resonances: list
    tf: object
    notches: list


def run_pipeline(rec: Record, s: Setup, on_stage=None) -> tuple[PipelineResult, dict[str, float]]:
    """The identification steps in order; returns the result and seconds per stage.

    ``on_stage(name)`` is called after each stage (outside its timing).
    """
    times: dict[str, float] = {}
    fs, cfg = s.sample_rate_hz, s.ident
    t = time.perf_counter()

    def lap(name):
        nonlocal t
        times[name] = time.perf_counter() - t
        if on_stage is not None:
            on_stage(name)
        t = time.perf_counter()

    sig = check_signals({"torque": rec.torque, "velocity": rec.velocity})
    lap(STAGES[0])
    u = fr.compensate(sig["torque"], sig["velocity"], s.friction)
    lap(STAGES[1])
    u = lowpass(u, cfg.lowpass_hz, fs)
    y = lowpass(sig["velocity"], cfg.lowpass_hz, fs)
    del sig
    lap(STAGES[2])
    u, y = detrend(u, "linear"), detrend(y, "linear")
    lap(STAGES[3])
    frf = h1_estimate(u, y, fs, int(round(cfg.segment_s * fs)))
    lap(STAGES[4])
    resonances = find_resonances(
        frf,
        coherence_threshold=cfg.coherence_threshold,
        min_prominence_db=cfg.min_prominence_db,
        max_count=cfg.max_resonances,
        band_hz=s.band_hz,
    )
    lap(STAGES[5])
    # Rigid-body pole fixed at 0; the velocity estimate lags the applied torque by about
    # one sample (zero-order hold plus backward difference), taken as a known delay.
    tf = fit_transfer_function(
        frf, *s.tf_orders, weights="coherence", integrators=1, delay_s=1.0 / fs, band_hz=s.band_hz
    )
    lap(STAGES[6])
    notches = design_notches(resonances, s.notch, s.filter_rate_hz, _SLOTS)
    lap(STAGES[7])
    return PipelineResult(u, y, frf, resonances, tf, notches), times


def run_identify_plant(rec: Record, s: Setup):
    return identify_plant(
        rec.excitation,
        rec.torque,
        rec.velocity,
        rec.velocity,
        s.sample_rate_hz,
        s.ident,
        s.band_hz,
        friction=s.friction,
    )


# --- helpers ------------------------------------------------------------------------------------


def _best_mean(samples: list[float]) -> tuple[float, float]:
    return min(samples), float(np.mean(samples))


def _timeit(fn, repeats: int, warmup: bool = True) -> list[float]:
    if warmup:
        fn()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def _mb(nbytes: float) -> str:
    return f"{nbytes / 2**20:7.1f} MB"


def _machine() -> str:
    model = platform.processor() or "?"
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return (
        f"{model}, {os.cpu_count()} cores; Python {platform.python_version()}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}"
    )


# --- 1. pipeline time -------------------------------------------------------------------------


def bench_pipeline(rec: Record, s: Setup, repeats: int, cfg) -> PipelineResult:
    print(
        f"\n1. pipeline on {rec.n:,} samples ({rec.n / rec.sample_rate_hz:g} s at "
        f"{rec.sample_rate_hz:g} Hz); best and mean of {repeats} runs after one warm-up"
    )
    result, _ = run_pipeline(rec, s)
    per_stage: dict[str, list[float]] = {name: [] for name in STAGES}
    totals = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result, times = run_pipeline(rec, s)
        totals.append(time.perf_counter() - t0)
        for name, dt in times.items():
            per_stage[name].append(dt)
    print(f"   {'stage':<24} {'best ms':>9} {'mean ms':>9} {'share':>6}")
    mean_total = float(np.mean(totals))
    for name in STAGES:
        best, mean = _best_mean(per_stage[name])
        print(f"   {name:<24} {1e3 * best:9.1f} {1e3 * mean:9.1f} {mean / mean_total:6.1%}")
    best, mean = _best_mean(totals)
    verdict = "met" if best < TIME_TARGET_S else "NOT met"
    print(f"   {'total':<24} {1e3 * best:9.1f} {1e3 * mean:9.1f}   (target < {TIME_TARGET_S:g} s: {verdict})")

    lib = _timeit(lambda: run_identify_plant(rec, s), repeats)
    best, mean = _best_mean(lib)
    print("   reference: identify_plant (check, compensate, low-pass and detrend of 3 signals,")
    print(f"   frf_from_reference + h1_estimate, resonances) {1e3 * best:.1f} ms best, {1e3 * mean:.1f} ms mean")
    _print_outcome(result, s, cfg)
    return result


def _print_outcome(result: PipelineResult, s: Setup, cfg) -> None:
    """What the pipeline found, next to the emulator's true plant."""
    ((f_true, z_true),) = true_modes(cfg.emulator)
    frf = result.frf
    print(f"   FRF: {len(frf)} lines at {frf.frequency_hz[1]:g} Hz, {frf.n_averages} averages")
    for r in result.resonances:
        print(
            f"   resonance {r.frequency_hz:.3f} Hz, zeta {r.damping_ratio:.4f} ({r.method}); "
            f"true {f_true:.3f} Hz, zeta {z_true:.4f}"
        )
    model = modal_form(result.tf)
    p = cfg.emulator.plant
    print(
        f"   transfer function {result.tf.n_num}/{result.tf.n_den} + integrator, delay "
        f"{1e3 * result.tf.delay_s:g} ms, {result.tf.n_bins} bins {s.band_hz[0]:g}-{s.band_hz[1]:g} Hz: "
        f"{result.tf.fit_db_rms:.2f} dB rms, {result.tf.phase_rms_deg:.1f} deg rms"
    )
    print(
        f"     gain {model.gain:.4f} (true c/(m1+m2) = {p.c / (p.m1 + p.m2):.4f}), resonances "
        + ", ".join(f"{f:.3f} Hz/{z:.4f}" for f, z in model.resonances)
        + ", antiresonances "
        + ", ".join(f"{f:.3f} Hz/{z:.4f}" for f, z in model.antiresonances)
        + f" (true {np.sqrt(p.k / p.m2) / (2 * np.pi):.3f} Hz/{p.d / (2 * np.sqrt(p.k * p.m2)):.4f})"
    )
    for d in result.notches:
        print(
            f"   notch slot {d.slot}: {d.spec.center_hz:.3f} Hz, width {d.spec.width_hz:.3f} Hz, "
            f"depth {d.spec.depth_db:g} dB at {d.sample_rate_hz:g} Hz"
        )


# --- 2. H1 against scipy --------------------------------------------------------------------------


def bench_h1(result: PipelineResult, s: Setup, repeats: int) -> None:
    u, y, fs = result.u, result.y, s.sample_rate_hz
    seg = int(round(s.ident.segment_s * fs))
    kw = dict(fs=fs, window="hann", nperseg=seg, noverlap=seg // 2, detrend="constant")

    def usual():
        f, puu = signal.welch(u, **kw)
        _, puy = signal.csd(u, y, **kw)
        _, coh = signal.coherence(u, y, **kw)
        return f, puy / puu, coh

    def lean():
        f, puu = signal.welch(u, **kw)
        _, pyy = signal.welch(y, **kw)
        _, puy = signal.csd(u, y, **kw)
        return f, puy / puu, np.abs(puy) ** 2 / (puu * pyy)

    print(
        f"\n2. H1 + coherence of the preprocessed torque and velocity ({u.size:,} samples, segments of "
        f"{seg}, 50 % overlap, Hann), best of {repeats}"
    )
    t_h = min(_timeit(lambda: h1_estimate(u, y, fs, seg), repeats))
    t_u = min(_timeit(usual, repeats))
    t_l = min(_timeit(lean, repeats))
    print(f"   hilident h1_estimate                              {1e3 * t_h:8.1f} ms")
    print(
        f"   scipy welch + csd + coherence (5 Welch passes)    {1e3 * t_u:8.1f} ms   "
        f"ratio scipy/hilident {t_u / t_h:.2f}"
    )
    print(
        f"   scipy welch(u) + welch(y) + csd (3 Welch passes)  {1e3 * t_l:8.1f} ms   "
        f"ratio scipy/hilident {t_l / t_h:.2f}"
    )
    ours = h1_estimate(u, y, fs, seg)
    f, h, coh = usual()
    if not np.allclose(f, ours.frequency_hz):
        print("   frequency grids differ: no comparison")
        return
    mask = (ours.coherence > COHERENCE_GATE) & (f > 0)
    with np.errstate(divide="ignore"):
        d_db = np.abs(20 * np.log10(np.abs(ours.response[mask]) / np.abs(h[mask])))
    d_deg = np.abs(np.degrees(np.angle(ours.response[mask] / h[mask])))
    print(
        f"   where coherence > {COHERENCE_GATE:g} ({mask.sum()} of {mask.size} lines): max |H| difference "
        f"{d_db.max():.2e} dB, max phase difference {d_deg.max():.2e} deg, max coherence difference "
        f"{np.abs(ours.coherence - coh)[mask].max():.2e}"
    )


# --- 3. ARX order search ---------------------------------------------------------------------------


def _search_per_candidate(u: np.ndarray, y: np.ndarray, nas, nbs, nks):
    """The order search as it was before the shared factor: one QR of each candidate's own columns.

    The regressor of the largest structure is built once; every candidate's
    columns are copied out of it and solved by ``hilident.ident.arx._solve``
    (the solver ``fit_arx`` uses), undetermined ones marked as the search marks
    them; the chosen model is refitted with ``fit_arx``. Kept here as the
    reference the fast search is timed and checked against.

    Returns
    -------
    rows : list of OrderCandidate
    params : list of ndarray or None
        Each candidate's parameters on the common rows (None: undetermined).
    model : ArxModel
        The chosen candidate refitted on its own record.
    """
    grid = [(na, nb, nk) for na, nb, nk in product(nas, nbs, nks) if na + nb]
    max_na, max_u_lag = max(nas), max(nk + nb - 1 for nk in nks for nb in nbs)
    n0 = max(max_na, max_u_lag, 0)
    full = arx._regressors(u, y, range(1, max_na + 1), range(0, max_u_lag + 1), n0)
    n_rows, energy = full.shape[0], float(full[:, -1] @ full[:, -1])
    rows, params = [], []
    for na, nb, nk in grid:
        cols = list(range(na)) + [max_na + j for j in range(nk, nk + nb)] + [full.shape[1] - 1]
        p = na + nb
        try:
            model = arx._solve(full[:, cols], na, nb, nk)
        except DataError:
            nan = float("nan")
            rows.append(arx.OrderCandidate(na, nb, nk, p, nan, np.inf, np.inf, nan, -np.inf))
            params.append(None)
            continue
        rss = max(2.0 * model.V, arx._RSS_FLOOR * energy, np.finfo(float).tiny)
        base = n_rows * np.log(rss / n_rows)
        rows.append(
            arx.OrderCandidate(
                na, nb, nk, p, model.V, float(base + 2 * p), float(base + p * np.log(n_rows)), model.fit_percent, np.nan
            )
        )
        params.append(model.params)
    c = rows[arx._smallest_adequate(rows, "aic", 2.0)]
    return rows, params, fit_arx(u, y, c.na, c.nb, c.nk)


def _largest_relative(a, b) -> float:
    """Largest ``|a - b| / |b|`` over the finite entries (0 when there are none)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(b) & (b != 0)
    return float(np.max(np.abs(a[ok] - b[ok]) / np.abs(b[ok]), initial=0.0))


def _compare_searches(uu, yy, nas, nbs, nks, search, old_rows, old_params, old_model) -> None:
    """Print whether the fast search reproduces the per-candidate one (parameters to 1e-10)."""
    grid = [(c.na, c.nb, c.nk) for c in old_rows]
    _, fits = arx._fit_grid(np.asarray(uu, float), np.asarray(yy, float), grid)
    marks_same = all((f is None) == (q is None) for f, q in zip(fits, old_params, strict=True))
    d_params = max(
        (
            _largest_relative(f.params, q)
            for f, q in zip(fits, old_params, strict=True)
            if f is not None and q is not None
        ),
        default=0.0,
    )
    d_chosen = _largest_relative(search.model.params, old_model.params)
    d_table = {
        name: _largest_relative([getattr(c, name) for c in search.candidates], [getattr(c, name) for c in old_rows])
        for name in ("V", "aic", "bic", "fit_percent")
    }
    same_choice = (search.model.na, search.model.nb, search.model.nk) == (old_model.na, old_model.nb, old_model.nk)
    ok = marks_same and max(d_params, d_chosen) <= 1e-10 and same_choice
    print(
        f"     check: candidates' parameters agree to 1e-10 relative and the choice is the same: "
        f"{'yes' if ok else 'NO'} (largest relative difference: candidates {d_params:.1e}, chosen model "
        f"{d_chosen:.1e}; undetermined candidates {'the same' if marks_same else 'DIFFER'}; same choice "
        f"{'yes' if same_choice else 'NO'})"
    )
    print("     table, largest relative difference: " + ", ".join(f"{name} {d:.1e}" for name, d in d_table.items()))


def bench_arx(result: PipelineResult, s: Setup, repeats: int, sippy_samples: int) -> None:
    u, y = result.u, result.y
    nas, nbs, nks = range(1, 5), range(1, 5), (1, 2)
    print(
        f"\n3. ARX order search on the preprocessed torque -> velocity: na 1..4, nb 1..4, nk 1..2 "
        f"({len(nas) * len(nbs) * len(nks)} candidates), AIC; median of {repeats} runs after one warm-up "
        f"(the per-candidate reference: median of {min(repeats, 3)})"
    )
    print(
        "   hilident nk = input delay in samples (nk = 0: u(k) acts on y(k)); sippy's delay d means "
        "u(k-1-d), so nk 1..2 is sippy's delays 0..1"
    )
    try:
        from sippy_unipi import system_identification
    except ImportError as exc:
        system_identification = None
        print(f"   sippy-unipi is not installed ({exc}); `pip install sippy-unipi` to compare. Only hilident is timed.")
    n_sippy = u.size if sippy_samples <= 0 else min(sippy_samples, u.size)
    runs = [(u.size, "full record")]
    if n_sippy < u.size:
        runs.append((n_sippy, f"first {n_sippy:,} samples (--sippy-samples)"))
    for n, label in runs:
        uu, yy = u[:n], y[:n]
        t_h = float(np.median(_timeit(lambda uu=uu, yy=yy: arx_order_search(uu, yy, nas, nbs, nks), repeats)))
        search = arx_order_search(uu, yy, nas, nbs, nks)
        strict = min(search.candidates, key=lambda c: c.aic)
        m = search.model
        print(f"   {n:,} samples, {label}:")
        print(
            f"     hilident arx_order_search   {t_h:8.3f} s; chooses na={m.na} nb={m.nb} "
            f"nk={m.nk} (fewest parameters within 2 of the best AIC); lowest AIC: na={strict.na} "
            f"nb={strict.nb} nk={strict.nk}; target <= {ARX_TARGET_S:g} s: "
            f"{'met' if t_h <= ARX_TARGET_S else 'NOT met'}"
        )
        t_old = float(
            np.median(
                _timeit(
                    lambda uu=uu, yy=yy: _search_per_candidate(uu, yy, nas, nbs, nks), min(repeats, 3), warmup=False
                )
            )
        )
        old_rows, old_params, old_model = _search_per_candidate(uu, yy, nas, nbs, nks)
        print(f"     one QR per candidate (before) {t_old:8.3f} s; time ratio before/now {t_old / t_h:.1f}")
        _compare_searches(uu, yy, nas, nbs, nks, search, old_rows, old_params, old_model)
        if system_identification is None or n > n_sippy:
            continue
        buf = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(buf):
            sm = system_identification(
                yy, uu, "ARX", IC="AIC", na_ord=[1, 4], nb_ord=[1, 4], delays=[0, 1], tsample=1.0 / s.sample_rate_hz
            )
        t_s = time.perf_counter() - t0
        na, nb, nk = int(sm.na), int(sm.nb), int(sm.theta) + 1
        print(
            f"     sippy-unipi (ARX, IC='AIC') {t_s:8.2f} s (one run); chooses na={na} nb={nb} nk={nk} "
            f"(lowest AIC); time ratio sippy/hilident {t_s / t_h:.1f}"
        )
        same = (na, nb, nk) == (strict.na, strict.nb, strict.nk)
        print(
            f"     same order as hilident's lowest AIC: {'yes' if same else 'no'}; "
            f"as hilident's choice: {'yes' if (na, nb, nk) == (m.na, m.nb, m.nk) else 'no'}"
        )
        ours = fit_arx(uu, yy, na, nb, nk)
        den = np.ravel(sm.DENOMINATOR)
        num = np.ravel(sm.NUMERATOR)
        a_sippy = -den[1 : na + 1]  # sippy's denominator is 1 + a z^-1 ...; hilident's a has the opposite sign
        b_sippy = num[nk - 1 : nk - 1 + nb]
        da = np.max(np.abs(ours.a - a_sippy))
        db = np.max(np.abs(ours.b - b_sippy) / np.max(np.abs(ours.b)))
        print(
            f"     parameters at na={na} nb={nb} nk={nk}: max |a difference| {da:.2e}, "
            f"max |b difference| / max|b| {db:.2e}"
        )
        a_txt = ", ".join(f"{x:.5f}" for x in ours.a)
        b_txt = ", ".join(f"{x:.4e}" for x in ours.b)
        print(f"       hilident a = ({a_txt}), b = ({b_txt})")


# --- 4. memory ------------------------------------------------------------------------------------


def _proc_status_bytes(key: str) -> int | None:
    """A ``kB`` field of /proc/self/status (``VmRSS``, ``VmHWM``) in bytes; None where there is none."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _reset_peak_rss() -> bool:
    """Reset this process's resident-set high-water mark (Linux: /proc/self/clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _rss_growth(fn) -> tuple[int | None, int]:
    """(peak RSS above the RSS at the start, ru_maxrss growth), both in bytes, of one call."""
    gc.collect()
    maxrss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    base = _proc_status_bytes("VmRSS") if _reset_peak_rss() else None
    fn()
    maxrss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    hwm = _proc_status_bytes("VmHWM")
    return (hwm - base if base is not None and hwm is not None else None), maxrss1 - maxrss0


def _memory_child(path: str, setup: Setup, conn) -> None:
    """Fresh process: RSS growth of one run, then the run again under tracemalloc."""
    data = np.load(path)
    rec = Record(setup.sample_rate_hz, data["excitation"], data["torque"], data["velocity"])
    short = Record(rec.sample_rate_hz, *(x[:50_000].copy() for x in (rec.excitation, rec.torque, rec.velocity)))
    run_pipeline(short, setup)  # lazy imports and caches, not the record's memory
    run_identify_plant(short, setup)
    out = {
        "rss_base": _proc_status_bytes("VmRSS"),
        "maxrss_base": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
    }
    out["rss_growth"], out["maxrss_growth"] = _rss_growth(lambda: run_pipeline(rec, setup))
    out["rss_growth_lib"], _ = _rss_growth(lambda: run_identify_plant(rec, setup))

    stages = {}

    def on_stage(name):
        current, peak = tracemalloc.get_traced_memory()
        stages[name] = (peak, current)
        tracemalloc.reset_peak()

    tracemalloc.start()
    run_pipeline(rec, setup, on_stage)
    out["traced_peak"] = max(p for p, _ in stages.values())
    out["stages"] = stages
    tracemalloc.reset_peak()
    run_identify_plant(rec, setup)
    out["traced_peak_lib"] = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    conn.send(out)
    conn.close()


def bench_memory(rec: Record, s: Setup) -> None:
    print("\n4. peak memory of one pipeline run, in a fresh process (after a warm-up on 50,000 samples)")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "record.npz")
        np.savez(path, excitation=rec.excitation, torque=rec.torque, velocity=rec.velocity)
        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_memory_child, args=(path, s, child))
        proc.start()
        child.close()
        out = parent.recv()
        proc.join()
    channel = rec.torque.nbytes
    inputs = 2 * channel  # torque and velocity (the velocity is also the output)
    print(
        f"   input: torque and velocity, {rec.n:,} float64 samples each = {_mb(channel).strip()} per channel, "
        f"{_mb(inputs).strip()} together; tracemalloc counts numpy's arrays, not library-internal buffers"
    )
    print(f"   {'stage':<24} {'traced peak':>12} {'held after':>12}   (both include the input)")
    for name in STAGES:
        peak, current = out["stages"][name]
        print(f"   {name:<24} {_mb(peak):>12} {_mb(current):>12}")
    peak = out["traced_peak"]
    verdict = "met" if peak < MEMORY_TARGET * inputs else "NOT met"
    print(
        f"   tracemalloc peak {_mb(peak).strip()} = {peak / inputs:.1f}x the input "
        f"({peak / channel:.1f}x one channel); target < {MEMORY_TARGET:g}x the input: {verdict}"
    )
    growth = out["rss_growth"]
    if growth is not None:
        print(
            f"   peak RSS growth {_mb(growth).strip()} = {growth / inputs:.1f}x the input "
            f"({growth / channel:.1f}x one channel): VmHWM after the run minus VmRSS before it "
            f"({_mb(out['rss_base']).strip()}), the high-water mark reset first"
        )
    print(
        f"   ru_maxrss growth {_mb(out['maxrss_growth']).strip()}"
        + (
            f": ru_maxrss was {_mb(out['maxrss_base']).strip()} before the run, the parent's peak carried over "
            "exec into the spawned process, so a smaller peak does not show in it"
            if growth is not None
            else ""
        )
    )
    n_lib = 3 * channel
    lib = out["traced_peak_lib"]
    lib_rss = out["rss_growth_lib"]
    print(
        f"   reference: identify_plant (3 distinct signals in, {_mb(n_lib).strip()}): tracemalloc peak "
        f"{_mb(lib).strip()} = {lib / n_lib:.1f}x its input"
        + (f", peak RSS growth {_mb(lib_rss).strip()} = {lib_rss / n_lib:.1f}x" if lib_rss is not None else "")
    )


# --- profile --------------------------------------------------------------------------------------


def profile_pipeline(rec: Record, s: Setup, top: int = 15) -> None:
    print(f"\nprofile of one pipeline run (top {top} by own time)")
    prof = cProfile.Profile()
    prof.enable()
    run_pipeline(rec, s)
    prof.disable()
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(top)
    lines = buf.getvalue().splitlines()
    start = next((i for i, line in enumerate(lines) if line.lstrip().startswith("ncalls")), 0)
    print("\n".join("   " + line for line in lines[start:] if line.strip()))


# --- command line ---------------------------------------------------------------------------------


def _parse_args(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--samples", type=int, default=1_000_000, help="record length (default 10^6)")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate, Hz (default 1000)")
    p.add_argument("--repeats", type=int, default=5, help="timed runs per measurement (default 5)")
    p.add_argument(
        "--sippy-samples",
        type=int,
        default=0,
        help="run sippy-unipi on the first N samples only (default 0: the full record, about a minute)",
    )
    p.add_argument("--skip", default="", help="comma-separated parts to skip: h1, arx, memory")
    p.add_argument("--profile", action="store_true", help="print a cProfile of one pipeline run")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    if args.samples < 20 * args.rate:
        p.error(f"--samples must be at least 20 s of data ({int(20 * args.rate)}), got {args.samples}")
    if args.rate < 500:
        p.error(f"--rate must be >= 500 Hz (the excitation reaches 200 Hz), got {args.rate}")
    if args.repeats < 1:
        p.error(f"--repeats must be >= 1, got {args.repeats}")
    args.skip = {x.strip() for x in args.skip.split(",") if x.strip()}
    unknown = args.skip - {"h1", "arx", "memory"}
    if unknown:
        p.error(f"--skip knows h1, arx, memory; got {', '.join(sorted(unknown))}")
    return args


def main(argv=None) -> int:
    args = _parse_args(argv)
    cfg = parse_config(_CONFIG.format(seed=args.seed), "<bench/ident.py>")
    print("hilident identification benchmark")
    print(f"machine: {_machine()}")
    t0 = time.perf_counter()
    fit = friction_test(cfg, args.rate)
    rec = make_record(cfg, args.samples, args.rate, args.seed)
    fp, tp = fit.params, cfg.emulator.friction
    print(
        f"data: emulated two-mass gantry (build_drive, torque mode, open loop), {args.samples:,} samples at "
        f"{args.rate:g} Hz, noise torque {_EXCITATION_RMS_NM:g} N·m rms in {_EXCITATION_BAND_HZ[0]:g}-"
        f"{_EXCITATION_BAND_HZ[1]:g} Hz; generated in {time.perf_counter() - t0:.1f} s (not timed below)"
    )
    print(
        f"friction fit from an emulated constant-speed test ({fit.n_points} points): Fc {fp.Fc:.4f}, "
        f"Fs {fp.Fs:.4f}, Fv {fp.Fv:.4f}, vs {fp.vs:.5f} (true {tp.Fc:g}, {tp.Fs:g}, {tp.Fv:g}, {tp.vs:g})"
    )
    setup = Setup(args.rate, cfg.identification, cfg.notch, fp)
    result = bench_pipeline(rec, setup, args.repeats, cfg)
    if "h1" not in args.skip:
        bench_h1(result, setup, args.repeats)
    if "arx" not in args.skip:
        bench_arx(result, setup, args.repeats, args.sippy_samples)
    if "memory" not in args.skip:
        bench_memory(rec, setup)
    if args.profile:
        profile_pipeline(rec, setup)
    print(f"\ndone in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
