"""Content of the figures (hilident.plots and report's run/identify sets): labels, units, lines, bands; no pixels."""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.plots import figures as report
from hilident.plots.bode import PER_CURVE, bode_figure, branch_phase_deg
from hilident.plots.common import channel_unit, config_name, plot_title, ratio_unit
from hilident.plots.friction import friction_figure, friction_parameter_lines
from hilident.plots.greybox import greybox_figure, simulate_greybox

FS = 4000.0


def _msd_velocity(f_hz, m=5.0, b=20.0, k=2.0e4):
    """Velocity over force of a mass-spring-damper, (m/s)/N: +90 deg below the resonance, -90 above."""
    s = 2j * np.pi * np.asarray(f_hz)
    return s / (m * s**2 + b * s + k)


def _lines(ax, label):
    return [ln for ln in ax.get_lines() if ln.get_label() == label]


def _drawn(fig):
    fig.canvas.draw()  # a FigureCanvasBase renders with Agg on savefig; draw() lays out the legends
    return fig


def _frf(f, h, coherence=None):
    return SimpleNamespace(frequency_hz=f, response=h, coherence=coherence)


@pytest.fixture
def msd_bode():
    f = np.linspace(0.0, 500.0, 2001)
    rng = np.random.default_rng(3)
    coh = np.where(f > 200.0, 0.3, 0.98)  # noise above the band
    coh[(f > 60) & (f < 62)] = 0.5  # a low-coherence dip inside the band
    h = _msd_velocity(np.maximum(f, 1e-3)) * np.exp(1j * np.where(f > 200, rng.uniform(-3, 3, f.size), 0.0))
    b, a = signal.iirnotch(10.07, 3.0, fs=FS)
    stored = Biquad(tuple(b), tuple(a))
    fine = np.geomspace(1.0, 500.0, 4000)
    designed = Biquad(*(tuple(x) for x in signal.iirnotch(10.0, 3.0, fs=FS)))
    fig = bode_figure(
        [("plant (net torque to output)", _frf(f, h, coh)), ("excitation to output", _frf(f, 1.05 * h, coh))],
        resonances=[SimpleNamespace(frequency_hz=10.07)],
        notch_response=(fine, designed.response(fine, FS)),
        coherence_threshold=0.8,
        model=("fitted TF, 1 zero / 2 poles, MDL", fine, _msd_velocity(fine)),
        bounds_db=(np.full(f.size, -0.5), np.full(f.size, 0.5)),
        title=plot_title("emulated-msd.toml", dt.datetime(2026, 11, 23, 19, 40, tzinfo=dt.UTC), "Bode"),
        magnitude_unit=ratio_unit("m/s", "N"),
        band_hz=(2.0, 200.0),
        stored_notch=(fine, stored.response(fine, FS)),
    )
    return _drawn(fig), f


def test_bode_magnitude_says_its_unit_and_the_title_config_and_date(msd_bode):
    fig, _ = msd_bode
    ax_mag, ax_phase, ax_coh = fig.axes[:3]
    assert ax_mag.get_ylabel() == "magnitude [dB re 1 (m/s)/N]"
    assert ax_phase.get_ylabel() == "phase [deg]" and ax_coh.get_ylabel() == "coherence [-]"
    assert ax_coh.get_xlabel() == "frequency [Hz]"
    assert fig.get_suptitle() == "Bode: emulated-msd.toml, 2026-11-23 19:40 UTC"


def test_bode_greys_lines_outside_the_band_and_under_the_threshold(msd_bode):
    fig, f = msd_bode
    ax_mag = fig.axes[0]
    plant = _lines(ax_mag, "plant (net torque to output)")[0]
    x, y = plant.get_xdata(), np.asarray(plant.get_ydata())
    assert np.all(np.isnan(y[x > 200.0]))  # outside the band: not in colour
    assert np.all(np.isnan(y[(x > 60) & (x < 62)]))  # coherence 0.5 < 0.8 inside the band
    assert np.all(np.isfinite(y[(x >= 2.0) & (x <= 50.0)]))
    grey = _lines(ax_mag, "outside band or coherence < 0.8")
    assert len(grey) == 1 and np.all(np.isfinite(grey[0].get_ydata()))  # greyed, not hidden
    # the region beyond the band is shaded on all three axes, and the view reaches past it
    for ax in fig.axes[:3]:
        spans = [p for p in ax.patches if p.get_x() >= 200.0 - 1e-9]
        assert spans, ax.get_ylabel()
    lo, hi = ax_mag.get_xlim()
    assert lo == pytest.approx(1.0) and hi == pytest.approx(400.0)


def test_bode_phase_is_on_the_branch_of_the_band(msd_bode):
    fig, _ = msd_bode
    phase = _lines(fig.axes[1], "plant (net torque to output)")[0]
    y = np.asarray(phase.get_ydata())
    first = np.flatnonzero(np.isfinite(y))[0]
    assert -180.0 < y[first] <= 180.0
    assert y[first] == pytest.approx(90.0, abs=3.0)  # velocity over force starts at +90, not -270
    assert np.nanmax(y) < 100.0 and np.nanmin(y) > -100.0
    assert fig.axes[1].get_ylim()[1] - fig.axes[1].get_ylim()[0] < 360.0  # not thousands of degrees
    model = _lines(fig.axes[1], "fitted TF, 1 zero / 2 poles, MDL")[0]
    assert np.allclose(
        np.interp(20.0, model.get_xdata(), model.get_ydata()), np.degrees(np.angle(_msd_velocity(20.0))), atol=1.0
    )


def test_bode_notches_model_confidence_and_legend_placement(msd_bode):
    fig, _ = msd_bode
    ax_mag, _, ax_coh = fig.axes[:3]
    stored = _lines(ax_mag, "stored notch, read back [dB re 1]")[0]
    designed = _lines(ax_mag, "designed notch [dB re 1]")[0]
    assert stored.get_xdata()[np.argmin(stored.get_ydata())] == pytest.approx(10.07, rel=2e-3)
    assert designed.get_xdata()[np.argmin(designed.get_ydata())] == pytest.approx(10.0, rel=2e-3)
    assert _lines(ax_mag, "fitted TF, 1 zero / 2 poles, MDL")
    band = [c for c in ax_mag.collections if c.get_label().startswith("95 % confidence")]
    assert len(band) == 1 and band[0].get_alpha() >= 0.2
    assert "±0.5 dB" in band[0].get_label()
    legend = ax_mag.get_legend()
    labels = [t.get_text() for t in legend.get_texts()]
    assert {
        "plant (net torque to output)",
        "excitation to output",
        "resonance",
        "outside analysis band",
        "stored notch, read back [dB re 1]",
    } <= set(labels)
    for ax in (ax_mag, ax_coh):  # beside the data, not on it
        assert ax.get_legend().get_window_extent().x0 >= ax.get_window_extent().x1
    coherence = [
        ln for ln in ax_coh.get_lines() if not ln.get_label().startswith("_") and ln.get_label() != "threshold 0.8"
    ]
    assert len(coherence) == 2
    styles = {(ln.get_color(), ln.get_linestyle(), ln.get_marker()) for ln in coherence}
    assert len(styles) == 2 and len({s[1] for s in styles}) == 2 and len({s[2] for s in styles}) == 2


def test_bode_frequency_ticks_are_distinct_plain_numbers():
    f = np.geomspace(0.05, 3.0, 200)
    fig = _drawn(bode_figure([("plant", _frf(f, _msd_velocity(f, k=5.0)))], magnitude_unit="m/N"))
    ax = fig.axes[2]
    lo, hi = ax.get_xlim()
    labels = [t.get_text() for t, x in zip(ax.get_xticklabels(), ax.get_xticks(), strict=True) if lo <= x <= hi]
    labels = [s for s in labels if s]
    assert len(labels) >= 3 and len(labels) == len(set(labels)), labels
    assert "0.05" in labels and "0.1" in labels and "0.2" in labels
    assert fig.axes[0].get_ylabel() == "magnitude [dB re 1 m/N]"
    per_curve = bode_figure([("plant [m/N]", _frf(f, _msd_velocity(f, k=5.0)))], magnitude_unit=PER_CURVE)
    assert per_curve.axes[0].get_ylabel() == "magnitude [dB re 1, units in legend]"


def test_bode_without_unit_or_band_says_so():
    f = np.geomspace(1, 100, 50)
    fig = bode_figure([("plant", _frf(f, 1 / (1j * f + 1)))])
    assert fig.axes[0].get_ylabel() == "magnitude [dB re 1, unit not recorded]"
    assert not fig.axes[0].patches  # no band given: nothing greyed
    with pytest.raises(DataError, match="band_hz"):
        bode_figure([("plant", _frf(f, 1 / (1j * f + 1)))], band_hz=(50.0, 10.0))


def test_branch_phase_starts_in_the_principal_interval_and_keeps_outside_lines_near_the_band():
    f = np.geomspace(1, 100, 300)
    h = -_msd_velocity(f, k=4e3) * np.exp(-1j * 2 * np.pi)  # starts near -90 deg
    in_band = (f >= 2) & (f <= 50)
    phase = branch_phase_deg(h * np.exp(-2j * np.pi), in_band)  # a whole turn off: same branch
    first = np.flatnonzero(in_band)[0]
    assert -180 < phase[first] <= 180
    assert np.allclose(phase, branch_phase_deg(h, in_band))
    noisy = h * np.exp(1j * np.where(f > 50, np.random.default_rng(0).uniform(-3, 3, f.size), 0) * 4)
    out = branch_phase_deg(noisy, in_band)
    last = np.flatnonzero(in_band)[-1]
    assert np.all(np.abs(out[last + 1 :] - out[last]) <= 180.0 + 1e-9)


def test_units_and_titles():
    assert channel_unit("velocity_mps") == "m/s" and channel_unit("position_m") == "m"
    assert channel_unit("torque_nm") == "N·m" and channel_unit("x") == ""
    assert ratio_unit("m/s", "N*m") == "(m/s)/(N·m)"
    assert ratio_unit("m", "N") == "m/N" and ratio_unit("m/s", "m/s") == "(m/s)/(m/s)"
    assert ratio_unit("m/s", "1") == ""  # "1" is no unit: nothing is invented
    assert config_name("run/identification.h5 (config_toml attribute)") == "identification.h5"
    assert config_name("configs/emulated-msd.toml") == "emulated-msd.toml"


def test_stored_notch_from_the_summary_read_back():
    b, a = signal.iirnotch(20.0, 4.0, fs=FS)
    summary = {
        "notch_filters": [{"slot": 1, "sample_rate_hz": FS}],
        "upload": {"slots": [{"slot": 1, "readback_b": list(b), "readback_a": list(a)}]},
    }
    f = np.linspace(10, 30, 2001)
    got = report.stored_notch_response(summary, f)
    assert got is not None
    assert f[np.argmin(np.abs(got[1]))] == pytest.approx(20.0, abs=0.02)
    assert report.stored_notch_response({"upload": {"slots": []}}, f) is None
    assert report.stored_notch_response(None, f) is None


def test_model_label_says_zeros_and_poles():
    model = SimpleNamespace(fit=SimpleNamespace(n_num=3, n_den=3, integrators=1), criterion="mdl")
    assert report.model_label(model) == "fitted TF, 3 zeros / 4 poles (1 integrator), MDL"


# --------------------------------------------------------------------------- friction


def test_friction_names_the_model_and_its_parameters_with_units():
    v = np.concatenate([-np.geomspace(1e-3, 0.3, 10), np.geomspace(1e-3, 0.3, 10)])
    tau = np.sign(v) * (0.2 + 2.0 * np.abs(v))
    params = {"Fc": 0.2, "Fs": 0.35, "Fv": 2.01, "vs": 0.01, "delta_v": 1.0, "delta_s": 2.0}
    fig = friction_figure(
        v,
        tau,
        v,
        tau,
        "emulated-gantry.toml, 2026-11-23 19:40 UTC",
        structure="stribeck",
        params=params,
        stderr={"Fv": 0.03},
    )
    ax = fig.axes[0]
    assert ax.get_title() == "Stribeck friction — emulated-gantry.toml, 2026-11-23 19:40 UTC"
    assert ax.get_xlabel() == "velocity [m/s]" and ax.get_ylabel() == "friction torque [N·m]"
    text = "\n".join(t.get_text() for t in ax.texts)
    assert "Fv = 2.01 ± 0.03 N·m/(m/s)" in text and "Fc = 0.2 N·m" in text and "vs = 0.01 m/s" in text
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["measured (steady state)", "fit: Stribeck friction"]
    assert len([ln for ln in ax.get_lines() if ln.get_color() == "tab:orange"]) == 2  # both branches


def test_friction_coulomb_viscous_shows_only_its_parameters():
    params = {"Fc": 0.21, "Fs": 0.21, "Fv": 2.0, "vs": 0.01, "delta_v": 1.0, "delta_s": 2.0}
    assert friction_parameter_lines("coulomb_viscous", params) == ["Fc = 0.21 N·m", "Fv = 2 N·m/(m/s)"]
    fig = friction_figure([-1, -0.5, 0.5, 1], [-2, -1, 1, 2], structure="coulomb_viscous", params=params)
    assert fig.axes[0].get_title() == "Coulomb + viscous friction"


# --------------------------------------------------------------------------- grey-box


def _msd_record(m=5.0, b=20.0, k=2.0e4, seconds=4.0, rate=1000.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    force = 50.0 * signal.chirp(t, 1.0, t[-1], 40.0)
    sys = signal.cont2discrete(([1.0], [m, b, k]), 1 / rate, method="zoh")
    x = signal.lfilter(np.squeeze(sys[0]), sys[1], force) + rng.normal(0, 1e-6, t.size)
    return force, x


def test_simulated_msd_matches_with_the_true_parameters_and_not_with_wrong_ones():
    force, x = _msd_record()
    good = simulate_greybox("mass_spring_damper", {"m": 5.0, "b": 20.0, "k": 2.0e4}, force, x, 1000.0, 40.0)
    bad = simulate_greybox("mass_spring_damper", {"m": 5.0, "b": 20.0, "k": 3.0e4}, force, x, 1000.0, 40.0)
    assert good.name == "position" and good.unit == "m"
    assert good.fit_percent > 95.0
    assert bad.fit_percent < good.fit_percent - 30.0
    with pytest.raises(DataError, match="parameter 'k'"):
        simulate_greybox("mass_spring_damper", {"m": 5.0, "b": 20.0}, force, x, 1000.0, 40.0)
    with pytest.raises(DataError, match="kind"):
        simulate_greybox("three_mass", {}, force, x, 1000.0, 40.0)


def test_simulated_rigid_axis_velocity_follows_the_measurement():
    rate, M, Fv, Fc = 1000.0, 2.0, 3.0, 0.5
    t = np.arange(6000) / rate
    force = 8.0 * np.sin(2 * np.pi * 0.7 * t) + 3.0 * np.sin(2 * np.pi * 3.1 * t)
    v = np.zeros_like(t)
    for i in range(1, t.size):  # fine Euler integration of the truth
        vi = v[i - 1]
        for _ in range(10):
            vi += (force[i - 1] - Fv * vi - Fc * np.sign(vi)) / M / (10 * rate)
        v[i] = vi
    q = np.cumsum(v) / rate
    sim = simulate_greybox("rigid_axis", {"M": M, "Fv": Fv, "Fc": Fc, "offset": 0.0}, force, q, rate, 20.0)
    assert sim.name == "velocity" and sim.unit == "m/s"
    assert sim.fit_percent > 90.0
    assert "filter settling" in sim.note


def test_greybox_figure_shows_compare_and_residual_tests():
    force, x = _msd_record()
    sim = simulate_greybox("mass_spring_damper", {"m": 5.0, "b": 20.0, "k": 2.0e4}, force, x, 1000.0, 40.0)
    fit = SimpleNamespace(params={"m": 5.0, "b": 20.0, "k": 2.0e4}, names=("m", "b", "k"))
    rng = np.random.default_rng(1)
    fig = greybox_figure(
        "mass_spring_damper",
        fit,
        {"estimation data": sim, "holdout": sim},
        {"estimation data": (rng.standard_normal(3000), rng.standard_normal(3000))},
        title="identify msd.csv, 2026-11-23 19:40 UTC",
        regression_fit_percent={"estimation data": 97.5},
    )
    axes = np.asarray(fig.axes).reshape(2, 3)
    compare, auto, cross = axes[0]
    assert compare.get_ylabel() == "position [m]" and compare.get_xlabel() == "time [s]"
    labels = [t.get_text() for t in compare.get_legend().get_texts()]
    assert labels[0] == "measured" and labels[1].startswith("simulated mass_spring_damper (fit ")
    assert float(labels[1].split("fit ")[1].split(" %")[0]) > 95.0
    assert "equation fit 97.5 %" in compare.get_title()
    for ax in (auto, cross):
        assert [t.get_text() for t in ax.get_legend().get_texts()][0].startswith("99 % band")
        assert ax.patches  # the band is drawn
        assert ax.get_xlabel() == "lag [samples]"
    assert "white: yes" in auto.get_title()  # white noise passes
    assert "m = 5, b = 20, k = 2e+04" in fig.get_suptitle()
    assert [t.get_text() for t in axes[1][1].texts] == ["no residuals"]
    with pytest.raises(DataError, match="no record"):
        greybox_figure("mass_spring_damper", fit, {}, {})
    # a record that could not be simulated, or has too few residuals, says why instead of failing the command
    fig = greybox_figure(
        "mass_spring_damper",
        fit,
        {"short.csv": "no simulation: 3 samples are too few"},
        {"short.csv": (np.arange(2.0), np.arange(2.0))},
    )
    assert fig.axes[0].texts[0].get_text() == "no simulation: 3 samples are too few"
    assert fig.axes[1].texts[0].get_text().startswith("no residual test:")
    assert fig.get_suptitle() == "mass_spring_damper: m = 5, b = 20, k = 2e+04"


# --------------------------------------------------------------------------- a run's set


def test_plot_run_passes_units_band_title_and_the_stored_notch(tmp_path, monkeypatch):
    f = np.linspace(0.5, 100.0, 200)
    frf = SimpleNamespace(frequency_hz=f, response=_msd_velocity(f), coherence=np.ones_like(f), n_averages=1)
    plant = SimpleNamespace(plant=frf, loop=frf, resonances=[], model=None)
    b, a = signal.iirnotch(10.0, 3.0, fs=FS)
    design = SimpleNamespace(
        spec=SimpleNamespace(center_hz=10.0, width_hz=3.3), biquad=Biquad(tuple(b), tuple(a)), sample_rate_hz=FS, slot=0
    )
    summary = {
        "config": "configs/emulated-msd.toml",
        "excitation": {"unit": "m/s"},
        "notch_filters": [{"slot": 0, "sample_rate_hz": FS}],
        "upload": {"slots": [{"slot": 0, "readback_b": list(b), "readback_a": list(a)}]},
    }
    seen = {}
    monkeypatch.setattr(report, "plot_bode", lambda path, responses, **kw: seen.update(kw, responses=responses))
    report.plot_run(tmp_path, None, plant, [design], summary=summary, band_hz=(1.0, 50.0), output="velocity_mps")
    assert seen["title"].startswith("Bode: emulated-msd.toml, ")
    assert seen["band_hz"] == (1.0, 50.0)
    # the plant is over torque, the loop over a velocity set-point: each curve says its unit
    assert seen["magnitude_unit"] == PER_CURVE
    assert [r[0] for r in seen["responses"]] == [
        "plant (net torque to output) [(m/s)/(N·m)]",
        "excitation to output, before notch [(m/s)/(m/s)]",
    ]
    fs_, hs = seen["stored_notch"]
    assert np.min(np.abs(hs)) < 0.01 and fs_[np.argmin(np.abs(hs))] == pytest.approx(10.0, rel=1e-3)
    assert seen["notch_label"] == "designed notch [dB re 1]"


def test_identify_writes_bode_and_model_plots(tmp_path):
    from hilident.cli.main import main
    from test_identify_offline import STIFF_MSD, identify_config, simulate, write_csv

    _, cols = simulate(STIFF_MSD, f_min=1.0, f_max=40.0, amplitude=50.0, periods=2)
    write_csv(tmp_path / "msd.csv", cols)
    config = identify_config(tmp_path, '\n[model]\nkind = "mass_spring_damper"\ncutoff_hz = 40.0\n')
    assert (
        main(["identify", str(tmp_path / "msd.csv"), "--config", str(config), "--out", str(tmp_path / "o"), "-q"]) == 0
    )
    for name in ("bode.png", "model.png"):
        assert (tmp_path / "o" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_run_prints_the_friction_parameters_with_their_units(tmp_path, monkeypatch, capsys):
    import hilident.session.run
    from hilident.cli.main import main

    summary = {
        "resonances": [],
        "excitation": {},
        "model": None,
        "verification": {"peak_reduction_db": None},
        "upload": {},
        "warnings": [],
        "stream": {"samples": 1, "lost_blocks": 0, "corrupt_frames": 0, "underruns": 0},
        "friction": {"structure": "stribeck", "params": {"Fc": 0.2, "Fs": 0.35, "Fv": 2.01, "vs": 0.01}},
    }

    class FakeSession:
        plan = None

        def __init__(self, *args, **kwargs):
            pass

        def run(self):
            return summary

    monkeypatch.setattr(hilident.session.run, "Session", FakeSession)
    config = Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml"
    assert main(["run", str(config), "--out", str(tmp_path), "-q"]) == 0
    out = capsys.readouterr().out
    assert "friction: Stribeck: Fc 0.2 N*m, Fs 0.35 N*m, Fv 2.01 N*m/(m/s), vs 0.01 m/s" in out


def test_greybox_records_split_as_the_fit_does():
    t, q = np.arange(10.0), np.arange(10.0) * 2
    split = report.greybox_records(0.3, (t, q))
    assert list(split) == ["estimation data", "holdout"]
    assert split["estimation data"][0].size == 7 and split["holdout"][1][0] == 14.0
    other = report.greybox_records(0.3, (t, q), {"verification": (t[:4], q[:4])})
    assert list(other) == ["estimation data", "verification"] and other["estimation data"][0].size == 10
    assert list(report.greybox_records(0.0, (t, q))) == ["estimation data"]


def test_a_bench_run_with_a_grey_box_model_draws_it(tmp_path):
    from dataclasses import replace

    from hilident.session.run import Session
    from test_session_e2e import gantry_variant

    cfg = gantry_variant()
    cfg = replace(
        cfg,
        model=replace(cfg.model, kind="rigid_axis", c=10.0, cutoff_hz=8.0),
        friction_test=replace(cfg.friction_test, enabled=False),
    )
    summary = Session(cfg, tmp_path).run()
    assert "verification" in summary["model"]["validation"]
    assert (tmp_path / "model.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "bode.png").is_file()


def test_bode_draws_a_response_whose_coherence_is_undefined():
    # one period, no averages: the coherence is NaN on every line
    f = np.geomspace(1, 100, 60)
    fig = _drawn(
        bode_figure(
            [("plant", _frf(f, _msd_velocity(f), np.full(f.size, np.nan)))],
            band_hz=(2.0, 50.0),
            coherence_threshold=0.8,
        )
    )
    plant = _lines(fig.axes[0], "plant")[0]
    x, y = plant.get_xdata(), np.asarray(plant.get_ydata())
    # unknown is not low: the band stays in colour, only the lines outside it are greyed
    assert np.all(np.isfinite(y[(x >= 2.0) & (x <= 50.0)])) and np.all(np.isnan(y[x > 50.0]))
    assert np.all(np.isfinite(_lines(fig.axes[0], "outside band or coherence < 0.8")[0].get_ydata()))


def test_upload_notch_plot_shows_designed_and_stored_chains():
    """notch.png of an upload: the designed chain, the read-back chain, each centre marked; dB and Hz on the axes."""
    import json

    from hilident.plots.notches import notch_figure

    summary = json.loads((Path(__file__).parent / "data" / "html_report" / "upload.json").read_text())
    fig = notch_figure(summary)
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(label.startswith("designed") for label in labels)
    assert any(label.startswith("stored in the device") for label in labels)
    centre = float(summary["notch_filters"][0]["center_hz"])
    assert any(f"{centre:.4g} Hz" in label for label in labels)
    assert ax.get_xlabel() == "frequency [Hz]" and "dB" in ax.get_ylabel()
    assert "Notches designed and stored" in ax.get_title()
    stored = next(line for line in ax.get_lines() if line.get_label().startswith("stored"))
    f, db = stored.get_xdata(), stored.get_ydata()
    assert abs(f[np.argmin(db)] - centre) < 0.05 * centre  # the stored notch's minimum sits at the design centre
    assert db.min() < -10.0


def test_upload_notch_plot_needs_a_notch():
    from hilident.plots.notches import notch_figure

    with pytest.raises(DataError, match="no notch"):
        notch_figure({"notch_filters": [], "upload": {"slots": []}})
