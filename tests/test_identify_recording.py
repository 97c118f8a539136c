"""`hilident identify` on hilident's own recordings: no --config, and the same resonances as the run."""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import h5py
import pytest

from hilident.cli.main import main
from hilident.config.tables import load_config
from hilident.session.run import Session
from support.summary_keys import assert_layout

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def quick_run(
    tmp_path: Path, name: str, time_scale: float, period_s: float, periods: int, friction_test: bool = False
) -> Path:
    """A short emulated session of a shipped config (a serial twin on an in-memory line, no verification run).

    Without ``friction_test`` the friction test is disabled; with it, the test runs four speeds each way.
    """
    text = (CONFIGS / name).read_text()
    raw = tomllib.loads(text)
    if friction_test:
        speeds = str(raw["friction_test"]["speeds_mps"]).replace("'", "")
        text = text.replace(f"speeds_mps = {speeds}", "speeds_mps = [0.01, 0.04, 0.1, 0.2]", 1)
        text = text.replace(f"hold_s = {raw['friction_test']['hold_s']}", "hold_s = 0.6", 1)
    disabled = (("notch", "verify"),) if friction_test else (("friction_test", "enabled"), ("notch", "verify"))
    for table, key in disabled:
        if key not in raw.get(table, {}):
            assert f"[{table}]\n" in text
            text = text.replace(f"[{table}]\n", f"[{table}]\n{key} = false\n", 1)
    cfg = load_config(CONFIGS / name)
    text = text.replace('link = "pty"', 'link = "pipe"')
    text = text.replace(f"time_scale = {cfg.emulator.time_scale}", f"time_scale = {time_scale}")
    text = text.replace(f"period_s = {cfg.excitation.period_s}", f"period_s = {period_s}")
    text = text.replace(f"duration_s = {cfg.excitation.duration_s}", f"duration_s = {period_s * periods}")
    path = tmp_path / name
    path.write_text(text)
    quick = load_config(path)
    assert (quick.emulator.time_scale, quick.excitation.period_s, quick.friction_test.enabled, quick.notch.verify) == (
        time_scale,
        period_s,
        friction_test,
        False,
    )
    if friction_test:
        assert (quick.friction_test.speeds_mps, quick.friction_test.hold_s) == ([0.01, 0.04, 0.1, 0.2], 0.6)
    out = tmp_path / "run"
    Session(quick, out).run()
    return out


def comparable(ran: dict) -> None:
    """Skip when the host fell behind the sped-up twin (a loaded machine).

    Then the board played zeros, the periods differ, and identify rightly
    refuses to average them as periods: run and identify cannot agree.
    """
    if ran["stream"]["underruns"]:
        pytest.skip(f"{ran['stream']['underruns']} underrun samples in the run")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Quick runs by config name, made once for this module."""
    made: dict[str, Path] = {}

    def get(name, *args):
        if name not in made:
            made[name] = quick_run(tmp_path_factory.mktemp(name.split(".")[0]), name, *args)
        return made[name]

    return get


@pytest.mark.parametrize(
    "name, time_scale, period_s, periods",
    [
        ("emulated-gantry.toml", 8.0, 2.0, 3),
        ("emulated-msd.toml", 25.0, 40.0, 2),
        ("emulated-modbus-gantry.toml", 8.0, 2.0, 3),
        ("emulated-canopen-gantry.toml", 8.0, 2.0, 3),
    ],
)
def test_identify_on_a_run_recording_needs_no_config_and_matches_the_run(
    tmp_path, capsys, runs, name, time_scale, period_s, periods
):
    run = runs(name, time_scale, period_s, periods)
    ran = json.loads((run / "summary.json").read_text())
    comparable(ran)
    assert ran["resonances"], ran["warnings"]
    recording = run / "identification.h5"
    with h5py.File(recording) as f:
        assert "period_samples" in f.attrs and "config_toml" in f.attrs
        rate = float(f.attrs["sample_rate_hz"])
    assert main(["identify", str(recording), "--out", str(tmp_path / "again"), "-q"]) == 0
    assert "configuration: the one stored in" in capsys.readouterr().out
    again = json.loads((tmp_path / "again" / "summary.json").read_text())
    if name == "emulated-gantry.toml":  # summary.json is a documented interface: its keys stay as they were
        assert_layout("run-quick", ran)
        assert_layout("identify", again)
    assert len(again["resonances"]) == len(ran["resonances"])
    for a, r in zip(again["resonances"], ran["resonances"], strict=True):
        assert abs(a["frequency_hz"] - r["frequency_hz"]) / r["frequency_hz"] < 0.005, (a, r)
        assert abs(a["damping_ratio"] - r["damping_ratio"]) / r["damping_ratio"] < 0.15, (a, r)
    data = again["data"]
    assert data["period_samples"] == int(round(period_s * rate))  # whole periods, as the run
    assert data["mapping"]["excitation"] == "excitation" and data["mapping"]["output"] == "velocity_mps"
    assert data["recorded_mode"] == "torque"
    assert data["units"]["torque"] == "N*m" and data["units"]["output"] == "m/s"
    assert data["units"]["excitation"] == "N*m"  # the unit of the recorded mode


def test_a_config_given_with_a_recording_overrides_its_tables(tmp_path, runs):
    run = runs("emulated-gantry.toml", 8.0, 2.0, 3)
    cfg = tmp_path / "override.toml"
    cfg.write_text('[identification]\noutput = "position_m"\nmax_resonances = 1\n')
    assert (
        main(["identify", str(run / "identification.h5"), "--config", str(cfg), "--out", str(tmp_path / "o"), "-q"])
        == 0
    )
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    # [data] left out: the recorded channels; [identification] from the file given: position is the output
    assert summary["data"]["mapping"]["output"] == "position_m"
    assert summary["data"]["mapping"]["torque"] == "torque_nm"
    ran = json.loads((run / "summary.json").read_text())
    comparable(ran)
    # another output, another response: the same mode's peak within the resolution the 2 s period gives. Three
    # periods of the position may not confirm it (its fit is looser than the velocity's), so a peak rejected as
    # not confirmed counts as found
    peaks = [r["frequency_hz"] for r in summary["resonances"]] + [
        p["frequency_hz"] for p in summary["rejected_peaks"] if p["reason"].startswith("not confirmed")
    ]
    mode = ran["resonances"][0]["frequency_hz"]
    assert min(abs(f / mode - 1) for f in peaks) < 0.01, (peaks, mode)


def test_a_file_that_is_no_hilident_recording_needs_a_config(tmp_path, capsys):
    data = tmp_path / "d.csv"
    data.write_text("t,tau,v\n" + "".join(f"{i / 1000},{(i % 7) - 3},{i % 5}\n" for i in range(200)))
    assert main(["identify", str(data), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "is not a hilident recording" in err and "--config" in err and "Traceback" not in err


def test_identify_removes_the_friction_the_run_removed(tmp_path):
    run = quick_run(tmp_path, "emulated-gantry.toml", 8.0, 2.0, 3, friction_test=True)
    ran = json.loads((run / "summary.json").read_text())
    comparable(ran)
    assert (run / "friction.h5").is_file() and ran["friction"] is not None
    assert main(["identify", str(run / "identification.h5"), "--out", str(tmp_path / "again"), "-q"]) == 0
    again = json.loads((tmp_path / "again" / "summary.json").read_text())
    # refitted from friction.h5 beside the recording, as the run fitted it
    for key, value in ran["friction"]["params"].items():
        assert again["friction"]["params"][key] == pytest.approx(value, rel=1e-9)
    # the same evidence, the same verdict: the same resonances (a run this short may confirm none, and then
    # identify must not find one either)
    assert len(again["resonances"]) == len(ran["resonances"])
    for a, r in zip(again["resonances"], ran["resonances"], strict=True):
        assert abs(a["frequency_hz"] / r["frequency_hz"] - 1) < 0.005
        assert abs(a["damping_ratio"] / r["damping_ratio"] - 1) < 0.15
    # without the friction test beside it, the torque keeps its friction, and a warning says so
    (run / "friction.h5").rename(tmp_path / "elsewhere.h5")
    assert main(["identify", str(run / "identification.h5"), "--out", str(tmp_path / "bare"), "-q"]) == 0
    bare = json.loads((tmp_path / "bare" / "summary.json").read_text())
    assert bare["friction"] is None and any("no friction test recorded beside" in w for w in bare["warnings"])


def test_a_run_whose_device_underran_is_not_averaged_as_periods_and_the_warning_says_why(tmp_path, runs):
    run = runs("emulated-gantry.toml", 8.0, 2.0, 3)
    copy = tmp_path / "identification.h5"
    shutil.copy(run / "identification.h5", copy)
    with h5py.File(copy, "r+") as f:
        period = int(f.attrs["period_samples"])
        col = [str(c) for c in f.attrs["channel_names"]].index("excitation")
        samples = f["samples"]
        for p in (1, 3):  # the device played zeros for a while in two periods: no two neighbours repeat
            block = samples[p * period : p * period + 300, :]
            block[:, col] = 0.0
            samples[p * period : p * period + 300, :] = block
        f.attrs["stream_json"] = json.dumps({"underruns": 600})
    assert main(["identify", str(copy), "--out", str(tmp_path / "o"), "-q"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["data"]["period_samples"] is None
    assert any("600 underrun samples" in w and "not to be trusted" in w for w in summary["warnings"])
