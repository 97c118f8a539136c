"""`[model]` keys of `hilident identify`: asymmetric friction, the low-speed threshold, decimation."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from hilident.cli.main import main
from hilident.config.tables import parse_config
from hilident.errors import ConfigError

RATE = 1000.0
TRUTH = {"M": 2.0, "Fv+": 3.0, "Fv-": 5.0, "Fc+": 1.0, "Fc-": 1.5}


def rigid_axis(n: int = 8000, seed: int = 0):
    """Point samples of force and position of a rigid axis with friction that differs by direction.

    Integrated at 20 kHz (semi-implicit Euler); the friction's sign is smoothed over 1 mm/s so the
    integration does not chatter at reversals (the fit leaves the slow rows out anyway).
    """
    over = 20
    dt = 1.0 / (RATE * over)
    t = np.arange(n * over) * dt
    rng = np.random.default_rng(seed)
    sos = signal.butter(2, 5.0, fs=RATE * over, output="sos")
    force = signal.sosfilt(sos, rng.standard_normal(t.size))
    force = 12.0 * force / np.std(force) + 8.0 * np.sin(2 * np.pi * 0.7 * t)
    v = x = 0.0
    pos = np.empty(t.size)
    for i, f in enumerate(force):
        up, down = 0.5 * (1 + np.tanh(v / 1e-3)), 0.5 * (1 - np.tanh(v / 1e-3))
        friction = TRUTH["Fv+"] * max(v, 0) + TRUTH["Fv-"] * min(v, 0) + TRUTH["Fc+"] * up - TRUTH["Fc-"] * down
        v += dt * (f - friction) / TRUTH["M"]
        x += dt * v
        pos[i] = x
    return force[::over], pos[::over]


@pytest.fixture(scope="module")
def axis_csv(tmp_path_factory):
    force, pos = rigid_axis()
    path = tmp_path_factory.mktemp("axis") / "axis.csv"
    np.savetxt(path, np.column_stack([force, pos]), delimiter=",", header="F,q", comments="")
    return path


def run(tmp_path, data, model: str):
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        '[data]\nsample_rate_hz = 1000.0\ntorque = "F"\nposition = "q"\n[identification]\n'
        'model_max_order = 0\n[model]\nkind = "rigid_axis"\ncutoff_hz = 20.0\n' + model
    )
    assert main(["identify", str(data), "--config", str(cfg), "--out", str(tmp_path / "o"), "--overwrite", "-q"]) == 0
    return json.loads((tmp_path / "o" / "summary.json").read_text())


def test_asymmetric_friction_per_direction_and_the_rows_left_out_reported(tmp_path, axis_csv, capsys):
    summary = run(tmp_path, axis_csv, "asymmetric = true\nmin_speed = 0.02\n")
    model = summary["model"]
    for name, truth in TRUTH.items():
        assert abs(model["params"][name] - truth) / truth < 0.1, (name, model["params"])
    est = model["estimation"]
    assert est["min_speed"] == 0.02 and est["low_speed_rows_excluded"] > 0
    assert any(f"{est['low_speed_rows_excluded']} of" in w and "model.min_speed" in w for w in summary["warnings"])
    out = capsys.readouterr().out
    assert f"{est['low_speed_rows_excluded']} low-speed rows left out" in out and "relative error" in out
    assert 0 < est["relative_error"] < 0.3


def test_a_higher_threshold_leaves_more_rows_out_and_decimation_fewer_in(tmp_path, axis_csv):
    low = run(tmp_path, axis_csv, "min_speed = 0.005\n")["model"]["estimation"]
    high = run(tmp_path, axis_csv, "min_speed = 0.05\n")["model"]["estimation"]
    assert high["low_speed_rows_excluded"] > low["low_speed_rows_excluded"]
    assert high["samples"] + high["low_speed_rows_excluded"] == low["samples"] + low["low_speed_rows_excluded"]
    every4 = run(tmp_path, axis_csv, "min_speed = 0.005\ndecimate = 4\n")["model"]
    assert abs(every4["estimation"]["samples"] - low["samples"] / 4) <= low["samples"] * 0.01 + 2
    assert abs(every4["params"]["M"] - TRUTH["M"]) / TRUTH["M"] < 0.1


@pytest.mark.parametrize(
    "text, key",
    [
        ('[model]\nkind = "mass_spring_damper"\nasymmetric = true\n', "model.asymmetric"),
        ('[model]\nkind = "mass_spring_damper"\nmin_speed = 0.1\n', "model.min_speed"),
        ("[model]\ndecimate = 0\n", "model.decimate"),
        ("[data]\nperiod_s = 1.0\nperiod_samples = 1000\n", "data.period_samples"),
        ("[data]\nperiod_s = 0.0101\nsample_rate_hz = 1000.0\n", "data.period_s"),
        ('[data]\ncolumn_names = ["a", "a"]\n', "data.column_names"),
    ],
)
def test_keys_that_do_not_fit_together_are_refused_by_name(text, key):
    with pytest.raises(ConfigError) as err:
        parse_config(text, "x.toml")
    assert key in str(err.value)
