"""`hilident identify` on a public measured record: the DaISy flexible robot arm (tests/data/README.md).

One period (1024 samples) of a periodic sine sweep into a flexible arm with
two lightly damped modes. The modes ``identify`` reports are compared with an
independent estimate computed here, without any of hilident's numerics: the
full-record DFT at the excited lines, the noise of each line from the
non-excited lines beside it, and a noise-weighted nonlinear least-squares fit
of one mode plus a constant to the lines around each peak. A time-domain
ARX fit cross-checks that estimate.

Frequencies are compared in cycles per sample (the record's sampling period
was never published), so the check holds at any declared rate.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from hilident.cli.main import main

DATA = Path(__file__).parent / "data" / "daisy_robot_arm.csv"
PERIOD = 1024

#: Frequency agreement, relative. The project's acceptance for a resonance; 3.5 noise standard deviations of the
#: reference at the first mode, and a seventh of the spacing of the excited lines (every other DFT line), so an
#: answer taken at the nearest excited line fails it (59 and 129 lines are 1.1 % and 0.6 % off).
FREQUENCY_TOLERANCE = 0.005
#: Damping agreement, relative. The first mode's half-power bandwidth (0.37 lines) is a fifth of the line spacing
#: and its one line near the peak has a weak input: the reference's noise standard deviation is 36 % there (5 % at
#: the second mode) and the independent estimates spread over +-12 %. 30 % still fails a pole on the axis
#: (zeta 0) and the factor 5 a half-power reading on the 2-line grid gives.
DAMPING_TOLERANCE = 0.30
#: Lines either side of a peak (in DFT lines) that the local fit uses: three excited lines each side.
LOCAL_HALF_WIDTH = 6


def load_record() -> tuple[np.ndarray, np.ndarray]:
    """Input (reaction torque) and output (tip acceleration) columns, unscaled."""
    d = np.loadtxt(DATA, delimiter=",")
    return d[:, 0], d[:, 1]


def excited_lines(U: np.ndarray) -> np.ndarray:
    """The odd DFT lines up to the last odd one within 20 dB of the strongest (the sweep excites odd lines only).

    The measured input drops at a resonance (line 59 holds 0.62 where its
    neighbours hold 2 to 10), so the set follows the design, not a threshold
    on every line.
    """
    odd = np.arange(1, len(U), 2)
    strong = odd[np.abs(U[odd]) > 0.1 * np.abs(U).max()]
    return odd[odd <= strong.max()]


def line_variance(X: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Noise power at lines ``k``: the mean power of the two non-excited lines either side."""
    return (np.abs(X[k - 1]) ** 2 + np.abs(X[k + 1]) ** 2) / 2.0


def _one_mode(p, x):
    kn, zeta, a_re, a_im, c_re, c_im = p
    return (a_re + 1j * a_im) * -(x**2) / (kn**2 - x**2 + 2j * zeta * kn * x) + (c_re + 1j * c_im)


def fit_mode(k: np.ndarray, H: np.ndarray, sigma: np.ndarray, peak: int) -> tuple[float, float, float, float]:
    """One mode (acceleration response) plus a constant, fitted to the lines around ``peak``.

    Returns
    -------
    tuple
        Natural frequency (DFT lines), damping ratio, and their standard
        deviations from the noise (``sigma``: standard deviation of each
        real and imaginary part of ``H``).
    """
    near = np.abs(k - peak) <= LOCAL_HALF_WIDTH
    x, h, w = k[near].astype(float), H[near], 1.0 / sigma[near]

    def residual(p):
        e = (_one_mode(p, x) - h) * w
        return np.concatenate([e.real, e.imag])

    starts = [(kn, z) for kn in np.linspace(peak - 1.0, peak + 2.0, 13) for z in (0.002, 0.005, 0.02)]
    best = min(
        (least_squares(residual, [kn, z, 0.1, 0.0, 0.0, 0.0], x_scale="jac") for kn, z in starts), key=lambda r: r.cost
    )
    cov = np.linalg.inv(best.jac.T @ best.jac)
    return best.x[0], best.x[1], float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))


def independent_modes() -> list[dict]:
    """The record's modes: frequency in cycles per sample, damping ratio, and their standard deviations."""
    u, y = load_record()
    U, Y = np.fft.rfft(u), np.fft.rfft(y)
    k = excited_lines(U)
    H = Y[k] / U[k]
    var_h = (line_variance(Y, k) + np.abs(H) ** 2 * line_variance(U, k)) / np.abs(U[k]) ** 2
    sigma = np.sqrt(var_h / 2.0)
    mag = np.abs(H)
    peaks = [
        i for i in range(1, len(k) - 1) if mag[i] > mag[i - 1] and mag[i] > mag[i + 1] and mag[i] > 5 * np.median(mag)
    ]
    modes = []
    for i in peaks:
        kn, zeta, s_kn, s_zeta = fit_mode(k, H, sigma, int(k[i]))
        modes.append({"f": kn / PERIOD, "zeta": zeta, "sd_f": s_kn / PERIOD, "sd_zeta": s_zeta})
    return modes


def arx_modes(order: int) -> list[tuple[float, float]]:
    """Lightly damped poles (cycles per sample, damping) of a least-squares ARX model of the periodic record.

    The record is one period of a periodic steady state, so the regression
    wraps around its end instead of dropping the first ``order`` rows.
    """
    u, y = load_record()
    cols = [-np.roll(y, i) for i in range(1, order + 1)] + [np.roll(u, i) for i in range(order + 1)]
    theta = np.linalg.lstsq(np.column_stack(cols), y, rcond=None)[0]
    z = np.roots(np.concatenate([[1.0], theta[:order]]))
    s = np.log(z[z.imag > 0])  # per sample
    return sorted((abs(p) / (2 * np.pi), -p.real / abs(p)) for p in s)


@pytest.fixture(scope="module")
def reference():
    modes = independent_modes()
    assert len(modes) == 2, modes
    return modes


def test_the_reference_finds_two_modes_and_a_time_domain_fit_agrees(reference):
    for order in (8, 10, 12):
        poles = arx_modes(order)
        for mode in reference:
            f, zeta = min(poles, key=lambda p: abs(p[0] - mode["f"]))
            assert f == pytest.approx(mode["f"], rel=0.002), (order, poles)
            assert zeta == pytest.approx(mode["zeta"], rel=DAMPING_TOLERANCE), (order, poles)
    # the tolerances above are wider than the reference's own uncertainty at the frequency
    assert all(3.5 * m["sd_f"] <= FREQUENCY_TOLERANCE * m["f"] for m in reference)


def _agrees(found: list[tuple[float, float]], reference: list[dict]) -> None:
    assert len(found) == len(reference), found
    for (f, zeta), mode in zip(sorted(found), reference, strict=True):
        assert f == pytest.approx(mode["f"], rel=FREQUENCY_TOLERANCE)
        assert zeta == pytest.approx(mode["zeta"], rel=DAMPING_TOLERANCE)


@pytest.mark.parametrize("rate_hz", [1024.0, 1.0])
def test_identify_reports_the_two_modes_and_nothing_else(tmp_path, reference, rate_hz):
    config = tmp_path / "arm.toml"
    config.write_text(
        f'[data]\ntorque = "0"\noutput = "1"\nsample_rate_hz = {rate_hz}\nperiod_samples = {PERIOD}\n'
        f"[model]\nfilter_rate_hz = {4 * rate_hz}\n"
    )  # notches for a drive at 4x the data's rate
    out = tmp_path / "o"
    assert main(["identify", str(DATA), "--config", str(config), "--out", str(out), "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())

    _agrees([(r["frequency_hz"] / rate_hz, r["damping_ratio"]) for r in summary["resonances"]], reference)
    model = summary["plant_model"]
    _agrees([(r["frequency_hz"] / rate_hz, r["damping_ratio"]) for r in model["resonances"]], reference)
    assert model["stable"] is True
    assert not model["flagged_poles"] and not model["real_poles_hz"]
    # the noise of the lines the sweep leaves out supports both modes: they are notched
    assert all(r["coherence"] >= 0.8 and r["notchable"] for r in summary["resonances"])
    u, _ = load_record()
    power = np.abs(np.fft.rfft(u)) ** 2
    odd_above_floor = np.count_nonzero(power[1::2] > 1e-4 * power.max())  # the 40 dB floor, on the odd lines
    assert summary["measurement"]["one_period"] == {
        "excited_lines": odd_above_floor,
        "line_step": 2,
        "noise_from_non_excited_lines": True,
    }
    centres = [n["center_hz"] / rate_hz for n in summary["notch_filters"]]
    assert len(centres) == 2 and summary["notch_skipped_reason"] is None
    for c, mode in zip(sorted(centres), reference, strict=False):
        assert c == pytest.approx(mode["f"], rel=FREQUENCY_TOLERANCE)


def test_identify_says_why_no_notch_when_the_evidence_is_short(tmp_path):
    config = tmp_path / "arm.toml"
    config.write_text(
        f'[data]\ntorque = "0"\noutput = "1"\nsample_rate_hz = 1024.0\nperiod_samples = {PERIOD}\n'
        "[identification]\ncoherence_threshold = 0.999\n"
    )  # more than one period's noise allows
    out = tmp_path / "o"
    assert main(["identify", str(DATA), "--config", str(config), "--out", str(out), "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["notch_filters"] == []
    assert "no notch was designed" in summary["notch_skipped_reason"]
    assert summary["notch_skipped_reason"] in summary["warnings"]
