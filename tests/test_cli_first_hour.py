"""The first hour at the command line: ``init``, ``ports``, ``--help``, ``--log-level``, output folders, and the
length an experiment plays."""

from __future__ import annotations

import argparse
import logging
import re
import shutil
import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest

from hilident.cli import main as cli
from hilident.cli.main import build_parser, main
from hilident.config.tables import load_config
from hilident.drivers.description import check_run_against_driver, find_driver
from hilident.drivers.starter_config import DEFAULT_DRIVERS
from hilident.session.experiment import length_line

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


# --- init --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("transport", ["serial", "canopen", "modbus"])
def test_init_writes_a_config_that_loads_and_fits_its_driver(tmp_path, capsys, transport):
    out = tmp_path / f"{transport}.toml"
    assert main(["init", "--transport", transport, "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    cfg = load_config(out)
    assert cfg.device.driver == DEFAULT_DRIVERS[transport] and cfg.device.port == "emulator"
    # what `run` checks before connecting: sample rate, channels, modes of the excitation and the friction test
    modes = check_run_against_driver(cfg, find_driver(cfg.device.driver))
    assert cfg.excitation.mode in modes
    text = out.read_text()
    for key in ("port", "torque_nm", "velocity_mps", "position_min_m", "position_max_m", "amplitude_nm"):
        line = next(x for x in text.splitlines() if x.startswith(f"{key} ="))
        assert "# CHECK" in line, line
    assert "N*m" in text and "m/s" in text and f"hilident run {out} --dry-run" in text
    table = {"serial": None, "canopen": "canopen", "modbus": "modbus"}[transport]
    if table:  # the transport's own keys are written out for the user to set
        assert tomllib.loads(text)["device"][table]


def test_init_with_a_driver_folder_writes_a_config_that_finds_it_from_elsewhere(tmp_path, monkeypatch):
    folder = tmp_path / "bench-drives" / "my-board"
    shutil.copytree(find_driver(DEFAULT_DRIVERS["serial"]).folder, folder)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "configs" / "mine.toml"
    out.parent.mkdir()
    assert main(["init", "--driver", "./bench-drives/my-board", "--out", str(out)]) == 0
    cfg = load_config(out)
    assert Path(cfg.device.driver) == folder.resolve()
    monkeypatch.chdir(out.parent)  # a run started elsewhere still finds the folder
    assert find_driver(cfg.device.driver).folder.resolve() == folder.resolve()


def test_init_takes_the_transport_from_the_driver_and_refuses_a_mismatch(tmp_path, capsys):
    out = tmp_path / "a.toml"
    assert main(["init", "--driver", "cia402-standard", "--out", str(out)]) == 0
    cfg = load_config(out)
    assert cfg.device.driver == "cia402-standard" and "[device.canopen]" in out.read_text()
    check_run_against_driver(cfg, find_driver("cia402-standard"))
    capsys.readouterr()
    assert main(["init", "--transport", "modbus", "--driver", "myrio-board", "--out", str(tmp_path / "b.toml")]) == 2
    err = capsys.readouterr().err
    assert "--driver myrio-board" in err and "serial" in err and "modbus" in err
    assert not (tmp_path / "b.toml").exists()
    assert main(["init", "--driver", "no-such-drive", "--out", str(tmp_path / "c.toml")]) == 2
    assert "no-such-drive" in capsys.readouterr().err


def test_init_driver_without_excitation_says_so_and_still_loads(tmp_path):
    out = tmp_path / "dsy.toml"
    assert main(["init", "--driver", "dsy-rs", "--out", str(out)]) == 0
    text = out.read_text()
    assert "declares no excitation mode" in text and "enabled = false" in text
    assert load_config(out).device.driver == "dsy-rs"


def test_init_keeps_an_existing_file_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "axis.toml"
    out.write_text("# mine\n")
    assert main(["init", "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err and out.read_text() == "# mine\n"
    assert main(["init", "--out", str(out), "--overwrite"]) == 0
    assert load_config(out).device.driver == "myrio-board"
    assert main(["init", "--out", str(tmp_path), "--overwrite"]) == 2  # a folder is never replaced
    assert "is a folder" in capsys.readouterr().err


# --- ports -------------------------------------------------------------------------------------------------------


def _fake_listings(monkeypatch, serial_ports, can_configs):
    import can
    from serial.tools import list_ports

    monkeypatch.setattr(list_ports, "comports", lambda: serial_ports)

    def detect(interfaces=None):
        (name,) = interfaces
        if name == "kvaser":
            raise OSError("canlib not found")
        return [c for c in can_configs if c["interface"] == name]

    monkeypatch.setattr(can, "detect_available_configs", detect)


def test_ports_lists_serial_ports_and_can_channels(monkeypatch, capsys):
    usb = SimpleNamespace(
        device="/dev/ttyUSB0", description="FT232R USB UART", hwid="USB VID:PID=0403:6001 SER=A50285BI"
    )
    acm = SimpleNamespace(device="/dev/ttyACM0", description="myRIO", hwid="USB VID:PID=3923:762F")
    _fake_listings(
        monkeypatch,
        [usb, acm],
        [{"interface": "socketcan", "channel": "can0"}, {"interface": "pcan", "channel": "PCAN_USBBUS1"}],
    )
    assert main(["ports"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    serial_at = lines.index(next(x for x in lines if x.startswith("serial ports")))
    assert lines[serial_at + 1].split("\t") == ["  /dev/ttyACM0", "myRIO", "USB VID:PID=3923:762F"]  # sorted
    assert lines[serial_at + 2].split("\t")[0:2] == ["  /dev/ttyUSB0", "FT232R USB UART"]
    assert "  socketcan\tcan0" in lines and "  pcan\tPCAN_USBBUS1" in lines
    assert re.search(r"note: kvaser: not asked \(OSError: canlib not found\)", out)


def test_ports_with_nothing_found_and_a_can_search_that_hangs(monkeypatch, capsys):
    import threading

    from hilident.adapters import ports

    release = threading.Event()
    _fake_listings(monkeypatch, [], [])
    import can

    monkeypatch.setattr(can, "detect_available_configs", lambda interfaces=None: release.wait(5) and [])
    try:
        found, notes = ports.can_interfaces(("socketcan", "pcan"), timeout_s=0.2)
    finally:
        release.set()
    assert found == [] and notes == ["no answer within 0.2 s from: socketcan, pcan"]
    assert main(["ports", "--no-can"]) == 0
    out = capsys.readouterr().out
    assert out.count("none found") == 2 and out.rstrip().endswith("note: CAN channels not searched (--no-can)")


# --- a port that does not open -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "code, hint",
    [(2, "no such device"), (13, "dialout"), (16, "in use by another program")],
    ids=["missing", "permission", "busy"],
)
def test_serial_open_failure_names_the_key_and_the_cause(monkeypatch, code, hint):
    import serial

    from hilident.adapters.serial.board import SerialBoardAdapter
    from hilident.errors import DeviceError

    def refuse(port, **kw):
        raise serial.SerialException(code, f"could not open port {port}: [Errno {code}] ...")

    monkeypatch.setattr(serial, "serial_for_url", refuse)
    with pytest.raises(DeviceError) as info:
        SerialBoardAdapter.open("/dev/ttyUSB9", find_driver("myrio-board"))
    text = str(info.value)
    assert text.startswith("[device.port] '/dev/ttyUSB9': cannot open: ") and hint in text
    assert info.value.exit_code == 4


def test_modbus_rtu_open_failure_names_the_key_and_the_cause(monkeypatch):
    import serial

    from hilident.adapters.modbus import common as modbus_common
    from hilident.adapters.modbus.drive import ModbusDriveAdapter
    from hilident.config.tables import parse_config
    from hilident.errors import DeviceError

    monkeypatch.setattr(modbus_common._SerialClient, "connect", lambda self: False)

    def refuse(port, **kw):
        raise serial.SerialException(13, f"could not open port {port}: [Errno 13] Permission denied: '{port}'")

    monkeypatch.setattr(serial, "serial_for_url", refuse)
    text = (CONFIGS / "emulated-modbus-gantry.toml").read_text().replace('port = "emulator"', 'port = "/dev/ttyS9"')
    cfg = parse_config(text, "rtu.toml")
    with pytest.raises(DeviceError) as info:
        ModbusDriveAdapter.open_device(cfg.device, find_driver(cfg.device.driver))
    message = str(info.value)
    assert message.startswith("[device.port] '/dev/ttyS9': cannot open at ") and "dialout" in message


def test_can_open_failure_names_the_key_and_the_cause(monkeypatch):
    from hilident.adapters.canopen import link as canopen_link
    from hilident.config.tables import parse_config
    from hilident.errors import DeviceError

    def refuse(self, **kwargs):
        raise OSError(19, "No such device")

    monkeypatch.setattr(canopen_link.TracingNetwork, "connect", refuse)
    text = (CONFIGS / "emulated-canopen-gantry.toml").read_text().replace('port = "emulator"', 'port = "can7"')
    cfg = parse_config(text, "can.toml")
    with pytest.raises(DeviceError) as info:
        canopen_link.open_network(cfg.device, 500_000, "socketcan can7")
    message = str(info.value)
    assert message.startswith("[device.port] 'can7': socketcan can7: cannot open CAN interface 'socketcan'")
    assert "hilident ports" in message


def test_a_port_held_by_another_session_names_the_key(tmp_path):
    from hilident.errors import DeviceError
    from hilident.session.devicelock import DeviceLock, device_key

    key = device_key("serial", "/dev/ttyUSB-held")
    with DeviceLock(key, tmp_path), pytest.raises(DeviceError) as info:
        DeviceLock(key, tmp_path).acquire()
    assert str(info.value).startswith("[device.port] line:/dev/ttyUSB-held: in use by another hilident session")


def test_a_missing_port_is_one_line_naming_the_key(tmp_path, capsys):
    cfg = tmp_path / "real.toml"
    cfg.write_text(
        (CONFIGS / "emulated-gantry.toml")
        .read_text()
        .replace('port = "emulator"', f'port = "{tmp_path / "ttyUSB-gone"}"')
    )
    assert main(["run", str(cfg), "--out", str(tmp_path / "o"), "--yes"]) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[device.port]" in err[0] and "no such device" in err[0]


# --- help, options, logging --------------------------------------------------------------------------------------


def _parsers(parser: argparse.ArgumentParser, path=("hilident",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_every_option_and_argument_has_help():
    missing = []
    for path, parser in _parsers(build_parser()):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue
            if not (action.help or "").strip():
                missing.append(f"{' '.join(path)} {'/'.join(action.option_strings) or action.dest}")
    assert missing == []


@pytest.mark.parametrize("command", [[], ["run"], ["identify"], ["upload"]], ids=["top", "run", "identify", "upload"])
def test_help_has_examples_and_exit_codes(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([*command, "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert re.search(r"^examples:|^first hour:", out, re.M)
    assert re.search(r"^\s+hilident \w+", out, re.M)  # at least one example command line
    codes = out[out.index("exit codes:") :]
    for code in ("0", "2", "3", "4", "5", "130"):
        assert re.search(rf"(^|\s|/){code}(\s|/)", codes), code
    assert "  hilident run configs/emulated-gantry.toml" in out or command != ["run"]


def test_log_level_reaches_the_library_loggers(tmp_path):
    root = logging.getLogger()
    before = root.level
    try:
        assert main(["--log-level", "DEBUG", "init", "--out", str(tmp_path / "a.toml")]) == 0
        assert logging.getLogger("hilident.session.run").getEffectiveLevel() == logging.DEBUG
        assert main(["--log-level", "error", "init", "--out", str(tmp_path / "b.toml")]) == 0
        assert logging.getLogger("hilident.adapters.canopen.link").getEffectiveLevel() == logging.ERROR
    finally:
        root.setLevel(before)
    with pytest.raises(SystemExit) as done:
        main(["--log-level", "loud", "ports"])
    assert done.value.code == 2


# --- output folders ----------------------------------------------------------------------------------------------


def test_default_out_is_a_new_timestamped_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    first = cli._out_folder(None, "bench", overwrite=False)
    assert re.fullmatch(r"runs/bench-\d{8}-\d{6}", first.as_posix())
    first.mkdir(parents=True)
    second = cli._out_folder(None, "bench", overwrite=False)
    assert second != first and second.name.startswith("bench-")


def test_run_identify_and_upload_refuse_an_out_holding_results(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    for argv in (
        ["run", str(CONFIGS / "emulated-gantry.toml"), "--out", str(out)],
        ["identify", str(tmp_path / "data.h5"), "--out", str(out)],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"--out {out}" in err and "--overwrite" in err
    assert (out / "summary.json").read_text() == "{}"
    assert main(["run", str(CONFIGS / "emulated-gantry.toml"), "--out", str(out), "--dry-run"]) == 0  # writes nothing
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]
    capsys.readouterr()
    from test_upload_command import write_source

    source = write_source(tmp_path / "src", 21.79, 4000.0)
    assert (
        main(
            [
                "upload",
                "--from",
                str(source),
                "--config",
                str(CONFIGS / "emulated-gantry.toml"),
                "--out",
                str(out),
                "-q",
            ]
        )
        == 2
    )
    assert f"--out {out}" in capsys.readouterr().err and (out / "summary.json").read_text() == "{}"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli._out_folder(str(empty), "x", overwrite=False) == empty
    assert cli._out_folder(str(out), "x", overwrite=True) == out


# --- the length played -------------------------------------------------------------------------------------------


def test_length_line_says_asked_and_played():
    recipe = {"kind": "multisine", "duration_s": 16.0, "period_s": 4.0}
    assert length_line("identification", "torque", 20.0, recipe) == (
        "identification: 16.0 s of torque excitation asked, 20.0 s played: one lead-in period (4.0 s, not analysed)"
    )
    odd = length_line("identification", "torque", 20.0, {**recipe, "duration_s": 15.0})
    assert "15.0 s of torque excitation asked, 20.0 s played: 4 whole periods of 4.0 s and one lead-in" in odd
    assert length_line("friction", "velocity", 20.5) == "friction: 20.5 s of velocity excitation"
    assert length_line("x", "torque", 10.0, {"kind": "chirp", "duration_s": 10.0}) == "x: 10.0 s of torque excitation"
    assert "whole PRBS sequences" in length_line("x", "torque", 4.1, {"kind": "prbs", "duration_s": 3.0})


# --- drivers -v --------------------------------------------------------------------------------------------------


def test_drivers_verbose_describes_every_shipped_driver(capsys):
    from hilident.drivers.description import available_drivers

    assert main(["drivers", "-v"]) == 0
    out = capsys.readouterr().out
    blocks = re.split(r"^(?=\S)", out, flags=re.M)
    described = {b.split("\t", 1)[0]: b for b in blocks if b and "\t" in b.splitlines()[0]}
    for name in ("myrio-board", "canopen-servo", "modbus-servo", "dsy-rs"):
        assert name in available_drivers()
        block = described[name]
        for label in (
            "rates: loop ",
            "filter slots: ",
            "channels: ",
            "channel units: ",
            "sample rates: ",
            "modes: ",
            "capabilities: ",
        ):
            assert label in block, (name, label)
    assert "velocity_mps [m/s]" in described["myrio-board"] and "torque_nm [N*m]" in described["canopen-servo"]
    assert re.search(r"sample rates: 8000, 4000, ", described["dsy-rs"])
    assert "filter slots: 1" in described["dsy-rs"] and "filters (notch_parameters)" in described["dsy-rs"]
