"""`amplitude_nm = "auto"`: the excitation amplitude chosen by a standstill record and short trials."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.config.tables import load_config, parse_config
from hilident.emulator.factory import true_modes
from hilident.errors import ConfigError
from hilident.ident.frequency import periodic_frf
from hilident.ident.friction import StribeckParams
from hilident.io.recording import read_run
from hilident.session.auto_amplitude import (
    band_coherence,
    coherence_factor,
    friction_share,
    predicted_coherence,
    response_change,
)
from hilident.session.run import Session

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
GANTRY = CONFIGS / "emulated-gantry.toml"


def auto_text(path: Path) -> str:
    """A shipped gantry config with its amplitude chosen automatically (as the shipped gantries ship)."""
    text = path.read_text()
    assert re.search(r"^amplitude_nm = ", text, flags=re.M)
    return re.sub(r"^amplitude_nm = .*$", 'amplitude_nm = "auto"', text, flags=re.M)


AUTO_GANTRY = auto_text(GANTRY)


def quick(path: Path = GANTRY, friction_test: bool = False, **excitation):
    """A shipped config with auto amplitude made quick: 2 s periods, no verification, 16x simulated time."""
    cfg = parse_config(auto_text(path), str(path))
    assert cfg.excitation.amplitude_auto
    exc = replace(cfg.excitation, **{"period_s": 2.0, "duration_s": 4.0, **excitation})
    emu = replace(cfg.emulator, time_scale=16.0, **({"link": "pipe"} if cfg.emulator.link == "pty" else {}))
    return replace(
        cfg,
        excitation=exc,
        emulator=emu,
        notch=replace(cfg.notch, verify=False),
        friction_test=replace(cfg.friction_test, enabled=friction_test),
    )


def assert_mode_found(cfg, summary, tolerance=0.005):
    ((true_f, _),) = true_modes(cfg.emulator)
    found = summary["resonances"]
    assert found, summary["warnings"]
    best = min(found, key=lambda r: abs(r["frequency_hz"] - true_f))
    assert abs(best["frequency_hz"] - true_f) / true_f < tolerance


# --- the numbers -------------------------------------------------------------------------------


def test_predicted_coherence_follows_the_signal_to_noise_ratio():
    signal, noise = {"output": np.array([1.0, 4.0, 0.0])}, {"output": np.array([1.0, 1.0, 1.0])}
    many = predicted_coherence(signal, noise, 1.0, 10**9)
    assert np.allclose(many, [0.5, 0.8, 0.0], atol=1e-6)  # S / (S + N) once the mean holds no noise
    two = predicted_coherence(signal, noise, 1.0, 2)
    assert np.all(two > many)  # two periods: the mean's own noise biases the estimate up
    assert np.allclose(predicted_coherence(signal, noise, 2.0, 10**9)[:2], [0.8, 16 / 17], atol=1e-6)


def test_the_coherence_factor_reaches_the_target_at_the_band_share():
    rng = np.random.default_rng(1)
    signal = {"output": rng.uniform(0.5, 2.0, 200), "torque": rng.uniform(1.0, 3.0, 200)}
    noise = {"output": rng.uniform(0.05, 1.0, 200), "torque": rng.uniform(0.01, 0.1, 200)}
    factor = coherence_factor(signal, noise, 4, 0.95)
    assert factor > 1.0
    assert band_coherence(predicted_coherence(signal, noise, factor, 4)) == pytest.approx(0.95, abs=2e-3)
    assert band_coherence(predicted_coherence(signal, noise, 0.9 * factor, 4)) < 0.95


def test_response_change_recovers_a_distortion_falling_as_one_over_the_amplitude():
    g = np.exp(1j * np.linspace(0, 3, 50)) / np.linspace(1, 5, 50)
    quiet = np.zeros(50)

    def trial(amplitude, distortion_at_1):
        return {"amplitude_nm": amplitude, "frf": g * (1 + distortion_at_1 / amplitude), "relative_variance": quiet}

    assert response_change(trial(1.0, 0.4), trial(2.0, 0.4)) == pytest.approx(0.2, rel=1e-6)
    assert response_change(trial(2.0, 0.4), trial(8.0, 0.4)) == pytest.approx(0.05, rel=1e-6)
    noisy = {**trial(2.0, 0.0), "relative_variance": np.full(50, 0.01)}
    assert response_change(trial(1.0, 0.0), noisy) == 0.0  # a change within the noise is no distortion


def test_friction_share_counts_a_stuck_axis_as_all_friction():
    fit = StribeckParams(Fc=0.2, Fs=0.35, Fv=2.0, vs=0.005, delta_v=1.0, delta_s=2.0)
    x = 0.3 * np.sin(np.linspace(0, 20, 2000))
    assert friction_share(np.zeros_like(x), x, fit, 5e-4) == pytest.approx(1.0)  # friction held all of it
    moving = friction_share(np.sign(x) * 0.1, 10 * x, fit, 5e-4)
    assert moving == pytest.approx(0.2 / np.sqrt(np.mean(np.square(10 * x))), rel=1e-3)  # Coulomb over rms


# --- configuration and plan ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, key",
    [
        (('amplitude_nm = "auto"', 'amplitude_nm = "loud"'), "excitation.amplitude_nm"),
        (('amplitude_nm = "auto"', 'amplitude_nm = "auto"\nauto_max_nm = 25.0'), "excitation.auto_max_nm"),
        (('amplitude_nm = "auto"', 'amplitude_nm = "auto"\nauto_start_nm = 20.0'), "excitation.auto_start_nm"),
        (('amplitude_nm = "auto"', 'amplitude_nm = "auto"\nauto_trial_periods = 1'), "excitation.auto_trial_periods"),
        (('kind = "multisine"', 'kind = "chirp"'), "excitation.amplitude_nm"),
        (('mode = "torque"', 'mode = "velocity"\namplitude_mps = "auto"'), "excitation.amplitude_mps"),
    ],
)
def test_bad_auto_settings_name_the_key_and_file(tmp_path, change, key):
    path = tmp_path / "bad.toml"
    path.write_text(AUTO_GANTRY.replace(*change))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert err.value.key == key and "bad.toml" in str(err.value)
    if key == "excitation.amplitude_mps":
        assert "torque" in str(err.value)  # auto is for the torque modes; a set-point needs its number


def test_auto_for_another_kind_set_in_code_is_refused_before_anything_moves(tmp_path):
    cfg = quick()
    cfg = replace(cfg, excitation=replace(cfg.excitation, kind="noise"))
    with pytest.raises(ConfigError) as err:
        Session(cfg, tmp_path).run()
    assert err.value.key == "excitation.amplitude_nm"
    assert not list(tmp_path.glob("*.h5"))


def test_plan_shows_auto_and_the_ceiling(tmp_path):
    cfg = quick()
    result = Session(cfg, tmp_path, dry_run=True).run()
    ident = next(e for e in result["plan"]["experiments"] if e["name"] == "identification")
    assert ident["amplitude"].startswith("auto") and "19 N*m" in ident["amplitude"]
    assert ident["peak_torque_nm"] == pytest.approx(cfg.limits.torque_nm)  # the limits were checked at the ceiling
    assert any(e["name"] == "auto amplitude" for e in result["plan"]["experiments"])
    assert not list(tmp_path.glob("*.h5"))  # nothing moved


# --- whole sessions ------------------------------------------------------------------------------


def run_coherence(path: Path, band_hz) -> np.ndarray:
    """Coherence over periods of a recorded run at its excited lines in ``band_hz`` (torque to velocity)."""
    run = read_run(path)
    period = int(run.attrs["period_samples"])
    s = run.samples
    frf = periodic_frf(s["torque_nm"], s["velocity_mps"], period, run.sample_rate_hz, skip_periods=1)
    inside = (frf.frequency_hz >= band_hz[0]) & (frf.frequency_hz <= band_hz[1])
    return frf.coherence[inside]


def test_auto_meets_the_target_it_predicts_and_finds_the_mode(tmp_path):
    cfg = quick(duration_s=8.0)  # four periods: the prediction is for the run's own number of periods
    # the clean twin with noisier sensors: sensor noise alone sets the coherence, so the target is reachable
    noisy = replace(cfg.emulator.sensors, encoder_resolution_m=3e-6, torque_noise_nm=0.05)  # coherence < 1
    cfg = replace(cfg, emulator=replace(cfg.emulator, preset="clean", sensors=noisy))
    summary = Session(cfg, tmp_path).run()
    auto = summary["excitation"]["auto"]
    assert summary["excitation"]["amplitude_setting"] == "auto"
    assert summary["excitation"]["amplitude"] == auto["chosen_nm"]
    assert auto["reason"].startswith("target met"), auto["reason"]
    assert "predicted" in auto["line"] and auto["line"].endswith(f"{len(auto['trials'])} trials)")
    first, last = auto["trials"][0], auto["trials"][-1]
    assert first["predicted_coherence_band"] < auto["target_coherence"]  # the noise made the start too weak
    # the chosen amplitude is one a trial showed enough, with the safety factor on what it predicted
    assert last["needed_nm"] <= last["amplitude_nm"] <= auto["chosen_nm"] <= cfg.limits.torque_nm
    assert last["predicted_coherence_band"] >= auto["target_coherence"]
    assert len(auto["trials"]) >= 2  # no friction test: the distortion is bounded by two trials' responses
    assert last["nonlinear_share"] <= cfg.excitation.auto_nonlinear_share
    # (at rest a quantised encoder may read nothing: the output's noise then comes from the trials' scatter)
    assert auto["noise_floor"]["torque_nm_median"] > 0 and auto["noise_floor"]["output_median"] >= 0
    assert {"auto_noise.h5", "auto_trial_1.h5", "auto_trial_2.h5"} <= set(summary["recordings"])
    # what the run measured is what the trials predicted
    coherence = run_coherence(tmp_path / "identification.h5", auto["band_hz"])
    assert np.quantile(coherence, 1 - auto["band_share"]) >= auto["target_coherence"] - 0.02
    assert_mode_found(cfg, summary)


def test_auto_never_exceeds_the_torque_limit_and_says_so(tmp_path):
    cfg = quick(auto_start_nm=0.3, auto_max_trials=3)
    cfg = replace(cfg, limits=replace(cfg.limits, torque_nm=1.0))  # friction alone needs more than this
    summary = Session(cfg, tmp_path).run()
    auto = summary["excitation"]["auto"]
    assert auto["ceiling_nm"] == 1.0
    assert all(t["amplitude_nm"] <= 1.0 for t in auto["trials"])
    assert auto["chosen_nm"] <= 1.0
    assert auto["reason"].startswith("capped"), auto["reason"]
    assert auto["line"].startswith(f"excitation: auto amplitude {auto['chosen_nm']:.3g} N*m (capped")
    assert "evidence gates" in auto["line"]
    assert auto["trials"][-1]["needed_nm"] > 1.0
    assert any("evidence gates" in w for w in summary["warnings"])
