"""``hilident upload``: notches of an earlier run or identify into a device, read back, enabled on a match, rolled
back on any failure, stored only with --save after every slot verified."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import pytest

from hilident.adapters.serial.board import board_stored_form
from hilident.cli.main import main
from hilident.config.tables import load_config
from hilident.errors import DataError, DeviceError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec, design_notch
from hilident.ident.resonance import Resonance
from hilident.pipeline.notches import design_notches
from hilident.pipeline.records import notch_records, resonance_records
from hilident.session.upload import UploadCommand
from support.schema_check import schema_errors
from support.summary_keys import assert_layout
from support.twins import Twin
from support.vendor_drives import VendorDrive, write_vendor_drive

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
ZETA = 0.018


def write_source(folder: Path, truth_hz: float, rate_hz: float, extra_hz: tuple[float, ...] = ()) -> Path:
    """A run folder whose summary.json holds notches designed for ``truth_hz`` (and ``extra_hz``) at ``rate_hz``."""
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    resonances = [Resonance(f, ZETA, 30.0, 0.99, frequency_ci95_hz=0.01 * f) for f in (truth_hz, *extra_hz)]
    designs = design_notches(resonances, cfg.notch, rate_hz, list(range(len(resonances))))
    folder.mkdir(parents=True)
    summary = {
        "resonances": resonance_records(resonances),
        "notch_filters": notch_records(designs),
        "upload": {"written": False, "verified_readback": False, "slots": []},
        "warnings": [],
    }
    (folder / "summary.json").write_text(json.dumps(summary))
    (folder / "identification.h5").write_bytes(b"recording")  # stands for the run's other files
    return folder


def fingerprint(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def slots(twin: Twin) -> list[tuple[Biquad, bool]]:
    chain = twin.emu.drive.filters
    return [chain.read(i) for i in range(len(chain))]


@pytest.fixture
def locks(tmp_path, monkeypatch):
    monkeypatch.setenv("HILIDENT_LOCK_DIR", str(tmp_path / "locks"))


def upload(*args: str) -> int:
    return main(["upload", *args])


@pytest.mark.parametrize(
    "transport,link,config",
    [
        ("serial", "pty", "emulated-gantry.toml"),
        ("modbus", "tcp", "emulated-modbus-gantry.toml"),
        ("canopen", "socketcand", "emulated-canopen-gantry.toml"),
    ],
    ids=["serial", "modbus", "canopen"],
)
def test_upload_writes_reads_back_and_enables_on_every_transport(tmp_path, locks, capsys, transport, link, config):
    twin = Twin(transport, link, config, tmp_path)
    try:
        source = write_source(tmp_path / "run", twin.truth_hz, 4000.0)
        before_files = fingerprint(source)
        before = slots(twin)
        assert upload("--from", str(source), "--config", str(twin.host_config("bench")), "--yes", "-q") == 0
        out = tmp_path / "run-upload"  # beside the source
        summary = json.loads((out / "summary.json").read_text())
        up = summary["upload"]
        assert up["written"] and up["verified_readback"] and not up["rolled_back"] and up["saved"] is False
        (slot,) = up["slots"]
        biquad, enabled = twin.emu.drive.filters.read(slot["slot"])
        assert enabled and list(biquad.b) == slot["readback_b"] and list(biquad.a) == slot["readback_a"]
        assert slot["readback_b"] == slot["expected_b"] and slot["matches"]
        # the achieved attenuation at the centre, from the coefficients the device holds
        design = summary["notch_filters"][0]
        held = Biquad(tuple(slot["readback_b"]), tuple(slot["readback_a"]))
        at_centre = -20 * __import__("math").log10(abs(held.response([design["center_hz"]], 4000.0)[0]))
        assert slot["achieved"]["attenuation_at_design_center_db"] == pytest.approx(at_centre, abs=1e-6)
        assert abs(slot["achieved"]["depth_error_db"]) < 1.0
        # what was there before is recorded, slot by slot
        assert [(b["enabled"], tuple(b["b"])) for b in summary["filters_before"]] == [(e, q.b) for q, e in before]
        assert summary["device"]["driver"] == twin.cfg.device.driver and not summary["device"]["emulated"]
        assert summary["source"]["summary"] == str(source / "summary.json")
        assert fingerprint(source) == before_files  # the source run is not touched
        assert "slot 0: read back as written, enabled" in capsys.readouterr().out
        assert_layout(f"upload-{transport}", summary)  # a documented interface: its keys stay as they were
    finally:
        twin.close()


@pytest.fixture
def serial_twin(tmp_path):
    twin = Twin("serial", "pty", "emulated-gantry.toml", tmp_path)
    yield twin
    twin.close()


def test_dry_run_prints_the_stored_form_and_touches_nothing(tmp_path, locks, capsys, serial_twin):
    source = write_source(tmp_path / "run", serial_twin.truth_hz, 4000.0)
    before = slots(serial_twin)
    config = serial_twin.host_config("bench")
    assert upload("--from", str(source), "--config", str(config), "--dry-run", "--slot", "2", "-q") == 0
    out = capsys.readouterr().out
    assert slots(serial_twin) == before
    assert not (tmp_path / "run-upload").exists()
    design = json.loads((source / "summary.json").read_text())["notch_filters"][0]
    stored = board_stored_form(Biquad(tuple(design["b"]), tuple(design["a"])))
    assert "slot 2 (now disabled)" in out and f"notch {design['center_hz']:.5g} Hz" in out
    assert f"{stored.b[1]:.9g}" in out and f"{stored.a[2]:.9g}" in out  # the REAL32 form the board would hold
    assert "nothing written" in out


def test_a_real_port_without_yes_is_refused_and_nothing_is_written(tmp_path, locks, capsys, serial_twin):
    source = write_source(tmp_path / "run", serial_twin.truth_hz, 4000.0)
    before = slots(serial_twin)
    assert upload("--from", str(source), "--config", str(serial_twin.host_config("bench")), "-q") == 2
    err = capsys.readouterr().err
    assert "--yes" in err and "upload plan for myrio-board" in err  # the plan was shown
    assert slots(serial_twin) == before
    assert not (tmp_path / "run-upload").exists()


def faulty(base, bad_slot: int):
    """``base`` adapter class whose read-back of ``bad_slot`` differs from what was written (a new notch only)."""

    class Faulty(base):
        corrupt = False

        def write_filter(self, slot, biquad, spec=None, *, enabled):
            super().write_filter(slot, biquad, spec, enabled=enabled)
            if slot == bad_slot:
                self.corrupt = biquad != Biquad.identity()

        def read_filter(self, slot):
            biquad, enabled = super().read_filter(slot)
            if slot == bad_slot and self.corrupt:
                biquad = Biquad((biquad.b[0] * 1.01, *biquad.b[1:]), biquad.a)
            return biquad, enabled

    return Faulty


def test_a_failing_read_back_rolls_every_slot_back_and_exits_with_a_partial_summary(
    tmp_path, locks, capsys, monkeypatch, serial_twin
):
    from hilident.session import connection as session

    old = board_stored_form(design_notch(NotchSpec(50.0, 10.0, 20.0), 4000.0))  # as the board holds it
    serial_twin.emu.drive.filters.write(0, old, True)  # an older notch the drive runs now
    before = slots(serial_twin)
    source = write_source(tmp_path / "run", serial_twin.truth_hz, 4000.0, extra_hz=(60.0,))
    real = session.adapter_class
    monkeypatch.setattr(session, "adapter_class", lambda transport: faulty(real(transport), bad_slot=1))
    rc = upload("--from", str(source), "--config", str(serial_twin.host_config("bench")), "--yes", "-q")
    assert rc == 4  # a device error
    err = capsys.readouterr().err
    assert "filter slot 1 read back" in err and "put back" in err and "Traceback" not in err
    assert slots(serial_twin) == before  # slot 0 holds the older notch again, enabled; slot 1 as it was
    summary = json.loads((tmp_path / "run-upload" / "summary.json").read_text())
    assert summary["failed_step"] == "upload" and "slot 1" in summary["error"]
    assert schema_errors(summary) == []  # a partial summary is still a summary.json of its kind
    up = summary["upload"]
    assert [s["matches"] for s in up["slots"]] == [True, False]
    assert up["rolled_back"] == [{"slot": 0, "restored": True}, {"slot": 1, "restored": True}]
    assert not up["written"] and not up["verified_readback"]
    assert summary["filters_before"][0]["enabled"] and summary["filters_before"][0]["b"] == list(old.b)


def test_a_signal_during_the_upload_puts_every_slot_back_and_exits_143(
    tmp_path, locks, capsys, monkeypatch, serial_twin
):
    import os
    import signal

    from hilident.session import connection as session

    old = board_stored_form(design_notch(NotchSpec(50.0, 10.0, 20.0), 4000.0))
    serial_twin.emu.drive.filters.write(0, old, True)
    before = slots(serial_twin)
    source = write_source(tmp_path / "run", serial_twin.truth_hz, 4000.0, extra_hz=(60.0,))
    real = session.adapter_class

    def terminated_at_slot_1(transport):
        class Terminated(real(transport)):
            def upload_filter(self, slot, biquad, spec=None):
                done = super().upload_filter(slot, biquad, spec)
                if slot == 1:  # slot 1 written and enabled when SIGTERM arrives
                    os.kill(os.getpid(), signal.SIGTERM)
                return done

        return Terminated

    monkeypatch.setattr(session, "adapter_class", terminated_at_slot_1)
    rc = upload("--from", str(source), "--config", str(serial_twin.host_config("bench")), "--yes", "-q")
    assert rc == 143
    assert "Traceback" not in capsys.readouterr().err
    assert slots(serial_twin) == before  # both slots as they were: the older notch enabled in 0, 1 untouched
    summary = json.loads((tmp_path / "run-upload" / "summary.json").read_text())
    assert summary["failed_step"] == "upload"
    assert summary["upload"]["rolled_back"] == [{"slot": 0, "restored": True}, {"slot": 1, "restored": True}]
    assert not summary["upload"]["written"]


def vendor_config(tmp_path: Path):
    folder = write_vendor_drive(tmp_path / "drivers", VendorDrive("acme-biquad", filters="biquad"))
    cfg = load_config(CONFIGS / "emulated-canopen-gantry.toml")
    return replace(cfg, device=replace(cfg.device, driver=str(folder)))


def test_save_stores_only_after_every_slot_read_back(tmp_path, monkeypatch):
    from hilident.session import connection as session

    cfg = vendor_config(tmp_path)
    source = write_source(tmp_path / "run", 21.79, 4000.0)
    good = UploadCommand(cfg, source, tmp_path / "good", save=True)
    summary = good.run()
    fw = good.device.emulator.server.firmware
    assert summary["upload"]["saved"] and "0x1010:1" in summary["upload"]["saved_with"]
    stored, stored_enabled = fw.stored_parameters[0]
    assert fw.saves == 1 and stored_enabled and list(stored.b) == summary["upload"]["slots"][0]["readback_b"]

    unsaved = UploadCommand(cfg, source, tmp_path / "unsaved")
    assert unsaved.run()["upload"]["saved"] is False and unsaved.device.emulator.server.firmware.saves == 0

    real = session.adapter_class
    monkeypatch.setattr(session, "adapter_class", lambda transport: faulty(real(transport), bad_slot=0))
    bad = UploadCommand(cfg, source, tmp_path / "bad", save=True)
    with pytest.raises(DeviceError, match="filter slot 0 read back"):
        bad.run()
    assert bad.device.emulator.server.firmware.saves == 0  # nothing stored: the read-back did not match
    assert not bad.device.emulator.drive.filters.read(0)[1]


def test_save_on_a_device_without_a_store_command_is_refused_before_writing(tmp_path, locks, capsys, serial_twin):
    source = write_source(tmp_path / "run", serial_twin.truth_hz, 4000.0)
    before = slots(serial_twin)
    assert (
        upload("--from", str(source), "--config", str(serial_twin.host_config("bench")), "--yes", "--save", "-q") == 2
    )
    assert "--save: a serial device has no store-parameters command" in capsys.readouterr().err
    assert slots(serial_twin) == before


def test_a_notch_for_another_filter_rate_is_designed_again_at_the_devices(tmp_path):
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    source = write_source(tmp_path / "run", 21.79, 1000.0)
    summary = UploadCommand(cfg, source, tmp_path / "out").run()
    (design,) = summary["notch_filters"]
    assert design["sample_rate_hz"] == 4000.0
    assert any("designed for a 1000 Hz filter rate" in w and "4000 Hz" in w for w in summary["warnings"])
    expected = design_notches([Resonance(21.79, ZETA, 30.0, 0.99, frequency_ci95_hz=0.2179)], cfg.notch, 4000.0, [0])[0]
    assert design["b"] == list(expected.biquad.b)
    assert summary["upload"]["verified_readback"]


def test_a_source_without_notches_is_a_data_error_quoting_its_reason(tmp_path, capsys):
    folder = tmp_path / "ident"
    folder.mkdir()
    reason = "no resonance was identified, so no notch was designed (see rejected_peaks)"
    (folder / "summary.json").write_text(json.dumps({"data": {}, "notch_filters": [], "notch_skipped_reason": reason}))
    assert upload("--from", str(folder), "--config", str(CONFIGS / "emulated-gantry.toml"), "-q") == 3
    err = capsys.readouterr().err
    assert f"{folder / 'summary.json'}: notch_filters is empty, the identify designed no notch" in err
    assert reason in err
    assert not (tmp_path / "ident-upload").exists()


@pytest.mark.parametrize(
    "broken,key",
    [
        ({"notch_filters": [{"center_hz": 20.0}]}, "notch_filters[0].width_hz"),
        (
            {
                "notch_filters": [
                    {
                        "center_hz": 20.0,
                        "width_hz": 2.0,
                        "depth_db": 30.0,
                        "sample_rate_hz": 4000.0,
                        "b": [1, 0, 0],
                        "a": [2, 0, 0],
                    }
                ]
            },
            "notch_filters[0].a",
        ),
        ({"resonances": []}, "no key notch_filters"),
    ],
)
def test_a_broken_source_names_the_file_and_key(tmp_path, broken, key):
    (tmp_path / "summary.json").write_text(json.dumps(broken))
    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    with pytest.raises(DataError, match=r"summary\.json: .*" + key.replace("[", r"\[").replace("]", r"\]")):
        UploadCommand(cfg, tmp_path / "summary.json", tmp_path / "out").run()


def test_out_may_not_be_the_source_folder(tmp_path, capsys):
    source = write_source(tmp_path / "run", 21.79, 4000.0)
    before = fingerprint(source)
    assert (
        upload(
            "--from",
            str(source / "summary.json"),
            "--config",
            str(CONFIGS / "emulated-gantry.toml"),
            "--out",
            str(source),
            "-q",
        )
        == 2
    )
    assert "never overwritten" in capsys.readouterr().err
    assert fingerprint(source) == before


def test_slot_beyond_the_devices_slots_is_a_usage_error(tmp_path, capsys):
    source = write_source(tmp_path / "run", 21.79, 4000.0)
    assert upload("--from", str(source), "--config", str(CONFIGS / "emulated-gantry.toml"), "--slot", "4", "-q") == 2
    assert "--slot 4" in capsys.readouterr().err and not (tmp_path / "run-upload").exists()


def test_a_failing_save_puts_the_slots_back(tmp_path):
    # the shipped CANopen drive's EDS has no store object (0x1010): the save fails after the upload verified
    cfg = load_config(CONFIGS / "emulated-canopen-gantry.toml")
    source = write_source(tmp_path / "run", 21.79, 4000.0)
    command = UploadCommand(cfg, source, tmp_path / "out", save=True)
    with pytest.raises(DeviceError, match="store parameters"):
        command.run()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["failed_step"] == "save" and summary["upload"]["slots"][0]["matches"]
    assert schema_errors(summary) == []
    assert summary["upload"]["rolled_back"] == [{"slot": 0, "restored": True}] and not summary["upload"]["saved"]
    assert command.device.emulator.drive.filters.read(0) == (Biquad.identity(), False)


def test_identify_a_recording_then_upload_its_notch_to_the_modbus_twin(tmp_path):
    # the flow of a drive hilident cannot excite: a recording made elsewhere (here a short serial-board run),
    # identified offline, its notch uploaded to another device
    import tomllib

    import tomli_w

    from support.twins import quick

    raw = quick(tomllib.loads((CONFIGS / "emulated-gantry.toml").read_text()), "serial")
    raw["excitation"]["duration_s"] = 6.0
    (tmp_path / "run.toml").write_text(tomli_w.dumps(raw))
    assert main(["run", str(tmp_path / "run.toml"), "--out", str(tmp_path / "run"), "-q", "--no-plots"]) == 0
    assert main(["identify", str(tmp_path / "run" / "identification.h5"), "--out", str(tmp_path / "ident"), "-q"]) == 0
    ident = json.loads((tmp_path / "ident" / "summary.json").read_text())
    assert len(ident["notch_filters"]) == 1, (ident["notch_skipped_reason"], ident["warnings"])
    (notch,) = ident["notch_filters"]
    assert notch["center_hz"] == pytest.approx(21.79, rel=0.005)
    command = UploadCommand(load_config(CONFIGS / "emulated-modbus-gantry.toml"), tmp_path / "ident")
    summary = command.run()
    (slot,) = summary["upload"]["slots"]
    assert slot["matches"] and summary["upload"]["verified_readback"]
    biquad, enabled = command.device.emulator.drive.filters.read(slot["slot"])
    assert enabled and list(biquad.b) == slot["readback_b"]
    assert abs(slot["achieved"]["depth_error_db"]) < 1.0  # the drive's parameter rounding costs under 1 dB
    assert command.out == tmp_path / "ident-upload" and (command.out / "summary.json").is_file()
    check_upload_to_a_parameter_drive(tmp_path / "ident", tmp_path / "dsy-upload", notch["center_hz"])


def check_upload_to_a_parameter_drive(source: Path, out: Path, center_hz: float) -> None:
    """The same notch into the DSY-RS twin, a drive of notch parameters (centre in 1 Hz steps, a width
    table, a depth in %), with --save: its integers written, read back equal, the attenuation at the centre
    from them as the design after the drive's quantisation, and the store carried out."""
    command = UploadCommand(load_config(CONFIGS / "emulated-dsy-rs.toml"), source, out, save=True)
    summary = command.run()
    (slot,) = summary["upload"]["slots"]
    assert slot["matches"] and summary["upload"]["verified_readback"] and summary["upload"]["saved"]
    (before,) = summary["filters_before"]
    assert before["parameters"]["center"]["value"] == 4000 and not before["enabled"]  # the drive's "off"
    firmware = command.device.emulator.server.firmware
    written = {field: p["value"] for field, p in slot["parameters"].items()}
    assert written == {
        "center": firmware.value("notch1_center_hz"),
        "width": firmware.value("notch1_width"),
        "depth": firmware.value("notch1_depth"),
    }
    assert written["center"] == round(center_hz)  # the nearest 1 Hz step of the drive
    assert slot["parameters"]["center"]["parameter"] == "P08.02"
    assert firmware.saves == 1 and firmware.eeprom[0x0802] == written["center"]
    biquad, enabled = command.device.emulator.drive.filters.read(0)
    assert enabled and list(biquad.b) == slot["readback_b"]
    achieved = slot["achieved"]
    designed = achieved["attenuation_at_design_center_db"] - achieved["depth_error_db"]
    assert achieved["realisable_db"] == pytest.approx(designed - achieved["quantisation_loss_db"])
    assert abs(achieved["beyond_quantisation_db"]) < 1.0 and achieved["realisable_db"] > 20.0


def test_the_upload_draws_its_notches_and_a_failing_plot_is_only_a_warning(
    tmp_path, locks, capsys, serial_twin, monkeypatch
):
    source = write_source(tmp_path / "run", serial_twin.truth_hz, 4000.0)
    config = str(serial_twin.host_config("bench"))
    assert upload("--from", str(source), "--config", config, "--yes", "-q", "--out", str(tmp_path / "a")) == 0
    assert (tmp_path / "a" / "notch.png").stat().st_size > 10_000

    import hilident.plots.notches

    def broken(path, summary):
        raise RuntimeError("no backend")

    monkeypatch.setattr(hilident.plots.notches, "plot_notches", broken)
    assert upload("--from", str(source), "--config", config, "--yes", "-q", "--out", str(tmp_path / "b")) == 0
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["upload"]["verified_readback"]  # the upload's result stands
    assert any("notch.png not written: no backend" in w for w in summary["warnings"])
    assert not (tmp_path / "b" / "notch.png").exists()
