"""Set-point perturbation in closed loop: drives that take no torque excitation.

A drive that runs only CSV, CSP or IP (no CST, no torque offset 0x60B2) is
excited through the set-point of the loop it closes: the excitation is a
velocity or position perturbation, the FRF's reference, and the plant (torque
to output) is estimated against it. The friction test runs in velocity mode,
or as a position profile when the drive has no velocity mode.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.config.tables import load_config
from hilident.drivers.description import load_driver
from hilident.emulator.factory import true_modes
from hilident.errors import ConfigError
from hilident.io.recording import read_run
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.eds import inspect_eds, load_eds
from hilident.session.excitation import build_excitation
from hilident.session.run import Session
from support.twins import assert_friction_matches
from support.vendor_drives import VendorDrive, write_vendor_drive

ROOT = Path(__file__).resolve().parents[1]
CANOPEN = ROOT / "configs" / "emulated-canopen-gantry.toml"
SERIAL = ROOT / "configs" / "emulated-gantry.toml"

#: maxon EPOS2-like: CSP and CSV only, current instead of torque, no torque offset
CURRENT_CSV = VendorDrive("acme-csv-current", modes=("pp", "pv", "hm", "csp", "csv"), torque="current")
#: Technosoft-like: IP only, no standard torque or current object, a vendor "Control effort"
IP_EFFORT = VendorDrive(
    "acme-ip-effort",
    modes=("pp", "hm", "ip"),
    torque="effort",
    torque_offset=False,
    limits=("max_velocity", "position_limits"),
)


def _config(path: Path, toml: str) -> Path:
    path.write_text(toml)
    return path


def _excitation_toml(mode: str, amplitude: str) -> str:
    text = SERIAL.read_text().replace('mode = "torque"', f'mode = "{mode}"')
    return re.sub(r"^amplitude_nm = .*$", amplitude, text, flags=re.M)


@pytest.mark.parametrize(
    "mode, amplitude, key",
    [
        ("velocity", "", "excitation.amplitude_mps"),  # not set: a set-point perturbation has no default size
        ("velocity", "amplitude_mps = 0.4", "excitation.amplitude_mps"),  # reaches limits.velocity_mps = 0.4
        ("position", "amplitude_m = 0.6", "excitation.amplitude_m"),  # does not fit the window [-0.6, 0.6]
        ("position", "amplitude_mps = 0.05", "excitation.amplitude_m"),  # the other mode's key
    ],
)
def test_a_set_point_perturbation_needs_its_own_amplitude_within_the_limits(tmp_path, mode, amplitude, key):
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path / "c.toml", _excitation_toml(mode, amplitude)))
    assert err.value.key == key and "c.toml" in str(err.value)


def test_a_velocity_perturbation_that_travels_too_far_is_refused_before_anything_moves(tmp_path):
    # a velocity step of 0.2 m/s for 16 s would travel about 3 m: the window is 1.2 m wide
    toml = _excitation_toml("velocity", "amplitude_mps = 0.2").replace('kind = "multisine"', 'kind = "step"')
    cfg = load_config(_config(tmp_path / "c.toml", toml))
    session = Session(cfg, tmp_path / "out", plots=False)
    with pytest.raises(ConfigError) as err:
        session.prepare()
    assert err.value.key == "excitation.amplitude_mps" and "travels up to" in str(err.value)
    assert session.adapter is None  # nothing was opened


def test_the_excitation_is_built_in_the_unit_of_its_mode(tmp_path):
    cfg = load_config(_config(tmp_path / "c.toml", _excitation_toml("velocity", "amplitude_mps = 0.05")))
    x = build_excitation(cfg).samples
    assert 0.03 < np.max(np.abs(x)) <= 0.05 + 1e-12  # m/s, not the 8 N*m of amplitude_nm
    torque = load_config(SERIAL)
    assert np.max(np.abs(build_excitation(torque).samples)) > 1.0


def _vendor_session(tmp_path, drive: VendorDrive, mode: str, amplitude: dict, friction: bool):
    folder = write_vendor_drive(tmp_path / "drivers", drive)
    cfg = load_config(CANOPEN)
    # speeds above the Stribeck range: a Coulomb-viscous fit of few legs recovers Fc and Fv; as a position
    # profile the legs need a settle long enough for the position loop's transient after each ramp
    ft = replace(
        cfg.friction_test,
        enabled=friction,
        speeds_mps=[0.03, 0.1, 0.2],
        hold_s=1.2,
        settle_s=0.8,
        model="coulomb_viscous",
    )
    # SYNC at 500 Hz: a host-streamed run is paced in real time, and this keeps it light on a busy machine
    cfg = replace(
        cfg,
        device=replace(cfg.device, driver=str(folder), acquisition="streamed"),
        run=replace(cfg.run, sample_rate_hz=500.0),
        emulator=replace(cfg.emulator, time_scale=20.0),
        friction_test=ft,
        excitation=replace(cfg.excitation, mode=mode, period_s=2.0, duration_s=4.0, **amplitude),
    )
    session = Session(cfg, tmp_path / "out", plots=False)
    return cfg, session, session.run()


def _resonance_error(cfg, summary) -> float:
    ((true_f, _),) = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    return abs(res["frequency_hz"] - true_f) / true_f


def test_a_current_only_csv_drive_is_identified_through_its_velocity_set_point(tmp_path):
    cfg, session, summary = _vendor_session(tmp_path, CURRENT_CSV, "velocity", {"amplitude_mps": 0.05}, friction=False)
    assert _resonance_error(cfg, summary) < 0.005
    assert summary["stream"]["lost_samples"] == 0
    assert summary["excitation"]["closed_loop"] is True and summary["excitation"]["unit"] == "m/s"
    run = read_run(tmp_path / "out" / "identification.h5")
    assert run.attrs["mode"] == "velocity"
    # the excitation column is the velocity set-point perturbation the host streamed
    assert 0.03 < np.max(np.abs(run.samples["excitation"])) <= 0.05 + 1e-9
    assert session.plan.experiments[0].peak_speed_mps == pytest.approx(0.05, rel=0.3)
    assert session.plan.experiments[0].peak_torque_nm is None
    assert not session.emulator.drive.enabled


def test_an_ip_only_drive_runs_friction_as_a_position_profile_and_is_excited_through_its_position(tmp_path):
    cfg, session, summary = _vendor_session(tmp_path, IP_EFFORT, "position", {"amplitude_m": 0.002}, friction=True)
    assert session.friction_mode == "position"
    assert [e.mode for e in session.plan.experiments[:2]] == ["position", "position"]
    assert _resonance_error(cfg, summary) < 0.005
    assert summary["stream"]["lost_samples"] == 0
    assert_friction_matches(summary["friction"], cfg.emulator.friction)
    run = read_run(tmp_path / "out" / "friction.h5")
    assert run.attrs["mode"] == "position"
    # the torque is the vendor's control effort, the only torque this drive gives
    assert np.ptp(run.samples["torque_nm"]) > 0.1


def test_a_mode_whose_set_point_the_eds_will_not_map_is_not_streamed(tmp_path):
    # CSP's 0x607A not PDO-mappable (as on one real file): position runs in IP, CSP may still hold the axis
    drive = VendorDrive("acme-csp-fixed", modes=("csp", "ip"), unmappable=(0x607A,))
    folder = write_vendor_drive(tmp_path, drive)
    desc = CanopenDescription.from_sections(
        load_driver(folder).sections, str(folder / "driver.toml"), load_eds(folder / f"{drive.name}.eds")[0]
    )
    assert desc.modes["position"].setpoint == "interpolation_data"
    assert desc.modes["torque_injection"].hold == "target_position"
    assert "target_position" in desc.unmappable


def test_a_vendor_torque_stands_in_only_where_the_eds_has_no_standard_torque(tmp_path):
    folder = write_vendor_drive(tmp_path, IP_EFFORT)
    summary = inspect_eds(load_eds(folder / f"{IP_EFFORT.name}.eds")[0])
    assert summary.torque_reference == "none"
    assert summary.vendor_torque == ((0x2022, "Control effort", "torque_demand"),)
    plain = write_vendor_drive(tmp_path, VendorDrive("acme-limits", objects=[]))
    assert inspect_eds(load_eds(plain / "acme-limits.eds")[0]).torque_reference == "rated_torque"


def test_drivers_new_writes_the_vendor_torque_as_a_placeholder_and_the_folder_runs(tmp_path):
    from hilident.drivers.tools import check_driver_folder, new_driver_folder

    eds = write_vendor_drive(tmp_path / "vendor", IP_EFFORT) / f"{IP_EFFORT.name}.eds"
    report = new_driver_folder(eds, tmp_path / "acme")
    assert "canopen.objects.torque_demand" in report.placeholders
    assert "canopen.scaling.rated_torque_nm" in report.placeholders
    check = check_driver_folder(tmp_path / "acme")
    assert check.ok, check.errors
    desc = CanopenDescription.from_sections(
        load_driver(tmp_path / "acme").sections, "driver.toml", load_eds(tmp_path / "acme" / eds.name)[0]
    )
    assert desc.channels["torque_nm"] == "torque_demand" and "torque_cmd_nm" not in desc.channels
    assert desc.objects["torque_demand"].index == 0x2022


def test_many_late_syncs_are_a_warning_few_are_not():
    from hilident.session.experiment import late_sampling_warnings

    late = [{"kind": "sync_late", "message": "", "sample_index": 0, "value": 300.0, "worst_s": 0.054}]
    (warning,) = late_sampling_warnings("identification", late, 12000)
    assert "300 of 12000 SYNCs (2.5 %)" in warning and "54.0 ms" in warning and "run.sample_rate_hz" in warning
    assert late_sampling_warnings("identification", [dict(late[0], value=50.0)], 12000) == []
    assert late_sampling_warnings("identification", [{"kind": "lost_blocks", "value": 900.0}], 12000) == []


def test_a_reading_at_its_integer_limit_is_counted_clipped_with_one_event():
    from types import SimpleNamespace

    from hilident.adapters.base import RunResult
    from hilident.adapters.canopen.common import ChannelCodec
    from hilident.adapters.canopen.drive import CanopenDriveAdapter
    from hilident.events import StreamStats
    from hilident.protocol.canopen_types import ObjectAddress

    events = []
    stub = SimpleNamespace(
        layout=SimpleNamespace(
            channels=[
                ChannelCodec("excitation", "m/s", None, None, 0x8, 1.0),  # the host's own set-point: never
                ChannelCodec("torque_nm", "N*m", "current_actual", ObjectAddress(0x6078), 0x3, 5e-5),
            ]  # INTEGER16
        ),
        last_result=RunResult(10, StreamStats()),
        log_event=events.append,
        sdo=SimpleNamespace(describe=str),
    )
    raw = np.zeros((10, 2))
    raw[:, 0] = 40000.0  # beyond any INTEGER16, but recorded by the host
    raw[[3, 4, 7], 1] = [32767, -32768, 32767]
    CanopenDriveAdapter.count_saturated(stub, raw, 100)
    assert stub.last_result.stats.clipped_blocks == 3
    (event,) = events
    assert event.kind.value == "clipped" and event.sample_index == 103 and "torque_nm" in event.message
    CanopenDriveAdapter.count_saturated(stub, raw, 110)  # later blocks are counted, not announced again
    assert stub.last_result.stats.clipped_blocks == 6 and len(events) == 1
