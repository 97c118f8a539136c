"""Input shapers: the designs' impulses, their residual vibration, a simulated mode, scoring and the choice.

The reference impulses below are written out plainly from the published
formulas, laid out as the Klipper firmware's definitions (amplitudes before
normalisation, times in seconds), so a shaper tuned by hilident and one entered
in the firmware are the same impulse train.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lsim

from hilident.errors import ConfigError, DataError
from hilident.motion.input_shapers import (
    DEFAULT_DAMPING_RATIO,
    DESIGNS,
    TEST_DAMPING_RATIOS,
    VIBRATION_TOLERANCE,
    Shaper,
    choose_shaper,
    design_shaper,
    ei_shaper,
    max_acceleration,
    residual_vibration,
    score_shaper,
    shaper_smoothing,
    zv_shaper,
    zvd_shaper,
)
from hilident.motion.profiles import trapezoid

KINDS = list(DESIGNS)
V_TOL = 0.05


# --- reference impulses, (amplitudes, times_s), from the published formulas ---------------------------------------


def reference_zv(f, z):
    k = math.exp(-z * math.pi / math.sqrt(1 - z * z))
    td = 1 / (f * math.sqrt(1 - z * z))
    return [1, k], [0, td / 2]


def reference_zvd(f, z):
    k = math.exp(-z * math.pi / math.sqrt(1 - z * z))
    td = 1 / (f * math.sqrt(1 - z * z))
    return [1, 2 * k, k * k], [0, td / 2, td]


def reference_mzv(f, z):
    k = math.exp(-0.75 * z * math.pi / math.sqrt(1 - z * z))
    td = 1 / (f * math.sqrt(1 - z * z))
    a1 = 1 - 1 / math.sqrt(2)
    return [a1, (math.sqrt(2) - 1) * k, a1 * k * k], [0, 0.375 * td, 0.75 * td]


def reference_ei(f, z, v=V_TOL):
    td = 1 / (f * math.sqrt(1 - z * z))
    a1 = (0.24968 + 0.24961 * v) + ((0.80008 + 1.23328 * v) + (0.49599 + 3.17316 * v) * z) * z
    a3 = (0.25149 + 0.21474 * v) + ((-0.83249 + 1.41498 * v) + (0.85181 - 4.90094 * v) * z) * z
    t2 = (
        0.4999 + ((0.46159 + 8.57843 * v) * v + ((4.26169 - 108.644 * v) * v + (1.75601 + 336.989 * v) * v * z) * z) * z
    )
    return [a1, 1 - a1 - a3, a3], [0, t2 * td, td]


def horner(coefficients, x):
    total = 0.0
    for c in reversed(coefficients):
        total = total * x + c
    return total


# Singhose, Porter, Tuttle & Singer (1997), 5 % tolerance: rows are impulses, columns the powers 0..3 of z.
TWO_HUMP_T = [
    [0, 0, 0, 0],
    [0.49890, 0.16270, -0.54262, 6.16180],
    [0.99748, 0.18382, -1.58270, 8.17120],
    [1.49920, -0.09297, -0.28338, 1.85710],
]
TWO_HUMP_A = [
    [0.16054, 0.76699, 2.26560, -1.22750],
    [0.33911, 0.45081, -2.58080, 1.73650],
    [0.34089, -0.61533, -0.68765, 0.42261],
    [0.15997, -0.60246, 1.00280, -0.93145],
]
THREE_HUMP_T = [
    [0, 0, 0, 0],
    [0.49974, 0.23834, 0.44559, 12.4720],
    [0.99849, 0.29808, -2.36460, 23.3990],
    [1.49870, 0.10306, -2.01390, 17.0320],
    [1.99960, -0.28231, 0.61536, 5.40450],
]
THREE_HUMP_A = [
    [0.11275, 0.76632, 3.29160, -1.44380],
    [0.23698, 0.61164, -2.57850, 4.85220],
    [0.30008, -0.19062, -2.14560, 0.13744],
    [0.23775, -0.73297, 0.46885, -2.08650],
    [0.11244, -0.45439, 0.96382, -1.46000],
]


def reference_2hump_ei(f, z):
    return [horner(row, z) for row in TWO_HUMP_A], [horner(row, z) / f for row in TWO_HUMP_T]


def reference_3hump_ei(f, z):
    return [horner(row, z) for row in THREE_HUMP_A], [horner(row, z) / f for row in THREE_HUMP_T]


REFERENCES = {
    "zv": reference_zv,
    "mzv": reference_mzv,
    "zvd": reference_zvd,
    "ei": reference_ei,
    "2hump_ei": reference_2hump_ei,
    "3hump_ei": reference_3hump_ei,
}


def exact_undamped(kind: str, v: float = V_TOL) -> Shaper:
    """The published closed-form undamped EI shapers (period 1 s), which the curve fits approximate."""
    if kind == "ei":
        a = [(1 + v) / 4, (1 - v) / 2, (1 + v) / 4]
    elif kind == "2hump_ei":
        x = (v * v * (math.sqrt(1 - v * v) + 1)) ** (1 / 3)
        a1 = (3 * x * x + 2 * x + 3 * v * v) / (16 * x)
        a = [a1, 0.5 - a1, 0.5 - a1, a1]
    else:
        a1 = (1 + 3 * v + 2 * math.sqrt(2 * v * (v + 1))) / 16
        a2 = (1 - v) / 4
        a = [a1, a2, 1 - 2 * (a1 + a2), a2, a1]
    return Shaper(kind, np.arange(len(a)) / 2.0, np.array(a) / sum(a), 1.0, 0.0)


# --- the designs ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("damping", [0.0, 0.05, 0.1, 0.2])
def test_every_design_is_a_train_of_positive_impulses_summing_to_one_from_time_zero(kind, damping):
    shaper = DESIGNS[kind](37.5, damping)
    assert shaper.kind == kind
    assert shaper.times_s[0] == 0.0
    assert np.all(np.diff(shaper.times_s) > 0)
    assert np.all(shaper.amplitudes > 0)
    assert shaper.amplitudes.sum() == pytest.approx(1.0, abs=1e-12)
    assert shaper.duration_s == shaper.times_s[-1] > 0
    assert (shaper.frequency_hz, shaper.damping_ratio) == (37.5, damping)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("frequency_hz", [20.0, 37.5, 61.0])
@pytest.mark.parametrize("damping", [0.05, 0.1])
def test_impulses_are_the_firmwares_definitions(kind, frequency_hz, damping):
    amplitudes, times = REFERENCES[kind](frequency_hz, damping)
    shaper = DESIGNS[kind](frequency_hz, damping)
    np.testing.assert_allclose(shaper.times_s, times, rtol=0, atol=1e-6 / frequency_hz)
    np.testing.assert_allclose(shaper.amplitudes, np.array(amplitudes) / sum(amplitudes), rtol=0, atol=1e-6)


@pytest.mark.parametrize("kind", ["zv", "mzv", "zvd"])
@pytest.mark.parametrize("damping", [0.0, 0.03, 0.1, 0.3])
def test_zero_vibration_designs_leave_none_at_their_design_point(kind, damping):
    shaper = DESIGNS[kind](43.0, damping)
    assert residual_vibration(shaper, 43.0, damping) < 1e-12
    assert residual_vibration(shaper, 43.0 * 1.2, damping) > 0.02  # not zero everywhere


def test_mzv_also_cancels_at_five_thirds_of_its_frequency_undamped():
    shaper = DESIGNS["mzv"](30.0, 0.0)
    assert residual_vibration(shaper, 50.0, 0.0) < 1e-12


@pytest.mark.parametrize("kind", ["ei", "2hump_ei", "3hump_ei"])
def test_published_undamped_ei_shapers_meet_the_tolerance_exactly(kind):
    """The closed forms leave exactly V at the design frequency (EI, 3-hump) or none (2-hump: its
    humps are either side), and no more than V anywhere between the band's outer zeros."""
    exact = exact_undamped(kind)
    at_design = residual_vibration(exact, 1.0, 0.0)
    if kind == "2hump_ei":
        assert at_design < 1e-12
    else:
        assert at_design == pytest.approx(V_TOL, abs=1e-9)
    f = np.linspace(0.5, 1.5, 20001)
    v = residual_vibration(exact, f, 0.0)
    inside = f[v <= V_TOL + 1e-9]
    hump = v[(f > inside[0]) & (f < inside[-1])]
    assert hump.max() == pytest.approx(V_TOL, abs=1e-6)


@pytest.mark.parametrize(
    ("kind", "at_design"), [("ei", VIBRATION_TOLERANCE), ("2hump_ei", 0.0), ("3hump_ei", VIBRATION_TOLERANCE)]
)
@pytest.mark.parametrize("damping", [0.0, 0.05, 0.1])
def test_the_curve_fitted_ei_shapers_leave_what_the_definition_asks_within_the_fits_error(kind, at_design, damping):
    """The damped EI designs are curve fits: at the design point they leave the tolerance (EI,
    3-hump) or nothing (2-hump) within 0.35 percentage points, not to 1e-9 (e.g. EI 4.88 % undamped)."""
    shaper = DESIGNS[kind](50.0, damping)
    assert residual_vibration(shaper, 50.0, damping) == pytest.approx(at_design, abs=3.5e-3)


@pytest.mark.parametrize("kind", ["ei", "2hump_ei", "3hump_ei"])
def test_undamped_fits_are_close_to_the_closed_forms(kind):
    exact = exact_undamped(kind)
    fitted = DESIGNS[kind](1.0, 0.0)
    np.testing.assert_allclose(fitted.times_s, exact.times_s, atol=3e-3)
    np.testing.assert_allclose(fitted.amplitudes, exact.amplitudes, atol=2e-3)


def test_ei_takes_its_tolerance_as_a_parameter():
    loose = ei_shaper(40.0, 0.0, vibration_tolerance=0.1)
    assert residual_vibration(loose, 40.0, 0.0) == pytest.approx(0.1, abs=5e-3)
    assert residual_vibration(ei_shaper(40.0, 0.0), 40.0, 0.0) < residual_vibration(loose, 40.0, 0.0)


def test_design_shaper_names_an_unknown_kind():
    assert design_shaper("zvd", 30.0).damping_ratio == DEFAULT_DAMPING_RATIO
    with pytest.raises(ConfigError, match="kind"):
        design_shaper("zvdd", 30.0)


# --- residual vibration ---------------------------------------------------------------------------------------------


def test_residual_vibration_is_vectorised_and_broadcasts():
    shaper = zvd_shaper(30.0, 0.05)
    f = np.array([20.0, 30.0, 40.0])
    v = residual_vibration(shaper, f, 0.05)
    assert isinstance(v, np.ndarray) and v.shape == (3,)
    assert v.tolist() == pytest.approx([residual_vibration(shaper, x, 0.05) for x in f], abs=1e-15)
    grid = residual_vibration(shaper, f[:, None], np.array([0.0, 0.1]))
    assert grid.shape == (3, 2)
    assert grid[1, 0] == pytest.approx(residual_vibration(shaper, 30.0, 0.0), abs=1e-15)
    assert isinstance(residual_vibration(shaper, 30.0, 0.05), float)


def test_a_single_impulse_leaves_all_the_vibration():
    identity = Shaper("none", np.array([0.0]), np.array([1.0]), 1.0, 0.0)
    assert residual_vibration(identity, np.array([5.0, 50.0]), 0.3).tolist() == pytest.approx([1.0, 1.0])


# --- physics: a simulated mode ---------------------------------------------------------------------------------------

MODE_HZ, MODE_DAMPING, FS = 25.0, 0.03, 5000.0


def ringing_amplitude(setpoint: np.ndarray, end_s: float) -> float:
    """Amplitude of the free vibration of the mode (unity DC gain) after the set-point settles at ``end_s``,
    extrapolated back to ``end_s``: the load's deviation from its final value is fitted with the mode's decaying
    cosine and sine."""
    w = 2 * math.pi * MODE_HZ
    wd = w * math.sqrt(1 - MODE_DAMPING**2)
    t = np.arange(setpoint.size + round(0.4 * FS)) / FS
    u = np.concatenate([setpoint, np.full(t.size - setpoint.size, setpoint[-1])])
    _, y, _ = lsim(([w * w], [1.0, 2 * MODE_DAMPING * w, w * w]), u, t)
    after = t >= end_s + 1e-9
    tau = t[after] - end_s
    envelope = np.exp(-MODE_DAMPING * w * tau)
    basis = np.column_stack([envelope * np.cos(wd * tau), envelope * np.sin(wd * tau)])
    coefficients, *_ = np.linalg.lstsq(basis, y[after] - setpoint[-1], rcond=None)
    fit_error = np.abs(basis @ coefficients - (y[after] - setpoint[-1])).max()
    assert fit_error < 1e-3 * np.abs(coefficients).max() + 1e-12  # it is the free vibration of the mode
    return float(np.hypot(*coefficients))


@pytest.fixture(scope="module")
def move():
    # 20 ms of acceleration, half the mode's period: the trapezoid rings as much as it can.
    profile = trapezoid(0.01, 0.1, 5.0, FS)
    return profile, ringing_amplitude(profile.position_m, profile.duration_s)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("design_hz", [MODE_HZ, 1.1 * MODE_HZ], ids=["at_the_mode", "10pct_above"])
def test_a_shaped_moves_ringing_is_the_closed_form_residual_vibration(move, kind, design_hz):
    profile, unshaped = move
    assert unshaped > 1e-4  # 1 cm moved in 60 ms: the unshaped move rings
    shaper = DESIGNS[kind](design_hz, MODE_DAMPING)
    shaped = shaper.apply(profile.position_m, FS)
    assert shaped[-1] == profile.position_m[-1]
    ratio = ringing_amplitude(shaped, profile.duration_s + shaper.duration_s) / unshaped
    expected = residual_vibration(shaper, MODE_HZ, MODE_DAMPING)
    assert ratio == pytest.approx(expected, rel=0.01, abs=2e-4)
    if design_hz != MODE_HZ:
        assert expected > 0.01  # 10 % off, the check compares a clearly non-zero vibration


# --- apply and convolve ---------------------------------------------------------------------------------------------


def test_apply_delays_each_impulse_by_a_fractional_number_of_samples():
    fs = 1000.0
    shaper = zv_shaper(37.0, 0.07)  # half a damped period: 13.55 ms, not a whole number of samples
    x = np.concatenate([np.zeros(5), 0.5 * np.arange(200) / fs])
    y = shaper.apply(x, fs)
    assert y.size == x.size + math.ceil(shaper.duration_s * fs)
    # On a ramp, linear interpolation is exact: the shaped ramp lags by the impulses' centroid.
    lag_s = float(np.dot(shaper.amplitudes, shaper.times_s))
    k = np.arange(40, x.size)
    np.testing.assert_allclose(y[k], 0.5 * ((k - 5) / fs - lag_s), atol=1e-12)
    assert np.all(y[x.size + math.ceil(shaper.duration_s * fs) - 1 :] == x[-1])
    assert np.all(y[:5] == 0.0)


def test_apply_shapes_a_step_into_a_staircase_of_the_amplitudes():
    fs = 2000.0
    shaper = Shaper("test", np.array([0.0, 0.005, 0.010]), np.array([0.25, 0.5, 0.25]), 100.0, 0.0)
    y = shaper.apply(np.concatenate([np.zeros(3), np.ones(5)]), fs)
    assert y.tolist() == pytest.approx([0, 0, 0, 0.25] + [0.25] * 9 + [0.75] * 10 + [1.0] * 5)


def test_apply_refuses_bad_set_points():
    shaper = zv_shaper(30.0)
    with pytest.raises(DataError, match="NaN"):
        shaper.apply([0.0, np.nan], 1000.0)
    with pytest.raises(DataError, match="1-D"):
        shaper.apply(np.zeros((2, 2)), 1000.0)
    with pytest.raises(ConfigError, match="sample_rate_hz"):
        shaper.apply([0.0, 1.0], 0.0)


def test_two_convolved_zv_shapers_cancel_both_modes():
    low, high = zv_shaper(20.0, 0.05), zv_shaper(47.0, 0.02)
    both = low.convolve(high)
    assert both.kind == "zv*zv"
    assert both.frequency_hz == (20.0, 47.0) and both.damping_ratio == (0.05, 0.02)
    assert both.times_s.size == 4 and both.amplitudes.sum() == pytest.approx(1.0, abs=1e-12)
    assert both.duration_s == pytest.approx(low.duration_s + high.duration_s)
    assert residual_vibration(both, 20.0, 0.05) < 1e-12
    assert residual_vibration(both, 47.0, 0.02) < 1e-12
    assert residual_vibration(low, 47.0, 0.02) > 0.5  # one alone leaves the other mode ringing


def test_a_zv_shaper_convolved_with_itself_is_the_zvd_shaper():
    zv = zv_shaper(33.0, 0.08)
    square = zv.convolve(zv)
    zvd = zvd_shaper(33.0, 0.08)
    np.testing.assert_allclose(square.times_s, zvd.times_s, atol=1e-15)
    np.testing.assert_allclose(square.amplitudes, zvd.amplitudes, atol=1e-15)


def test_a_shaper_must_be_a_train_of_positive_impulses():
    with pytest.raises(DataError, match="sum to 1"):
        Shaper("bad", np.array([0.0, 0.01]), np.array([0.5, 0.6]), 50.0, 0.0)
    with pytest.raises(DataError, match="start at 0"):
        Shaper("bad", np.array([0.001, 0.01]), np.array([0.5, 0.5]), 50.0, 0.0)
    with pytest.raises(DataError, match="increase"):
        Shaper("bad", np.array([0.0, 0.0]), np.array([0.5, 0.5]), 50.0, 0.0)
    shaper = zv_shaper(30.0)
    with pytest.raises(ValueError):
        shaper.times_s[1] = 1.0  # read-only


# --- scoring ----------------------------------------------------------------------------------------------------------


def smoothing_mm(amplitudes, times, accel=5000.0, scv=5.0):
    """The firmware's smoothing estimate in its units (mm, mm/s^2, mm/s), written out plainly."""
    total = sum(amplitudes)
    centroid = sum(a * t for a, t in zip(amplitudes, times, strict=True)) / total
    offset_90 = offset_180 = 0.0
    for a, t in zip(amplitudes, times, strict=True):
        if t >= centroid:
            offset_90 += a * (scv + accel / 2 * (t - centroid)) * (t - centroid)
        offset_180 += a * accel / 2 * (t - centroid) ** 2
    return max(offset_90 * math.sqrt(2) / total, offset_180 / total)


def bisected_max_accel_mm(amplitudes, times, scv=5.0, target_mm=0.12):
    """The firmware's search for the largest acceleration within the smoothing target, in mm/s^2."""

    def ok(accel):
        return smoothing_mm(amplitudes, times, accel, scv) <= target_mm

    if not ok(1e-9):
        return 0.0
    left = right = 1.0
    while not ok(left):
        right, left = left, left / 2
    if right == left:
        while ok(right):
            right *= 2
    while right - left > 1e-8:
        middle = (left + right) / 2
        left, right = (middle, right) if ok(middle) else (left, middle)
    return left


@pytest.mark.parametrize("kind", KINDS)
def test_smoothing_and_max_acceleration_are_the_firmwares_in_si_units(kind):
    amplitudes, times = REFERENCES[kind](45.0, 0.1)
    shaper = DESIGNS[kind](45.0, 0.1)
    assert shaper_smoothing(shaper) == pytest.approx(smoothing_mm(amplitudes, times) * 1e-3, rel=1e-12)
    assert shaper_smoothing(shaper, 3.0, 0.01) == pytest.approx(smoothing_mm(amplitudes, times, 3000.0, 10.0) * 1e-3)
    assert max_acceleration(shaper) == pytest.approx(bisected_max_accel_mm(amplitudes, times) * 1e-3, rel=1e-9)
    assert max_acceleration(zv_shaper(5.0)) == 0.0  # the corner velocity alone smooths more than 0.12 mm


def test_score_is_the_worst_vibration_over_the_band_and_damping_ratios():
    shaper = zvd_shaper(40.0, 0.1)
    score = score_shaper(shaper, (36.0, 44.0), n=81)
    grid = residual_vibration(shaper, np.linspace(36.0, 44.0, 81)[:, None], np.array(TEST_DAMPING_RATIOS))
    assert score.worst_vibration == pytest.approx(grid.max(), abs=1e-15)
    assert score.worst_damping_ratio in TEST_DAMPING_RATIOS and 36.0 <= score.worst_frequency_hz <= 44.0
    assert score.smoothing == shaper_smoothing(shaper) and score.max_accel_mps2 == max_acceleration(shaper)
    narrow = score_shaper(shaper, (39.0, 41.0), damping_ratios=[0.1])
    assert narrow.worst_vibration < score.worst_vibration
    assert score.as_dict()["smoothing_m"] == score.smoothing


# --- the choice -------------------------------------------------------------------------------------------------------


def test_a_narrow_band_gets_a_short_shaper_and_a_wide_one_a_robust_shaper():
    narrow = choose_shaper([(MODE_HZ, MODE_DAMPING, 0.01 * MODE_HZ, 0.005)])
    wide = choose_shaper([(MODE_HZ, MODE_DAMPING, 0.15 * MODE_HZ, 0.005)])
    assert narrow.chosen.kind in ("zv", "mzv")
    assert wide.chosen.kind in ("ei", "2hump_ei", "3hump_ei")
    assert wide.shaper.duration_s > narrow.shaper.duration_s
    for choice in (narrow, wide):
        assert sorted(s.kind for s in choice.candidates) == sorted(KINDS)
        assert choice.chosen.worst_vibration <= choice.target_vibration
        assert choice.chosen.kind in choice.reason and choice.reason.endswith(".")
        passing = [s for s in choice.candidates if s.worst_vibration <= choice.target_vibration]
        assert choice.chosen.smoothing == min(s.smoothing for s in passing)
    # The narrow band is scored at +-5 % at least.
    assert narrow.chosen.frequency_intervals_hz[0] == pytest.approx((0.95 * MODE_HZ, 1.05 * MODE_HZ))
    assert narrow.chosen.damping_ratios[0] == pytest.approx((0.025, 0.03, 0.035))


def test_without_any_shaper_under_the_target_the_least_vibration_is_chosen():
    choice = choose_shaper([(40.0, 0.05, 16.0, None)], target_vibration=0.01)
    worst = [s.worst_vibration for s in choice.candidates]
    assert worst == sorted(worst) and worst[0] > 0.01
    assert choice.reason.startswith("no shaper")


def test_two_modes_are_shaped_by_convolved_shapers():
    choice = choose_shaper([(20.0, 0.05, None, None), (47.0, 0.02, 1.0, 0.005)], kinds=["zv", "zvd", "ei"])
    assert {s.kind for s in choice.candidates} == {"zv*zv", "zvd*zvd", "ei*ei"}
    assert len(choice.chosen.frequency_intervals_hz) == 2
    assert choice.chosen.damping_ratios[0] == pytest.approx((0.0375, 0.05, 0.075))  # no interval: the spread


def test_a_kind_whose_fit_does_not_cover_the_damping_is_left_out():
    choice = choose_shaper([(30.0, 0.35, None, None)])
    assert {s.kind for s in choice.candidates} == {"zv", "mzv", "zvd", "ei"}


# --- bad input --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("frequency_hz", [0.0, -10.0, math.nan, math.inf])
def test_a_frequency_that_is_not_positive_is_refused(kind, frequency_hz):
    with pytest.raises(ConfigError, match="frequency_hz"):
        DESIGNS[kind](frequency_hz, 0.1)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("damping", [-0.01, 1.0, 1.5, math.nan])
def test_a_damping_ratio_outside_zero_to_one_is_refused(kind, damping):
    with pytest.raises(ConfigError, match="damping_ratio"):
        DESIGNS[kind](30.0, damping)


def test_a_damping_ratio_beyond_a_fits_range_is_refused():
    with pytest.raises(ConfigError, match="damping_ratio.*3hump_ei"):
        DESIGNS["3hump_ei"](30.0, 0.25)


def test_residual_vibration_and_scoring_refuse_bad_arguments():
    shaper = zv_shaper(30.0)
    with pytest.raises(ConfigError, match="frequency_hz"):
        residual_vibration(shaper, np.array([10.0, 0.0]), 0.1)
    with pytest.raises(ConfigError, match="damping_ratio"):
        residual_vibration(shaper, 30.0, 1.0)
    with pytest.raises(ConfigError, match="frequency_hz_interval"):
        score_shaper(shaper, (40.0, 30.0))
    with pytest.raises(ConfigError, match="damping_ratios"):
        score_shaper(shaper, (30.0, 40.0), damping_ratios=[1.2])
    with pytest.raises(ConfigError, match="modes"):
        choose_shaper([])
    with pytest.raises(ConfigError, match=r"modes\[0\]\.frequency_hz"):
        choose_shaper([(0.0, 0.1, None, None)])
    with pytest.raises(ConfigError, match=r"modes\[1\]\.damping_ratio"):
        choose_shaper([(30.0, 0.1, None, None), (40.0, 1.0, None, None)])
