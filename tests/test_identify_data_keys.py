"""`hilident identify` on data from elsewhere: periods, headerless files, any extension, rates, output, failures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from hilident.cli.main import main
from support.schema_check import schema_errors

FS = 256.0
PERIOD = 1024
MODES = ((12.0, 0.02), (31.0, 0.015))  # Hz, damping ratio


def flexible_mechanism(noise: float = 1e-4, seed: int = 1):
    """Exactly one period of a multisine through two lightly damped modes, in periodic steady state.

    The excitation has every line from 0.25 Hz (the period's resolution) to 60 Hz with Schroeder phases;
    the plant is sampled with a zero-order hold, so its poles are exp(s T) of the continuous ones.
    """
    num, den = np.zeros(1), np.ones(1)
    for f, z in MODES:
        w = 2 * np.pi * f
        num = np.polyadd(np.polymul(num, [1, 2 * z * w, w * w]), np.polymul([w * w], den))
        den = np.polymul(den, [1, 2 * z * w, w * w])
    b, a, _ = signal.cont2discrete((num, den), 1 / FS, method="zoh")
    k = np.arange(1, int(60 * PERIOD / FS) + 1)
    n = np.arange(PERIOD)
    u = np.sum(np.cos(2 * np.pi * np.outer(n, k) / PERIOD - np.pi * k * (k - 1) / len(k)), axis=1)
    u /= np.abs(u).max()
    y = signal.lfilter(b.ravel(), a, np.tile(u, 12))[-PERIOD:]  # the transient has died out
    return u, y + noise * np.std(y) * np.random.default_rng(seed).standard_normal(PERIOD)


def identify(tmp_path, data, config: str, *extra) -> tuple[int, dict | None]:
    cfg = tmp_path / "c.toml"
    cfg.write_text(config)
    code = main(
        ["identify", str(data), "--config", str(cfg), "--out", str(tmp_path / "o"), "--overwrite", "-q", *extra]
    )
    path = tmp_path / "o" / "summary.json"
    return code, json.loads(path.read_text()) if path.exists() else None


def check_modes(summary):
    found = [(r["frequency_hz"], r["damping_ratio"]) for r in summary["resonances"]]
    assert len(found) == len(MODES), found
    for (f, z), (ft, zt) in zip(found, MODES, strict=True):
        assert abs(f - ft) / ft < 0.005, found
        assert abs(z - zt) / zt < 0.15, found


def test_one_period_headerless_file_with_any_extension(tmp_path):
    u, y = flexible_mechanism()
    data = tmp_path / "mechanism.asc"
    np.savetxt(data, np.column_stack([u, y]), fmt="%.10g")  # no header, whitespace
    keys = '[data]\nformat = "csv"\ntorque = "0"\noutput = "1"\nsample_rate_hz = 256.0\n'
    code, summary = identify(tmp_path, data, keys + "period_samples = 1024\n[identification]\nmax_resonances = 2\n")
    assert code == 0
    check_modes(summary)
    assert summary["data"]["period_samples"] == PERIOD and summary["data"]["used_rows"] == PERIOD
    assert any("one excitation period" in w for w in summary["warnings"])
    # period_s says the same in seconds
    code, again = identify(tmp_path, data, keys + "period_s = 4.0\n[identification]\nmax_resonances = 2\n")
    assert code == 0 and again["resonances"] == summary["resonances"]


def test_the_same_record_without_its_period_is_not_analysed_leakage_free(tmp_path):
    u, y = flexible_mechanism()
    data = tmp_path / "mechanism.csv"
    np.savetxt(data, np.column_stack([u, y]), delimiter=",")
    code, summary = identify(
        tmp_path,
        data,
        '[data]\ntorque = "0"\noutput = "1"\nsample_rate_hz = 256.0\n[identification]\nmax_resonances = 2\n',
    )
    assert code == 0 and summary["data"]["period_samples"] is None
    assert summary["measurement"]["n_averages"] > 1  # Welch segments: what the period key avoids


def test_headerless_columns_named_in_the_config_and_two_periods_averaged(tmp_path):
    u, y = flexible_mechanism()
    data = tmp_path / "mechanism.dat"
    np.savetxt(data, np.column_stack([np.tile(u, 2), np.tile(y, 2)]), delimiter=";")
    code, summary = identify(
        tmp_path,
        data,
        '[data]\ncolumn_names = ["force", "accel"]\ntorque = "force"\n'
        'output = "accel"\nsample_rate_hz = 256.0\nperiod_samples = 1024\n'
        "[identification]\nmax_resonances = 2\n",
    )
    assert code == 0
    check_modes(summary)
    assert summary["measurement"]["n_averages"] == 2


def test_column_names_on_a_file_with_a_header_is_refused_naming_the_key(tmp_path, capsys):
    data = tmp_path / "h.csv"
    data.write_text("a,b\n" + "".join(f"{i % 9},{i % 4}\n" for i in range(100)))
    code, _ = identify(
        tmp_path, data, '[data]\ncolumn_names = ["x", "y"]\ntorque = "x"\noutput = "y"\nsample_rate_hz = 100.0\n'
    )
    err = capsys.readouterr().err
    assert code == 2 and "data.column_names" in err and "header" in err


def msd_record(rate: float, n: int, seed: int, rate_error: float = 0.0):
    """Point samples of a continuous force and of the position it gives a mass-spring-damper (m 5, b 20, k 2e4)."""
    m, b, k = 5.0, 20.0, 2.0e4
    over = 20
    t = np.arange(n * over) / (rate * over)
    rng = np.random.default_rng(seed)
    sos = signal.butter(4, 60.0, fs=rate * over, output="sos")  # a smooth, broadband force
    force = signal.sosfilt(sos, rng.standard_normal(t.size))
    force *= 30.0 / np.std(force)
    _, x, _ = signal.lsim(([1.0], [m, b, k]), force, t)
    stamps = t[::over] * (1.0 + rate_error)  # the time column of a clock that runs slightly fast
    return {"t": stamps, "f": force[::over], "x": x[::over]}


def write_csv(path, columns):
    names = list(columns)
    np.savetxt(path, np.column_stack([columns[c] for c in names]), delimiter=",", header=",".join(names), comments="")


MSD_KEYS = '[data]\ntime = "t"\ntorque = "f"\nposition = "x"\n[model]\nkind = "mass_spring_damper"\ncutoff_hz = 80.0\n'


def test_sampled_force_needs_no_hold_correction_by_default(tmp_path):
    write_csv(tmp_path / "msd.csv", msd_record(1000.0, 6000, 1))
    code, summary = identify(tmp_path, tmp_path / "msd.csv", MSD_KEYS)
    assert code == 0
    p = summary["model"]["params"]
    assert abs(p["b"] - 20.0) / 20.0 < 0.03 and abs(p["m"] - 5.0) / 5.0 < 0.01, p
    est = summary["model"]["estimation"]
    assert 0 < est["relative_error"] < 0.2 and est["fit_percent"] > 80
    # treating these point samples as a held command biases the damping by about (T/2)(k - m w^2)
    code, held = identify(tmp_path, tmp_path / "msd.csv", MSD_KEYS + 'input_hold = "zoh"\n')
    assert abs(held["model"]["params"]["b"] - 20.0) > 3 * abs(p["b"] - 20.0)


def test_validation_record_on_a_clock_off_by_3e_5_is_accepted_and_the_difference_reported(tmp_path):
    write_csv(tmp_path / "a.csv", msd_record(1000.0, 4000, 1))
    write_csv(tmp_path / "b.csv", msd_record(1000.0, 4000, 2, rate_error=-3e-5))
    code, summary = identify(tmp_path, tmp_path / "a.csv", MSD_KEYS, "--validation", str(tmp_path / "b.csv"))
    assert code == 0
    assert summary["data"]["validation_rate_difference"] == pytest.approx(3e-5, rel=0.05)
    assert summary["model"]["validation"]["b.csv"]["fit_percent"] > 80


def test_rates_that_disagree_name_only_keys_that_were_set(tmp_path, capsys):
    write_csv(tmp_path / "a.csv", msd_record(1000.0, 4000, 1))
    write_csv(tmp_path / "b.csv", msd_record(1000.0, 4000, 2, rate_error=-2e-3))
    code, _ = identify(tmp_path, tmp_path / "a.csv", MSD_KEYS, "--validation", str(tmp_path / "b.csv"))
    err = capsys.readouterr().err
    assert code == 3 and "time column 't' (data.time)" in err and "[data.sample_rate_hz]" not in err
    # a rate that is set and disagrees with the time column: that key is the one to fix
    code, _ = identify(tmp_path, tmp_path / "a.csv", MSD_KEYS.replace("[data]\n", "[data]\nsample_rate_hz = 1001.0\n"))
    err = capsys.readouterr().err
    assert code == 3 and "correct data.sample_rate_hz" in err


def test_identification_output_is_honoured_and_no_velocity_is_needed(tmp_path):
    rec = msd_record(1000.0, 8000, 3)
    write_csv(tmp_path / "d.csv", {"t": rec["t"], "f": rec["f"], "x": rec["x"], "junk": np.cos(rec["t"])})
    keys = (
        '[data]\ntime = "t"\ntorque = "f"\nposition = "x"\n'
        '[identification]\noutput = "position"\nmax_resonances = 1\nsegment_s = 4.0\n'
    )
    code, summary = identify(tmp_path, tmp_path / "d.csv", keys)
    assert code == 0 and summary["data"]["mapping"]["output"] == "x"
    # msd: sqrt(k/m)/2pi = 10.07 Hz; torque to position has its peak there
    assert abs(summary["resonances"][0]["frequency_hz"] - np.sqrt(2.0e4 / 5.0) / (2 * np.pi)) < 0.15
    code, direct = identify(tmp_path, tmp_path / "d.csv", '[data]\ntime = "t"\ntorque = "f"\noutput = "x"\n')
    assert code == 0 and direct["data"]["mapping"] == {"torque": "f", "output": "x"}


def test_a_failing_step_still_writes_the_summary_naming_it(tmp_path, capsys):
    rec = msd_record(1000.0, 4000, 4)
    write_csv(tmp_path / "d.csv", {"t": rec["t"], "f": rec["f"], "x": rec["x"]})
    code, summary = identify(
        tmp_path,
        tmp_path / "d.csv",
        '[data]\ntime = "t"\ntorque = "f"\noutput = "x"\n[model]\nkind = "mass_spring_damper"\n',
    )
    err = capsys.readouterr().err
    assert code == 2 and "data.position" in err and "up to the failed step" in err
    assert summary["failed_step"] == "model" and "data.position" in summary["error"]
    assert schema_errors(summary) == []  # a partial summary is still a summary.json of its kind
    assert summary["resonances"] and summary["plant_model"] is not None
