"""A command starts without what it does not need yet, and ``import hilident`` is light.

Each check runs in a fresh interpreter and looks at ``sys.modules``; nothing is timed
(``bench/startup.py`` measures the wall time).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import hilident

SRC = Path(hilident.__file__).resolve().parents[1]
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
HEAVY = ("numpy", "scipy", "scipy.signal", "matplotlib", "h5py")

#: Runs the CLI with the given arguments, then prints the heavy modules imported and the exit code as JSON.
PROBE = textwrap.dedent(
    """
    import json, sys
    argv = json.loads(sys.argv[1])
    code = None
    if argv is not None:
        from hilident.cli.main import main
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    else:
        exec(sys.argv[2])
    heavy = [m for m in json.loads(sys.argv[3]) if m in sys.modules]
    print(json.dumps({"code": code, "heavy": heavy}))
    """
)


def probe(argv: list[str] | None, statement: str = "", cwd: Path | None = None) -> tuple[dict, str]:
    """Run ``hilident argv`` (or ``statement``) in a fresh interpreter; its report and its stderr."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    done = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(argv), statement, json.dumps(HEAVY)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=cwd,
    )
    last = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else ""
    assert last.startswith("{"), f"probe printed no report: stdout {done.stdout!r}, stderr {done.stderr!r}"
    return json.loads(last), done.stderr


def test_importing_the_cli_imports_no_analysis_or_plotting():
    report, _ = probe(None, "import hilident.cli.main")
    assert report["heavy"] == []


def test_importing_the_package_is_light():
    report, _ = probe(None, "import hilident; hilident.__version__; dir(hilident)")
    assert report["heavy"] == []


@pytest.mark.parametrize(
    "text, key",
    [
        ('[device]\ntransport = "serial"\nbogus = 1\n', "device.bogus"),
        ("[run]\nsample_rate_hz = -5\n", "run.sample_rate_hz"),
        ("[device\n", "bad.toml"),
    ],
    ids=["unknown-key", "bad-value", "not-toml"],
)
def test_a_config_error_comes_before_the_heavy_imports(tmp_path, text, key):
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    report, stderr = probe(["run", str(bad)], cwd=tmp_path)
    assert report["code"] == 2
    assert key in stderr and "Traceback" not in stderr
    assert report["heavy"] == []


def test_a_late_config_error_comes_before_the_heavy_imports(tmp_path):
    """A shipped config with one value wrong that only the cross-checks at the end of loading find."""
    text = (CONFIGS / "emulated-gantry.toml").read_text()
    assert "f_max_hz = 80.0" in text
    bad = tmp_path / "late.toml"
    bad.write_text(text.replace("f_max_hz = 80.0", "f_max_hz = 800.0"))
    report, stderr = probe(["run", str(bad)], cwd=tmp_path)
    assert report["code"] == 2
    assert "excitation.f_max_hz" in stderr and "Traceback" not in stderr
    assert report["heavy"] == []


def test_loading_configs_from_python_imports_nothing_heavy(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[device]\nport = "emulator"\nbaudrate = "fast"\n')
    good = CONFIGS / "emulated-gantry.toml"
    statement = (
        f"from hilident import load_config, ConfigError\n"
        f"load_config({str(good)!r})\n"
        f"try:\n    load_config({str(bad)!r})\nexcept ConfigError as exc:\n    print(exc, file=sys.stderr)\n"
        f"else:\n    raise SystemExit('no ConfigError')"
    )
    report, stderr = probe(None, statement)
    assert "device.baudrate" in stderr
    assert report["heavy"] == []


@pytest.mark.parametrize(
    "command",
    [["identify", "data.h5", "--config"], ["upload", "--from", "old", "--config"]],
    ids=["identify", "upload"],
)
def test_other_commands_report_a_config_error_before_the_heavy_imports(tmp_path, command):
    bad = tmp_path / "bad.toml"
    bad.write_text('[device]\nport = "emulator"\nbogus = 1\n')
    report, stderr = probe([*command, str(bad)], cwd=tmp_path)
    assert report["code"] == 2
    assert "device.bogus" in stderr and "Traceback" not in stderr
    assert report["heavy"] == []


def test_a_missing_recording_is_reported_before_the_analysis_is_imported(tmp_path):
    report, stderr = probe(["identify", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "out")], cwd=tmp_path)
    assert report["code"] == 3
    assert "missing.h5: no such file" in stderr and "Traceback" not in stderr
    assert not {"scipy", "scipy.signal", "matplotlib"} & set(report["heavy"]), report["heavy"]


def test_help_imports_nothing_heavy():
    report, _ = probe(["--help"])
    assert report["code"] == 0
    assert report["heavy"] == []


def test_every_public_name_resolves():
    assert hilident.__all__, "the package exports nothing"
    for name in hilident.__all__:
        assert getattr(hilident, name) is not None, name
    assert set(hilident.__all__) <= set(dir(hilident))
    assert "importlib" not in dir(hilident)  # what the lazy loading imports is not offered


def test_public_names_are_the_objects_of_their_modules():
    from hilident.config.tables import load_config
    from hilident.errors import ConfigError
    from hilident.io.recording import RunData, read_run
    from hilident.session.offline import identify_recording
    from hilident.session.run import Session

    assert hilident.load_config is load_config
    assert hilident.Session is Session
    assert hilident.identify is identify_recording
    assert hilident.read_run is read_run and hilident.RunData is RunData
    assert hilident.ConfigError is ConfigError


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        hilident.no_such_name  # noqa: B018
    assert not hasattr(hilident, "no_such_name")


def test_the_signals_package_still_offers_its_generators():
    import hilident.signals as signals
    from hilident.signals import generators

    assert set(signals.__all__) <= set(dir(signals))
    for name in signals.__all__:
        assert getattr(signals, name) is getattr(generators, name)
    with pytest.raises(AttributeError):
        signals.no_such_signal  # noqa: B018


def test_the_startup_bench_runs_and_reports_every_command():
    """``bench/startup.py`` still runs (its broken config, its exit codes); its figures are not judged here."""
    bench = Path(__file__).resolve().parents[1] / "bench" / "startup.py"
    done = subprocess.run(
        [sys.executable, str(bench), "--repeats", "1", "--json"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    results = json.loads(done.stdout)
    assert [r["command"].split(" (")[0] for r in results] == [
        "hilident run BAD.toml",
        "hilident --help",
        "hilident identify MISSING.h5",
        "python -c pass",
    ]
    for r in results:
        assert r["target_s"] == 0.3 and r["repeats"] == 1
        assert 0 < r["min_s"] <= r["median_s"] <= r["max_s"]
        assert r["ratio"] == pytest.approx(r["median_s"] / 0.3)
