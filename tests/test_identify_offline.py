"""`hilident identify` on recordings from elsewhere: CSV, .mat and hilident HDF5."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.io import savemat

from hilident.cli.main import main
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import build_drive, true_modes
from hilident.io.recording import RunWriter
from hilident.signals import multisine

GANTRY = """
[emulator]
preset = "clean"
[emulator.plant]
model = "two_mass"
m1 = 40.0
m2 = 10.0
k = 1.5e5
d = 40.0
c = 10.0
[emulator.friction]
model = "none"
[emulator.sensors]
encoder_resolution_m = 1e-7
torque_noise_nm = 0.01
"""
STIFF_MSD = """
[emulator]
preset = "clean"
[emulator.plant]
model = "mass_spring_damper"
m = 5.0
b = 20.0
k = 2.0e4
[emulator.friction]
model = "none"
[emulator.sensors]
encoder_resolution_m = 1e-8
torque_noise_nm = 0.0
"""
RATE = 1000.0


def simulate(plant_toml: str, f_min=2.0, f_max=80.0, amplitude=4.0, periods=4):
    """Open-loop torque run of an emulated axis, sampled at 1 kHz (the drive runs at 4 kHz)."""
    cfg = parse_config(plant_toml)
    drive = build_drive(cfg.emulator, find_driver("myrio-board"))
    drive.set_limits(100.0, 10.0, -10.0, 10.0)
    drive.set_mode("torque")
    drive.enable()
    ms = multisine(amplitude, f_min, f_max, 4.0, periods, RATE)
    rows = drive.run(np.repeat(ms.samples, 4))[::4]  # as the board samples: at the start of each period
    col = {name: rows[:, i] for i, name in enumerate(drive.CHANNELS)}
    return cfg, {
        "t": np.arange(len(rows)) / RATE,
        "tau": col["torque_nm"],
        "v": col["velocity_mps"],
        "x": col["position_m"],
    }


@pytest.fixture(scope="module")
def gantry_data():
    return simulate(GANTRY)


def write_csv(path, columns):
    names = list(columns)
    np.savetxt(path, np.column_stack([columns[n] for n in names]), delimiter=",", header=",".join(names), comments="")


def identify_config(tmp_path, extra="", identification=""):
    path = tmp_path / "identify.toml"
    path.write_text(
        '[data]\ntime = "t"\ntorque = "tau"\nvelocity = "v"\nposition = "x"\n'
        + extra
        + "\n[identification]\nmax_resonances = 1\n"
        + identification
    )
    return path


@pytest.mark.parametrize("fmt", ["csv", "mat", "h5"])
def test_identify_finds_the_resonance_in_every_format(tmp_path, gantry_data, fmt):
    cfg, cols = gantry_data
    data = tmp_path / f"rec.{fmt}"
    config = identify_config(tmp_path)
    if fmt == "csv":
        write_csv(data, cols)
    elif fmt == "mat":
        savemat(data, cols)
    else:
        with RunWriter(data, list(cols), ["s", "N*m", "m/s", "m"], RATE) as w:
            w.append(np.column_stack(list(cols.values())))
    assert main(["identify", str(data), "--config", str(config), "--out", str(tmp_path / "o"), "-q"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    ((true_f, true_zeta),) = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.01
    assert abs(res["damping_ratio"] - true_zeta) / true_zeta < 0.3
    (notch,) = summary["notch_filters"]
    assert notch["sample_rate_hz"] == 4000.0 and abs(notch["center_hz"] - res["frequency_hz"]) < 1e-9
    assert (tmp_path / "o" / "bode.png").is_file()
    # the fitted transfer function: one integrator (velocity of a free axis), the coupled mode, and the
    # anti-resonance of the load on its spring, sqrt(k / m2) / 2 pi
    model = summary["plant_model"]
    assert model["integrators"] == 1 and model["stable"]
    assert any(abs(r["frequency_hz"] - true_f) / true_f < 0.005 for r in model["resonances"])
    true_anti = np.sqrt(1.5e5 / 10.0) / (2 * np.pi)
    assert abs(model["antiresonances"][0]["frequency_hz"] - true_anti) / true_anti < 0.01
    quality = summary["measurement"]
    (at_peak,) = quality["uncertainty"]["at_resonances"]
    assert 0 < at_peak["magnitude_rel_std"] < 0.2  # leakage at the peak lowers the coherence of 2 s segments
    assert quality["input_spectrum"]["coverage"] > 0.9
    assert quality["input_spectrum"]["band_hz"][0] >= 1.5 and quality["input_spectrum"]["band_hz"][1] <= 90


def test_resolution_check_explains_an_over_estimated_damping(tmp_path, gantry_data):
    cfg, cols = gantry_data
    ((true_f, true_zeta),) = true_modes(cfg.emulator)
    write_csv(tmp_path / "rec.csv", cols)

    def identify(segment_s):
        config = identify_config(tmp_path, identification=f"segment_s = {segment_s}\n")
        out = tmp_path / f"seg{segment_s}"
        assert main(["identify", str(tmp_path / "rec.csv"), "--config", str(config), "--out", str(out), "-q"]) == 0
        return json.loads((out / "summary.json").read_text())

    coarse = identify(2.0)  # 0.5 Hz bins: two across the 1 Hz half-power band
    assert coarse["measurement"]["resolution"]["resolution_hz"] == pytest.approx(0.5)
    assert any("damping is over-estimated" in w for w in coarse["warnings"])
    needed = coarse["measurement"]["resolution"]["required_record_s"]
    assert 2.0 < needed < 4.0
    fine = identify(8.0)  # 0.125 Hz bins: eight across
    assert not any("resolution" in w for w in fine["warnings"])
    (res,) = fine["resonances"]
    assert abs(res["damping_ratio"] - true_zeta) / true_zeta < 0.15
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.005


def test_grey_box_parameters_with_standard_deviations(tmp_path):
    cfg, cols = simulate(STIFF_MSD, f_min=1.0, f_max=40.0, amplitude=50.0, periods=3)
    data = tmp_path / "msd.csv"
    write_csv(data, cols)
    # the simulated drive holds each torque sample for a whole sample period: the data say so
    config = identify_config(tmp_path, '\n[model]\nkind = "mass_spring_damper"\ncutoff_hz = 40.0\ninput_hold = "zoh"\n')
    assert main(["identify", str(data), "--config", str(config), "--out", str(tmp_path / "o"), "-q"]) == 0
    model = json.loads((tmp_path / "o" / "summary.json").read_text())["model"]
    for name, truth in (("m", 5.0), ("b", 20.0), ("k", 2.0e4)):
        assert abs(model["params"][name] - truth) / truth < 0.02, (name, model["params"])
        assert model["stderr"][name] > 0
    assert model["fit_percent"] > 90
    # without a second record, the last 30 % validated the fit
    assert model["validation"]["holdout"]["fit_percent"] > 90
    assert model["estimation"]["samples"] > 2 * model["validation"]["holdout"]["samples"]


def test_grey_box_validated_on_a_separate_record(tmp_path, capsys):
    _, cols = simulate(STIFF_MSD, f_min=1.0, f_max=40.0, amplitude=50.0, periods=3)
    write_csv(tmp_path / "estimation.csv", cols)
    _, same = simulate(STIFF_MSD, f_min=2.0, f_max=30.0, amplitude=30.0, periods=2)
    write_csv(tmp_path / "same-axis.csv", same)
    _, other = simulate(STIFF_MSD.replace("k = 2.0e4", "k = 3.0e4"), f_min=2.0, f_max=30.0, amplitude=30.0, periods=2)
    write_csv(tmp_path / "stiffer-axis.csv", other)
    config = identify_config(tmp_path, '\n[model]\nkind = "mass_spring_damper"\ncutoff_hz = 40.0\n')

    def identify(validation):
        out = tmp_path / ("out-" + validation)
        assert (
            main(
                [
                    "identify",
                    str(tmp_path / "estimation.csv"),
                    "--config",
                    str(config),
                    "--out",
                    str(out),
                    "--validation",
                    str(tmp_path / validation),
                    "-q",
                ]
            )
            == 0
        )
        return json.loads((out / "summary.json").read_text())

    good = identify("same-axis.csv")
    check = good["model"]["validation"]["same-axis.csv"]
    assert check["fit_percent"] > 90
    assert not any("overfitting" in w for w in good["warnings"])
    assert "on the estimation data, " in capsys.readouterr().out
    bad = identify("stiffer-axis.csv")
    assert bad["model"]["validation"]["stiffer-axis.csv"]["fit_percent"] < check["fit_percent"] - 10
    assert any("stiffer-axis.csv" in w and "validation data" in w for w in bad["warnings"])


def one_line_error(capsys, argv, code):
    assert main(argv) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_bad_recordings_are_one_clear_line(tmp_path, gantry_data, capsys):
    _, cols = gantry_data
    config = identify_config(tmp_path)
    out = ["--out", str(tmp_path / "o"), "-q"]

    nan = dict(cols, tau=cols["tau"].copy())
    nan["tau"][100] = np.nan
    write_csv(tmp_path / "nan.csv", nan)
    line = one_line_error(capsys, ["identify", str(tmp_path / "nan.csv"), "--config", str(config), *out], 3)
    assert "'tau'" in line and "row 100" in line

    write_csv(tmp_path / "renamed.csv", {"t": cols["t"], "torque": cols["tau"], "v": cols["v"], "x": cols["x"]})
    line = one_line_error(capsys, ["identify", str(tmp_path / "renamed.csv"), "--config", str(config), *out], 3)
    assert "'tau'" in line and "torque" in line  # names the missing column and what the file has

    jitter = dict(cols, t=cols["t"].copy())
    jitter["t"][500:] += 0.0004
    write_csv(tmp_path / "jitter.csv", jitter)
    line = one_line_error(capsys, ["identify", str(tmp_path / "jitter.csv"), "--config", str(config), *out], 3)
    assert "not uniform" in line and "row 500" in line

    short = {k: v[:20] for k, v in cols.items()}
    write_csv(tmp_path / "short.csv", short)
    assert "at least" in one_line_error(
        capsys, ["identify", str(tmp_path / "short.csv"), "--config", str(config), *out], 3
    )

    savemat(tmp_path / "ragged.mat", dict(cols, v=cols["v"][:-5]))
    assert "different lengths" in one_line_error(
        capsys, ["identify", str(tmp_path / "ragged.mat"), "--config", str(config), *out], 3
    )

    flat = dict(cols, tau=np.full_like(cols["tau"], 2.0))
    write_csv(tmp_path / "flat.csv", flat)
    line = one_line_error(capsys, ["identify", str(tmp_path / "flat.csv"), "--config", str(config), *out], 3)
    assert "constant" in line and "'tau'" in line


def test_closed_loop_data_without_excitation_is_accepted_with_a_warning(tmp_path, gantry_data):
    _, cols = gantry_data
    data = tmp_path / "cl.csv"
    write_csv(data, cols)
    config = identify_config(tmp_path, "closed_loop = true\n")
    assert main(["identify", str(data), "--config", str(config), "--out", str(tmp_path / "o"), "-q"]) == 0
    warnings = json.loads((tmp_path / "o" / "summary.json").read_text())["warnings"]
    assert any("closed-loop" in w and "biased" in w for w in warnings)
