"""Host-side shaping of a set-point: causal, unity DC gain, exact end, the notch really removes the mode."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad, BiquadSection
from hilident.filters.notch import NotchSpec, design_notch
from hilident.motion.profiles import s_curve, trapezoid
from hilident.motion.shaping import chain_dc_gain, filter_setpoint, shape_move

FS = 4000.0


def notch(center_hz=21.8, width_hz=6.0, depth_db=40.0, fs=FS):
    return design_notch(NotchSpec(center_hz=center_hz, width_hz=width_hz, depth_db=depth_db), fs)


def test_filter_matches_the_drives_own_biquad_sections_sample_by_sample():
    chain = [notch(), notch(60.0, 10.0, 20.0)]
    x = 0.05 + np.cumsum(np.random.default_rng(1).normal(size=2000)) * 1e-4
    sections = [BiquadSection(c) for c in chain]
    expected = []
    for v in x - x[0]:
        for s in sections:
            v = s.step(v)
        expected.append(v + x[0])
    assert np.allclose(filter_setpoint(x, chain), expected, rtol=0, atol=1e-12)


def test_filter_is_causal_and_starts_without_a_transient():
    x = np.concatenate([np.full(100, 0.3), np.linspace(0.3, 0.5, 300)])
    y = filter_setpoint(x, [notch()])
    assert np.all(y[:100] == 0.3)  # nothing happens before the input moves
    late = x.copy()
    late[250:] += 1.0  # a change later in the input does not touch earlier output
    assert np.array_equal(filter_setpoint(late, [notch()])[:250], y[:250])


@settings(max_examples=40, deadline=None)
@given(st.floats(-1.0, 1.0).filter(lambda d: abs(d) > 1e-3), st.floats(5.0, 200.0), st.floats(1.0, 30.0), st.booleans())
def test_shaped_move_ends_exactly_where_asked_and_keeps_its_dwell(distance, center_hz, width_hz, curved):
    move = s_curve(distance, 0.4, 3.0, 300.0, FS, 0.3) if curved else trapezoid(distance, 0.4, 3.0, FS, 0.3)
    chain = [notch(center_hz, min(width_hz, center_hz), 30.0)]
    shaped = shape_move(move, chain)
    p = shaped.profile
    i = p.move_end_index
    assert np.all(p.position_m[i:] == distance) and not np.any(p.velocity_mps[i:])
    assert p.dwell_s == pytest.approx(move.dwell_s)
    assert p.move_end_s == pytest.approx(move.move_end_s + shaped.added_delay_s)
    # before the end it is the filtered move held at its end; from the end on that stays within the tolerance
    held = np.concatenate([move.position_m[: move.move_end_index + 1], np.full(4 * p.position_m.size, distance)])
    reference = filter_setpoint(held, chain)
    assert np.allclose(p.position_m[:i], reference[:i], rtol=0, atol=1e-15)
    assert np.all(np.abs(reference[i:] - distance) <= shaped.tolerance_m)
    assert shaped.tolerance_m == pytest.approx(1e-5 * abs(distance))
    assert shaped.dc_gain == pytest.approx(1.0, abs=1e-9)


def test_shaping_removes_the_notch_frequency_from_the_set_point():
    move = trapezoid(0.2, 0.3, 2.0, FS, 1.0)
    shaped = shape_move(move, [notch(21.8, 6.0, 40.0)])

    def content(x, f_hz):
        n = 2**16
        spectrum = np.abs(np.fft.rfft(np.diff(x), n))  # the velocity's spectrum: the step's DC is gone
        return spectrum[np.argmin(np.abs(np.fft.rfftfreq(n, 1 / FS) - f_hz))]

    ratio_db = 20 * np.log10(content(move.position_m, 21.8) / content(shaped.profile.position_m, 21.8))
    assert ratio_db > 25.0
    # far from the notch the set-point is not changed much: the same move, a little later
    assert content(shaped.profile.position_m, 2.0) == pytest.approx(content(move.position_m, 2.0), rel=0.1)


def test_chain_dc_gain_is_checked():
    half = Biquad((0.5, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert chain_dc_gain([notch(), half]) == pytest.approx(0.5)
    with pytest.raises(DataError, match="DC gain 0.5"):
        shape_move(trapezoid(0.1, 0.3, 2.0, FS), [notch(), half])


def test_unstable_or_foreign_sections_are_data_errors_naming_the_section():
    unstable = Biquad((1.0, 0.0, 0.0), (1.0, -2.1, 1.1))
    with pytest.raises(DataError, match="section 1: unstable"):
        shape_move(trapezoid(0.1, 0.3, 2.0, FS), [notch(), unstable])
    b, a = signal.iirnotch(20.0, 3.0, fs=FS)
    with pytest.raises(DataError, match="section 0: expected a Biquad"):
        filter_setpoint(np.zeros(10), [(b, a)])  # type: ignore[list-item]
    with pytest.raises(DataError, match="NaN"):
        filter_setpoint(np.array([0.0, np.nan]), [notch()])


def test_no_sections_leave_the_move_as_it_is():
    move = trapezoid(0.1, 0.3, 2.0, FS, 0.2)
    shaped = shape_move(move, [])
    assert shaped.added_delay_s == 0.0
    assert np.array_equal(shaped.profile.position_m, move.position_m)


def test_a_set_point_that_cannot_settle_in_time_is_refused():
    # a pole at radius 0.999999: settling to 2 um takes far longer than 0.05 s
    slow = Biquad((1e-6, 0.0, 0.0), (1.0, -0.999999, 0.0))
    with pytest.raises(DataError, match="did not settle"):
        shape_move(trapezoid(0.2, 0.3, 2.0, FS), [slow], max_extension_s=0.05)


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        (dict(tolerance_m=0.0), "tolerance_m"),
        (dict(tolerance_m=float("nan")), "tolerance_m"),
        (dict(max_extension_s=-1.0), "max_extension_s"),
    ],
)
def test_bad_tolerances_are_config_errors(kwargs, key):
    with pytest.raises(ConfigError) as err:
        shape_move(trapezoid(0.2, 0.3, 2.0, FS), [notch()], **kwargs)
    assert err.value.key == key
