"""How far a measured band figure can be trusted: the error of a periodic estimate and the floor it puts under
the verification (``frfquality.estimate_error_std``, ``pipeline.verification.band_floor_db``,
``pipeline.responses.pooled_loop_response``).

A notch takes the response near the mode down; what the output does that the excitation does not explain (noise,
forces on the load behind the filter slots) stays. The verification measures the notched response through it, so
its band figure cannot exceed a floor set by that noise and the number of periods averaged.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from hilident.config.tables import IdentificationConfig
from hilident.errors import DataError
from hilident.ident.frequency import periodic_frf
from hilident.ident.frfquality import estimate_error_std
from hilident.ident.resonance import Resonance
from hilident.pipeline.responses import pooled_loop_response
from hilident.pipeline.verification import band_floor_db, peak_reductions

FS = 1000.0
PERIOD = 4000  # 4 s: 0.25 Hz lines
MODE_HZ, ZETA = 21.0, 0.02
BINS = np.arange(8, 321)  # 2-80 Hz
MAP_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry-map.toml"


def _multisine(periods: int, seed: int = 3) -> np.ndarray:
    spec = np.zeros(PERIOD // 2 + 1, complex)
    spec[BINS] = np.exp(2j * np.pi * np.random.default_rng(seed).random(BINS.size))
    x = np.fft.irfft(spec, n=PERIOD)
    return np.tile(x / np.abs(x).max(), periods)


def _mode():
    """A lightly damped mode, force to velocity: ``s / (s^2 + 2 zeta w s + w^2)``, discretised."""
    w = 2 * np.pi * MODE_HZ
    b, a, _ = signal.cont2discrete(([1.0, 0.0], [1.0, 2 * ZETA * w, w * w]), 1.0 / FS, method="bilinear")
    return np.ravel(b), a


def _record(periods: int, notch: bool, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """One lead-in period and ``periods`` analysed ones of the mode, plus a force on it the excitation does not
    explain (white noise through the same mode, as a load force is). ``notch``: the excitation reaches the mode
    80 dB down, so that near the mode only the noise is left to measure."""
    b, a = _mode()
    r = _multisine(periods + 1)
    x = 1e-4 * r if notch else r
    force = noise * np.random.default_rng(seed).standard_normal(r.size)
    y = signal.lfilter(b, a, x + force)
    return r[PERIOD:], y[PERIOD:]


def _response(r, y):
    return periodic_frf(r, y, PERIOD, FS, skip_periods=0, bins=BINS)


def _mode_record() -> Resonance:
    return Resonance(frequency_hz=MODE_HZ, damping_ratio=ZETA, peak_magnitude_db=0.0, coherence=1.0, method="test")


@pytest.mark.parametrize("periods", [2, 8])
def test_the_estimate_error_of_a_periodic_response_is_its_spread_over_periods(periods):
    """Pooled over 300 lines the estimated error variance matches the variance of the estimate about the truth
    within 1 dB. Counting the periods' spread with M instead of M - 1 degrees of freedom would be 3 dB off at
    two periods."""
    b, a = _mode()
    truth = signal.freqz(b, a, worN=BINS * FS / PERIOD, fs=FS)[1]
    actual, estimated = [], []
    for seed in range(6):
        r = _multisine(periods)
        y = signal.lfilter(b, a, np.concatenate([r[:PERIOD], r]))[PERIOD:]  # steady state
        y = y + 2e-4 * np.random.default_rng(seed).standard_normal(y.size)
        est = _response(r, y)
        actual.append(np.abs(est.response - truth) ** 2)
        estimated.append(estimate_error_std(est) ** 2)
    ratio_db = 10 * np.log10(np.mean(estimated) / np.mean(actual))
    assert abs(ratio_db) < 1.0, ratio_db


def test_an_estimate_without_spread_has_no_error_and_one_without_coherence_an_unknown_one():
    r = _multisine(3)
    b, a = _mode()
    y = signal.lfilter(b, a, np.concatenate([r[:PERIOD], r]))[PERIOD:]
    assert np.nanmax(estimate_error_std(_response(r, y)) / np.abs(_response(r, y).response)) < 1e-4
    no_coherence = replace(_response(r, y), coherence=np.full(BINS.size, np.nan))
    assert np.all(np.isnan(estimate_error_std(no_coherence)))


def test_a_notched_response_measured_in_noise_reads_about_its_floor_and_more_periods_raise_both():
    """Behind a notch that leaves only noise near the mode, the measured band figure lies within 3 dB of the
    floor its own record predicts, on average over records; four times the periods raise the floor by 6 dB
    (10 log10 4) within 1.5, and the measured figure with it."""
    mode = _mode_record()
    floors, figures = {2: [], 8: []}, {2: [], 8: []}
    for seed in range(5):
        before = _response(*_record(2, notch=False, noise=0.0, seed=seed))
        for periods in (2, 8):
            after = _response(*_record(periods, notch=True, noise=0.002, seed=100 + seed))
            (r,) = peak_reductions(before, after, [mode])
            figures[periods].append(r["band_reduction_db"])
            floors[periods].append(band_floor_db(before, after, mode))
    for periods in (2, 8):
        assert abs(np.mean(figures[periods]) - np.mean(floors[periods])) < 3.0, (periods, figures, floors)
    rise = np.mean(floors[8]) - np.mean(floors[2])
    assert abs(rise - 6.0) < 1.5, rise
    assert np.mean(figures[8]) > np.mean(figures[2]) + 3.0


def test_without_noise_the_floor_is_infinite_and_far_above_what_the_notch_gives():
    mode = _mode_record()
    before = _response(*_record(2, notch=False, noise=0.0, seed=0))
    after = _response(*_record(2, notch=True, noise=0.0, seed=0))
    (r,) = peak_reductions(before, after, [mode])
    floor = band_floor_db(before, after, mode)
    assert floor > r["band_reduction_db"] + 40.0
    outside = Resonance(frequency_hz=300.0, damping_ratio=ZETA, peak_magnitude_db=0.0, coherence=1.0, method="t")
    assert np.isnan(band_floor_db(before, after, outside))


def test_pooled_records_average_all_their_periods_each_conditioned_on_its_own():
    """Two records of one periodic excitation pool into the estimate of all their periods. Each record's own
    drift (a held position creeping) is removed on its own: the pooled estimate with a different ramp on each
    record is the one without ramps, where splicing the raw records would leak the ramps into every line."""
    cfg = IdentificationConfig()
    r1, y1 = _record(2, notch=False, noise=0.002, seed=1)
    r2, y2 = _record(3, notch=False, noise=0.002, seed=2)
    ramp1, ramp2 = np.linspace(0.0, 0.05, y1.size), np.linspace(0.02, -0.03, y2.size)
    clean = pooled_loop_response([r1, r2], [y1, y2], FS, cfg, PERIOD, BINS)
    drifting = pooled_loop_response([r1, r2], [y1 + ramp1, y2 + ramp2], FS, cfg, PERIOD, BINS)
    assert drifting.n_averages == 5
    spliced = _response(np.concatenate([r1, r2]), np.concatenate([y1 + ramp1, y2 + ramp2]))
    pooled_error = np.abs(drifting.response - clean.response).max()
    spliced_error = np.abs(spliced.response - clean.response).max()
    assert pooled_error < 1e-3 * np.abs(clean.response).max()
    assert spliced_error > 10 * pooled_error
    with pytest.raises(DataError, match="whole number"):
        pooled_loop_response([r1[:-10]], [y1[:-10]], FS, cfg, PERIOD, BINS)


class _Bench:
    """An axis held at one position with a lightly damped mode (MODE_HZ, ZETA) and a force on it the excitation
    does not explain, driven open loop: the command entering the filter slots is the excitation, and the slots
    hold ``chain`` once the notches are enabled. It plays what :class:`WorkspaceRun` asks, as a session's
    recorder would, and keeps every record's name."""

    def __init__(self, noise: float, chain: list):
        self.noise, self.chain, self.notched = noise, chain, False
        self.here, self.names, self.seed = 0.0, [], 0

    def record(self, name, mode, samples, period_samples=None, recipe=None):
        self.names.append(name)
        x = np.asarray(samples, dtype=float)
        if mode == "position":  # the trapezoid is relative to where the cart is: it ends still at the target
            position = self.here + x
            self.here = float(position[-1])
            return SimpleNamespace(samples={"position_m": position, "velocity_mps": np.zeros_like(x)})
        b, a = _mode()
        into_mode = x
        if self.notched:
            for section in self.chain:
                into_mode = signal.lfilter(section.b, section.a, into_mode)
        self.seed += 1
        force = self.noise * np.random.default_rng(self.seed).standard_normal(x.size)
        velocity = signal.lfilter(b, a, into_mode + force)
        return SimpleNamespace(samples={"excitation": x, "torque_cmd_nm": x, "velocity_mps": velocity})


def _verified_run(noise: float, verify_max_duration_s: float = 0.0):
    """A one-position map, measured before on ``_Bench``, then verified with two staggered notches enabled
    (about 35 dB over the band figure's band): ``(verification summary, the bench, the run's warnings)``."""
    from hilident.config.tables import load_config
    from hilident.filters.notch import NotchSpec, design_notch
    from hilident.session.excitation import build_excitation
    from hilident.session.map_positions import MAP_MODE, MapPoint
    from hilident.session.map_run import WorkspaceRun

    cfg = load_config(MAP_CONFIG)
    cfg = replace(
        cfg,
        run=replace(cfg.run, sample_rate_hz=FS),
        map=replace(cfg.map, positions_m=[0.0], count=0, verify_max_duration_s=verify_max_duration_s),
    )
    mapped = replace(
        cfg, excitation=replace(cfg.excitation, mode=MAP_MODE, amplitude_nm=1.0, duration_s=cfg.map.duration_s)
    )
    chain = [design_notch(NotchSpec(MODE_HZ, 16.0, 60.0), FS)] * 2
    bench, warnings = _Bench(noise, chain), []

    def analysis_samples(exp, excitation):  # the whole periods after the lead-in
        return {k: v[excitation.period_samples :] for k, v in exp.samples.items()}

    run = WorkspaceRun(
        cfg,
        bench.record,
        identify=None,
        analysis_samples=analysis_samples,
        position=lambda: bench.here,
        progress=None,
        warnings=warnings,
        filter_input="torque_cmd_nm",
    )
    run.excitation, run.mapped_cfg, run.recipe = build_excitation(mapped), mapped, None
    exp = bench.record("map_0", MAP_MODE, run.excitation.samples)
    s = analysis_samples(exp, run.excitation)
    period, bins = run.excitation.period_samples, run.excitation.excited_bins
    loop = pooled_loop_response([s["excitation"]], [s["velocity_mps"]], FS, cfg.identification, period, bins)
    run.results = {"map_0": SimpleNamespace(loop=loop, resonances=[_mode_record()])}
    run.command_responses = {
        "map_0": pooled_loop_response([s["excitation"]], [s["torque_cmd_nm"]], FS, cfg.identification, period, bins)
    }
    run.points = [MapPoint(0.0, 0.0, MODE_HZ, ZETA, 0.01, 0.99, "map_0.h5")]
    run.chain, run.chain_rate_hz = chain, FS
    bench.notched = True
    return run.verify(), bench, warnings


def test_a_verification_whose_noise_floor_hides_the_target_records_longer_and_then_shows_it():
    """With a load force that puts the two-period record's floor below the target, the verification records a
    second, longer excitation at the position and measures on all the periods: the floor rises by about 10 log10
    of the periods' ratio, and the figure the notches earn shows. With no room for it ([map]
    verify_max_duration_s), the figure stays at the floor and the warnings say why."""
    target = 20.0
    short, short_bench, short_warnings = _verified_run(noise=0.4, verify_max_duration_s=13.0)
    (row,) = short["positions"]
    assert short_bench.names[-1] == "map_verify_0" and row["periods"] == 2 and row["recordings"] == ["map_verify_0.h5"]
    assert row["floor_limited"] and row["band_reduction_db"] < target
    assert row["predicted_band_reduction_db"] > target + 10.0  # the notches are not what falls short
    assert any("leaves no room" in w for w in short_warnings), short_warnings
    assert any("noise floor" in w and "dropped by only" in w for w in short_warnings), short_warnings

    verified, bench, warnings = _verified_run(noise=0.4)
    (longer,) = verified["positions"]
    assert bench.names[-1] == "map_verify_0_more"
    assert longer["recordings"] == ["map_verify_0.h5", "map_verify_0_more.h5"] and longer["periods"] > 2
    rise = 10 * np.log10(longer["periods"] / row["periods"])
    assert longer["floor_db"] - row["floor_db"] == pytest.approx(rise, abs=3.0)
    assert longer["band_reduction_db"] >= target and longer["band_reduction_db"] > row["band_reduction_db"] + 3.0
    assert not [w for w in warnings if "dropped by only" in w]


def test_a_verification_above_its_floor_records_once():
    verified, bench, warnings = _verified_run(noise=0.001)
    (row,) = verified["positions"]
    assert not row["floor_limited"] and row["band_reduction_db"] >= 20.0
    assert row["recordings"] == ["map_verify_0.h5"] and "map_verify_0_more" not in bench.names
    assert not [w for w in warnings if "noise floor" in w]
