"""The friction test's extension without a device: folded points, intervals, the planning of a round, the report."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.config.tables import parse_config
from hilident.errors import ConfigError
from hilident.html_report import write_report
from hilident.ident import friction as fr
from hilident.pipeline import friction as pf
from hilident.pipeline.friction_plan import AIM, Leg, LegRules, candidate_speeds, plan_round
from hilident.signals.ramp_legs import ramp_extent
from support.report_page import Page

HTML_DATA = Path(__file__).resolve().parent / "data" / "html_report"

#: A plant none of the shipped configs has: its Coulomb and viscous levels and a Stribeck hump at low speed.
TRUTH = fr.StribeckParams(Fc=0.31, Fs=0.52, Fv=3.4, vs=0.004)
RULES = LegRules(accel_mps2=0.8, settle_s=0.4, sample_rate_hz=500.0, travel_m=0.3, max_speed_mps=0.3, min_hold_s=1.0)


def pair_points(speeds, rng, noise_nm=0.02, load_nm=0.05) -> fr.FoldedPoints:
    """Folded pairs of legs at ``speeds``: friction plus noise, and a load torque that does not change with the
    direction (it cancels in each pair)."""
    speeds = np.asarray(speeds, dtype=float)
    v, tau, windows = [], [], []
    for k, s in enumerate(speeds):
        load = load_nm * rng.uniform(-1, 1)
        for sign in (1.0, -1.0):
            vm = sign * s * (1 + 0.005 * rng.standard_normal())
            v.append(np.full(50, vm))
            tau.append(fr.stribeck(vm, TRUTH) + load + noise_nm * rng.standard_normal() + np.zeros(50))
            windows.append((100 * k + (50 if sign < 0 else 0), 100 * k + (100 if sign < 0 else 50), sign * s))
    return fr.folded_points(np.concatenate(v), np.concatenate(tau), windows)


# --- the points and their intervals -------------------------------------------------------------


def test_a_pair_of_opposite_legs_is_one_point_and_a_direction_free_torque_cancels_in_it():
    rng = np.random.default_rng(4)
    points = pair_points([0.02, 0.05, 0.1], rng, noise_nm=0.0, load_nm=0.2)
    assert points.windows.tolist() == [2, 2, 2]
    assert np.allclose(points.friction, fr.stribeck(points.speed, TRUTH), atol=1e-3)


def test_a_torque_that_repeats_with_position_does_not_read_as_friction():
    # cogging of amplitude A and period P aids the axis where it speeds it up: over time the axis spends longer
    # where it is held back, so a mean over time reads the ripple as more friction; over distance it averages out
    amplitude, period, v0, swing, dt = 0.1, 0.01, 0.02, 0.3, 1e-3
    position, p, v = [], 0.0, []
    while p < 5 * period:  # whole periods
        speed = v0 * (1 + swing * np.sin(2 * np.pi * p / period))
        position.append(p)
        v.append(speed)
        p += speed * dt
    position, v = np.array(position), np.array(v)
    tau = TRUTH.Fc + TRUTH.Fv * v - amplitude * np.sin(2 * np.pi * position / period)
    points = fr.steady_state_points(v, tau, [(0, v.size, v0)], max_relative_std=0.5)
    truth = TRUTH.Fc + TRUTH.Fv * points.v_mean[0]
    assert abs(points.tau_mean[0] - truth) < 0.02 * amplitude
    assert tau.mean() - (TRUTH.Fc + TRUTH.Fv * v.mean()) > 0.1 * amplitude  # what a mean over time reads


def test_a_window_without_its_opposite_stays_a_point_of_its_own():
    v = np.r_[np.full(20, 0.1), np.full(20, 0.2), np.full(20, -0.2)]
    tau = fr.stribeck(v, TRUTH)
    points = fr.folded_points(v, tau, [(0, 20, 0.1), (20, 40, 0.2), (40, 60, -0.2)])
    assert points.windows.tolist() == [1, 2]
    assert points.speed == pytest.approx([0.1, 0.2])


@pytest.mark.parametrize("n_speeds", [5, 12])
def test_the_95_percent_interval_contains_the_truth_95_times_in_100(n_speeds):
    # Few points: the scatter is estimated from three degrees of freedom, which Student's t accounts for
    # (1.96 standard errors would hold the truth about 86 times in 100 here).
    rng = np.random.default_rng(11)
    speeds = np.geomspace(0.02, 0.25, n_speeds)
    trials, held = 1500, {"Fc": 0, "Fv": 0}
    for _ in range(trials):
        points = pair_points(speeds, rng)
        fit = fr.fit_coulomb_viscous(points.speed, points.friction)
        for name in held:
            held[name] += abs(getattr(fit.params, name) - getattr(TRUTH, name)) <= fit.half_width(name)
    for name, count in held.items():
        assert 0.93 <= count / trials <= 0.97, (name, count / trials)


def test_a_fit_without_a_degree_of_freedom_claims_no_interval():
    fit = fr.fit_stribeck([0.01, 0.02, 0.05, 0.1, 0.2], [0.5, 0.4, 0.45, 0.6, 1.0], fix_delta_v=1, fix_delta_s=2)
    assert fit.dof == 1 and 0 < fit.half_width("Fc") < np.inf
    exact = replace(fit, n_points=4)  # as many points as parameters
    assert exact.dof == 0 and exact.half_width("Fc") == np.inf and exact.half_width("delta_v") == 0.0


def test_a_stribeck_fit_that_bends_the_curve_down_at_the_top_is_not_the_structure():
    # Coulomb + viscous with the fastest point low: a "Stribeck" decay from Fs below Fc, or one still decaying at
    # the fastest speed, would explain it; neither is friction's structure.
    v = np.geomspace(0.02, 0.25, 14)
    tau = TRUTH.Fc + TRUTH.Fv * v + 0.004 * np.random.default_rng(2).standard_normal(v.size)
    tau[-1] -= 0.08
    fit = fr.fit_friction(v, tau)
    p = fit.params
    assert fit.structure == "coulomb_viscous" or (p.Fs >= p.Fc and np.exp(-((v.max() / p.vs) ** p.delta_s)) < 0.05)
    # a real hump, measured through it, is still found
    v = np.geomspace(0.001, 0.25, 16)
    assert fr.fit_friction(v, fr.stribeck(v, TRUTH)).structure.startswith("stribeck")


def test_points_of_several_recordings_are_pooled():
    rng = np.random.default_rng(5)

    def recorded(speeds):
        points = pair_points(speeds, rng)
        return pf.RecordedPoints(fr.SteadyStatePoints(points.speed, points.friction, 0 * points.speed), points)

    one = pf.fit_recorded([recorded([0.02, 0.05, 0.1, 0.2])], "coulomb_viscous")
    both = pf.fit_recorded([recorded([0.02, 0.05, 0.1, 0.2]), recorded([0.03, 0.07, 0.15, 0.25])], "coulomb_viscous")
    assert both.fit.n_points == 2 * one.fit.n_points == 8
    assert set(both.intervals()) == {"Fc", "Fv"}


@pytest.mark.parametrize("ringing_nm_per_mps", [0.0, 0.25])
def test_a_first_round_that_disagrees_with_the_later_ones_is_left_out(ringing_nm_per_mps):
    # the configured round's windows began before the axis settled: its means lie low, the more the faster
    rng = np.random.default_rng(8)

    def recorded(speeds, bias_per_mps=0.0):
        points = pair_points(speeds, rng, noise_nm=0.004)
        points = points._replace(friction=points.friction - bias_per_mps * points.speed)
        return pf.RecordedPoints(fr.SteadyStatePoints(points.speed, points.friction, 0 * points.speed), points)

    first = recorded([0.02, 0.04, 0.08, 0.15, 0.25], ringing_nm_per_mps)
    later = [recorded(np.geomspace(0.02, 0.25, 8)) for _ in range(2)]
    result = pf.fit_recorded([first, *later], "coulomb_viscous")
    assert result.first_round_left_out == (ringing_nm_per_mps > 0)
    assert abs(result.fit.params.Fv - TRUTH.Fv) <= result.fit.half_width("Fv")


# --- the legs a round may play -------------------------------------------------------------------


def test_candidates_are_the_steady_speeds_and_the_midpoints_between_them():
    played = [0.003, 0.01, 0.02, 0.05, 0.2, 0.4]
    measured = [0.0199, 0.0502, 0.1996]  # 0.003 and 0.01 were not steady; 0.4 is above the speed allowed
    speeds = candidate_speeds(played, measured, max_speed_mps=0.3)
    assert min(speeds) == 0.02 and max(speeds) == 0.2
    assert {0.02, 0.05, 0.2} < set(speeds) and len(speeds) == 5
    assert all(a < b for a, b in zip(speeds, speeds[1:], strict=False))


@pytest.mark.parametrize("speed", [0.01, 0.05, 0.12, 0.2, 0.29])
def test_a_leg_is_held_only_as_long_as_the_travel_allows(speed):
    hold = RULES.longest_hold_s(speed, 30.0)
    if hold == 0.0:  # not even the configured hold fits
        assert ramp_extent([speed], RULES.min_hold_s, RULES.accel_mps2, RULES.sample_rate_hz, RULES.settle_s)[1] >= (
            RULES.travel_m
        )
        return
    assert hold >= RULES.min_hold_s
    assert RULES.extent(Leg(speed, hold))[1] < RULES.travel_m
    if hold < 30.0:  # cut by the travel: a sample longer would not fit
        assert RULES.extent(Leg(speed, hold + 1 / RULES.sample_rate_hz))[1] >= RULES.travel_m


def first_round(seed: int = 1, speeds=(0.005, 0.01, 0.02, 0.05, 0.1, 0.2)):
    points = pair_points(speeds, np.random.default_rng(seed))
    return fr.fit_friction(points.speed, points.friction), points, {Leg(s, 1.0) for s in speeds}


def test_a_round_stays_within_the_travel_the_speed_and_its_time():
    fit, points, played = first_round()
    plan = plan_round(fit, points, played, RULES, hold_s=2.0, budget_s=40.0, target_percent=2.0)
    assert plan.legs and not played & set(plan.legs)
    assert sum(RULES.duration_s(leg) for leg in plan.legs) == pytest.approx(plan.duration_s)
    assert plan.duration_s <= 40.0
    for leg in plan.legs:
        assert 0.0 < leg.speed_mps <= RULES.max_speed_mps
        assert RULES.min_hold_s <= leg.hold_s <= 2.0
        assert RULES.extent(leg)[1] < RULES.travel_m


def test_a_round_runs_where_the_levels_are_least_determined():
    # A straight line's intercept is pinned by the slowest points, its slope by the two ends: a round aimed at
    # both runs the slowest and the fastest speeds before any in the middle.
    fit, points, played = first_round(speeds=(0.02, 0.04, 0.06, 0.08, 0.1, 0.15, 0.2))
    assert fit.structure == "coulomb_viscous"
    plan = plan_round(fit, points, played, RULES, hold_s=1.5, budget_s=12.0, target_percent=1.0)
    speeds = [leg.speed_mps for leg in plan.legs]
    assert min(speeds) < 0.04 and max(speeds) > 0.15


def test_a_round_stops_once_the_target_is_predicted_met():
    fit, points, played = first_round(3)
    now = {n: 100 * fit.half_width(n) / getattr(fit.params, n) for n in ("Fc", "Fv")}
    target = 0.7 * max(now.values())
    plan = plan_round(fit, points, played, RULES, hold_s=2.0, budget_s=1e4, target_percent=target)
    assert plan.legs and max(plan.predicted_percent.values()) <= AIM * target
    shorter = plan_round(fit, points, played, RULES, hold_s=2.0, budget_s=1e4, target_percent=target / 2)
    assert len(shorter.legs) > len(plan.legs)


def test_no_round_when_nothing_fits_the_time_or_the_travel():
    fit, points, played = first_round()
    assert plan_round(fit, points, played, RULES, 2.0, budget_s=0.5, target_percent=1.0).limited_by == "time"
    # the axis stands where no leg of the configured hold fits the room left
    cramped = replace(RULES, travel_m=0.004)
    plan = plan_round(fit, points, played, cramped, 1.0, budget_s=100.0, target_percent=1.0)
    assert not plan.legs and plan.limited_by == "travel"


# --- the configuration ---------------------------------------------------------------------------

LIMITS = "[limits]\ntorque_nm = 5.0\nvelocity_mps = 0.5\nposition_min_m = -0.5\nposition_max_m = 0.5\n"


def test_the_extension_keys_are_checked_and_named():
    cfg = parse_config(LIMITS, "bench.toml")
    ft = cfg.friction_test
    assert ft.target_ci_percent == 5.0 and ft.max_duration_s > 0 and ft.max_rounds >= 2
    with pytest.raises(ConfigError) as err:
        parse_config(LIMITS + "[friction_test]\nmax_duration_s = 5.0\n", "bench.toml")
    assert err.value.key == "friction_test.max_duration_s" and "bench.toml" in str(err.value)
    # without a target the configured legs alone run, whatever their length
    parse_config(LIMITS + "[friction_test]\nmax_duration_s = 5.0\ntarget_ci_percent = 0\n", "bench.toml")
    with pytest.raises(ConfigError) as err:
        parse_config(LIMITS + "[friction_test]\ntarget_ci_percent = -1\n", "bench.toml")
    assert err.value.key == "friction_test.target_ci_percent"


# --- the report ----------------------------------------------------------------------------------


def test_the_report_says_how_the_friction_test_extended_itself(tmp_path):
    summary = json.loads((HTML_DATA / "run.json").read_text())
    fr_part = summary["friction"]
    fr_part["ci95"] = {"Fc": 0.0091, "Fv": 0.083}
    fr_part["extension"] = {
        "target_ci_percent": 5.0,
        "met": False,
        "stopped_by": "time",
        "rounds": 4,
        "duration_s": 239.7,
        "max_duration_s": 240.0,
        "half_width_percent": {"Fc": 6.2, "Fv": 4.1},
        "first_round_left_out": True,
        "legs": [{"round": 2, "speed_mps": 0.02, "hold_s": 1.5}],
    }
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    friction = Page(write_report(tmp_path).read_text(encoding="utf-8")).sections["friction"]
    assert "4 round(s)" in friction and "Fc ±6.2 %" in friction and "max_duration_s" in friction
    assert "left out" in friction and "0.0091 N*m" in friction
