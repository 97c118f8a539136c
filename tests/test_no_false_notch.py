"""The mode within 0.5 %, or no notch at all: never a notch where the plant has no mode.

Random plants (a two-mass axis with its coupled mode inside, near or outside
the excited band, now and then a mass-spring-damper), random friction and a
random excitation amplitude from far too weak to ample go through the
emulator's own physics (:func:`hilident.emulator.factory.build_drive`, the
board's sample divider, no wire protocol) and the session's own analysis
(:func:`hilident.session.excitation.build_excitation`, :func:`pipeline.selection.select_gap_free`,
:func:`pipeline.plant.identify_plant`, :func:`pipeline.notches.notch_decision`). Every
resonance a notch would be designed for must lie within 0.5 % of a true
mode (:func:`hilident.emulator.factory.true_modes`); when none is, the
upload's ``skipped_reason`` says why.

The ``[emulator]`` tables name only the plant, the friction and the seed, so
the emulator's default sensors and drive (its realistic noise) apply. The
friction the analysis removes is the true one off by up to 10 % (a friction
test's error). Samples are recorded at the drive's loop rate, and one case at
the end below it, where the board's averaged torque matters.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, event, example, given, settings
from hypothesis import strategies as st

from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.clock import TablePlayer
from hilident.emulator.factory import build_drive, true_modes
from hilident.errors import DataError
from hilident.ident.friction import StribeckParams
from hilident.pipeline.eligibility import notch_eligibility
from hilident.pipeline.notches import notch_decision
from hilident.pipeline.plant import analysis_band, identify_plant
from hilident.pipeline.selection import select_gap_free
from hilident.session.excitation import build_excitation

#: Largest relative error of a notched resonance against the true mode.
TOLERANCE = 0.005
#: Excited band, Hz.
F_MIN_HZ, F_MAX_HZ = 2.0, 80.0

DRIVER = find_driver("myrio-board")


def bench_toml(
    plant: dict,
    friction: dict | None,
    mode: str,
    amplitude_nm: float,
    seed: int,
    sample_rate_hz: float = DRIVER.loop_rate_hz,
) -> str:
    """A session config for the embedded board: short multisine (3 periods of 2 s after the lead-in), recorded at
    the drive's loop rate."""
    plant_lines = "\n".join(f"{k} = {v!r}" for k, v in plant.items())
    friction_lines = 'model = "none"' if friction is None else "\n".join(f"{k} = {v!r}" for k, v in friction.items())
    return f"""
[device]
driver = "myrio-board"
port = "emulator"

[run]
sample_rate_hz = {sample_rate_hz!r}
seed = {seed}

[limits]
torque_nm = 45.0
velocity_mps = 50.0
position_min_m = -100.0
position_max_m = 100.0

[friction_test]
enabled = {"false" if friction is None else "true"}

[excitation]
kind = "multisine"
mode = "{mode}"
amplitude_nm = {amplitude_nm!r}
f_min_hz = {F_MIN_HZ}
f_max_hz = {F_MAX_HZ}
period_s = 2.0
duration_s = 6.0

[identification]
output = "velocity_mps"
max_resonances = 1

[emulator]
seed = {seed}

[emulator.plant]
{plant_lines}

[emulator.friction]
{friction_lines}
"""


def run_and_analyse(cfg, friction_error: float = 1.0):
    """Play the session's excitation through the twin's drive loop and decide notches as the session does.

    Parameters
    ----------
    cfg : Config
    friction_error : float
        Factor on the true friction the analysis removes (what a friction test
        that is off by that much would hand over).

    Returns
    -------
    (PlantResult, NotchDecision)
    """
    excitation = build_excitation(cfg)
    drive = build_drive(cfg.emulator, DRIVER)
    # the board plays each sample for `divider` loop ticks and records the first tick of each, its torques as the
    # mean of the period's ticks (PROTOCOL.md section 7)
    divider = round(DRIVER.loop_rate_hz / cfg.run.sample_rate_hz)
    drive.set_mode(cfg.excitation.mode)
    drive.enable()
    rows = TablePlayer(drive, divider, DRIVER.loop_rate_hz, DRIVER.averaged_channels).play(excitation.samples, 0).rows
    assert drive.fault is None
    recorded = {name: rows[:, i] for i, name in enumerate(drive.CHANNELS)}
    recorded["sample_index"] = np.arange(len(rows))
    selection = select_gap_free(recorded["sample_index"], excitation.period_samples, "identification")
    s = {k: v[selection.keep] for k, v in recorded.items()}
    ic = cfg.identification
    f = cfg.emulator.friction
    friction = None
    if cfg.friction_test.enabled and f.model != "none":
        friction = StribeckParams(
            Fc=f.Fc * friction_error,
            Fs=f.Fs * friction_error,
            Fv=f.Fv * friction_error,
            vs=f.vs,
            delta_v=f.delta_v,
            delta_s=f.delta_s,
        )
    plant = identify_plant(
        s["excitation"],
        s["torque_nm"],
        s[ic.output],
        s["velocity_mps"],
        cfg.run.sample_rate_hz,
        ic,
        analysis_band(ic, excitation.band_hz),
        friction=friction,
        velocity_deadband_mps=cfg.friction_test.velocity_deadband_mps,
        period_samples=excitation.period_samples,
        excited_bins=excitation.excited_bins,
    )
    e = cfg.excitation
    return plant, notch_decision(plant, ic.coherence_threshold, e.amplitude_key, e.amplitude)


def false_notches(cfg, decision) -> list[str]:
    """Each resonance the decision would notch that is not within TOLERANCE of a true mode."""
    modes = true_modes(cfg.emulator)
    out = []
    for r in decision.resonances:
        errors = [abs(r.frequency_hz - fm) / fm for fm, _ in modes]
        if not errors or min(errors) > TOLERANCE:
            out.append(
                f"notch at {r.frequency_hz:.4g} Hz (+-{r.frequency_ci95_hz:.3g} Hz, zeta {r.damping_ratio:.4f}, "
                f"local fit ratio {r.local_fit_ratio:.2f}); true modes {modes}"
            )
    return out


def check_no_false_notch(cfg, plant, decision) -> None:
    """No notch off a true mode; nothing uploaded only with a reason, and one naming the amplitude to change
    when a resonance was found but its evidence fell short."""
    problems = false_notches(cfg, decision)
    assert not problems, "\n".join(problems) + "\n" + cfg.text
    if not decision.resonances:
        assert decision.skipped_reason, "nothing would be uploaded, and no reason is given"
        if plant.resonances:
            assert f"excitation.{cfg.excitation.amplitude_key}" in decision.skipped_reason, decision.skipped_reason


# --- plants ------------------------------------------------------------------------------------


def log_uniform(lo: float, hi: float):
    """Floats from `lo` to `hi`, uniform in their logarithm."""
    return st.floats(math.log(lo), math.log(hi)).map(math.exp)


@st.composite
def plants(draw) -> dict:
    """``[emulator.plant]`` with its mode anywhere from 1 to 250 Hz (the band is 2-80 Hz) and zeta 0.005-0.1."""
    f_mode = draw(
        st.one_of(
            log_uniform(4.0, 70.0),  # well inside the band
            log_uniform(1.0, 4.0),
            log_uniform(70.0, 120.0),  # near or across its edges
            log_uniform(120.0, 250.0),
        )
    )  # no mode in the band
    zeta = draw(log_uniform(0.005, 0.1))
    c = draw(st.floats(5.0, 20.0))
    w = 2 * math.pi * f_mode
    if draw(st.integers(0, 4)) == 0:
        m = draw(st.floats(2.0, 40.0))
        k = w * w * m
        return {"model": "mass_spring_damper", "m": m, "k": k, "b": 2 * zeta * math.sqrt(k * m), "c": c}
    m1, m2 = draw(st.floats(5.0, 60.0)), draw(st.floats(1.0, 30.0))
    mu = m1 * m2 / (m1 + m2)
    k = w * w * mu
    return {"model": "two_mass", "m1": m1, "m2": m2, "k": k, "d": 2 * zeta * math.sqrt(k * mu), "c": c}


@st.composite
def frictions(draw) -> dict | None:
    """``[emulator.friction]`` (Stribeck, up to about a newton-metre), or None for none."""
    if draw(st.integers(0, 3)) == 0:
        return None
    fc = draw(st.floats(0.0, 1.0))
    return {
        "model": "stribeck",
        "Fc": fc,
        "Fs": fc * draw(st.floats(1.0, 2.0)),
        "Fv": draw(st.floats(0.0, 5.0)),
        "vs": draw(log_uniform(0.001, 0.02)),
    }


@settings(
    max_examples=8,
    deadline=None,
    derandomize=True,
    database=None,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    plant=plants(),
    friction=frictions(),
    amplitude=log_uniform(0.02, 16.0),
    mode=st.sampled_from(["torque", "torque_injection"]),
    friction_error=st.floats(0.9, 1.1),
    seed=st.integers(0, 2**16),
)
# Cases the property found before the gate asked for NOTCH_FREQUENCY_TOLERANCE: a heavily damped mode under weak
# excitation (notch 1.1 % off, +-1.3 %), a lightly damped one between the lines in closed loop (2.2 % off, +-0.51 %).
@example(
    plant={
        "model": "two_mass",
        "m1": 16.584586346107294,
        "m2": 6.472067601753561,
        "k": 2622.887400677285,
        "d": 15.978717455409285,
        "c": 15.423058455324016,
    },
    friction=None,
    amplitude=0.033550700061503805,
    mode="torque",
    friction_error=1.0,
    seed=45050,
)
@example(
    plant={
        "model": "two_mass",
        "m1": 7.65624638186981,
        "m2": 11.084504455507926,
        "k": 3859.5140598654,
        "d": 1.716193900659687,
        "c": 19.581793703077178,
    },
    friction=None,
    amplitude=11.79085159430692,
    mode="torque_injection",
    friction_error=1.0,
    seed=2770,
)
# A weak excitation of a plant whose mode (94 Hz) lies above the band: a "mode" narrower than a line at 68.7 Hz,
# which the misfitting model could not confirm, was notched on its local fit alone.
@example(
    plant={
        "model": "two_mass",
        "m1": 44.12461889398282,
        "m2": 14.50830506154086,
        "k": 3811723.2488279645,
        "d": 646.8424834239443,
        "c": 13.171398691866969,
    },
    friction=None,
    amplitude=0.1655080838371778,
    mode="torque",
    friction_error=1.0,
    seed=22487,
)
def test_a_notch_only_at_a_true_mode(plant, friction, amplitude, mode, friction_error, seed):
    cfg = parse_config(bench_toml(plant, friction, mode, amplitude, seed))
    try:
        plant_result, decision = run_and_analyse(cfg, friction_error)
    except DataError as exc:
        # e.g. stiction held the axis: the run ends at its identification step, nothing is uploaded
        event("identification refused the data")
        assert str(exc)
        return
    event("notched" if decision.resonances else "nothing uploaded")
    check_no_false_notch(cfg, plant_result, decision)


# --- the strong-excitation cases must find the mode (the property cannot pass by never notching) -----------

GANTRY = {"model": "two_mass", "m1": 40.0, "m2": 10.0, "k": 1.5e5, "d": 40.0, "c": 10.0}
GANTRY_FRICTION = {"model": "stribeck", "Fc": 0.2, "Fs": 0.35, "Fv": 2.0, "vs": 0.005}


@pytest.mark.parametrize(
    "plant, friction, mode",
    [
        (GANTRY, GANTRY_FRICTION, "torque"),
        (GANTRY, GANTRY_FRICTION, "torque_injection"),
        (
            {
                "model": "mass_spring_damper",
                "m": 5.0,
                "k": 5.0 * (2 * math.pi * 35.0) ** 2,
                "b": 2 * 0.03 * math.sqrt(5.0 * 5.0 * (2 * math.pi * 35.0) ** 2),
                "c": 10.0,
            },
            None,
            "torque",
        ),
    ],
)
def test_ample_excitation_finds_the_mode(plant, friction, mode):
    cfg = parse_config(bench_toml(plant, friction, mode, 8.0, 11))
    plant_result, decision = run_and_analyse(cfg)
    check_no_false_notch(cfg, plant_result, decision)
    assert decision.resonances, decision.skipped_reason


def test_no_mode_in_the_band_no_notch():
    stiff = dict(GANTRY, k=GANTRY["k"] * 100.0)  # the mode at 218 Hz, far above the 80 Hz band
    cfg = parse_config(bench_toml(stiff, GANTRY_FRICTION, "torque", 8.0, 5))
    _, decision = run_and_analyse(cfg)
    assert not decision.resonances
    assert decision.skipped_reason.startswith("no resonance was identified")


def test_a_damped_mode_known_only_to_its_bandwidth_gets_no_notch():
    from hilident.ident.resonance import Resonance

    # zeta 0.07 at 3.8 Hz: a 0.53 Hz bandwidth, so a +-0.05 Hz (1.3 %) interval passes the bandwidth rule
    res = Resonance(3.8, 0.07, -40.0, 0.99, "fit", 0.05, 0.01, 0.2, 0.3, 10.0, 0.8)
    verdict = notch_eligibility(res)
    assert not verdict["notchable"] and "0.5 %" in verdict["reason"]
    assert verdict["amplitude_factor"] == pytest.approx(2 * 0.05 / (0.005 * 3.8))
    assert notch_eligibility(Resonance(3.8, 0.07, -40.0, 0.99, "fit", 0.005, 0.01, 0.2, 0.3, 10.0, 0.8))["notchable"]


def test_torque_injection_recorded_below_the_loop_rate():
    """Recorded at 1 kHz from a 4 kHz loop. In torque_injection the loop's torque changes from tick to tick within
    a sample (it answers the encoder's noise at 4 kHz). A torque taken at the first tick aliased that: the mode came
    out 0.9 % high with a 0.14 % interval, which no evidence gate on the response can see. The board records the
    mean of the period's ticks (PROTOCOL.md section 7), and the mode is found where it is."""
    plant = {
        "model": "two_mass",
        "m1": 29.549252086336438,
        "m2": 23.590332053218063,
        "k": 859430.3254396777,
        "d": 298.73864306532914,
        "c": 19.87751421345008,
    }
    friction = {
        "model": "stribeck",
        "Fc": 0.21602178927464633,
        "Fs": 0.23674914099719024,
        "Fv": 4.494669509273522,
        "vs": 0.0010489481686790185,
    }
    cfg = parse_config(bench_toml(plant, friction, "torque_injection", 7.8741680998615315, 59953, 1000.0))
    plant_result, decision = run_and_analyse(cfg, 0.7993662423956174)
    # passes once the mode is found and notched where it is (refusing it would not be the fix either)
    assert decision.resonances, decision.skipped_reason
    check_no_false_notch(cfg, plant_result, decision)
