"""CiA 402 drives as vendors describe them: standard objects only, found by index in their EDS.

Each drive folder is an EDS written by :mod:`vendor_drives` (modelled on traits
of real vendor files) plus a driver.toml of a dozen lines. The twin is built
from the folder alone, and a host-streamed session must find the resonance
with no sample lost; the host matches TPDOs to SYNCs by their order on the bus.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.config.tables import load_config
from hilident.drivers.description import check_run_against_driver, load_driver
from hilident.emulator.canopen.server import start
from hilident.emulator.factory import true_modes
from hilident.errors import ConfigError, DeviceError, LimitTrip
from hilident.io.recording import read_run
from hilident.session.run import Session
from support.twins import wait_until
from support.vendor_drives import FILTER_DRIVES, VendorDrive, write_vendor_drive

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-canopen-gantry.toml"
FS = 1000.0

DRIVES = {
    "plain": VendorDrive("acme-plain"),  # CSP/CSV/CST, 4+4 PDOs of 8 entries, 0x60C2, 0x6076 = 1000 mN*m
    # 4 entries per PDO, 2 RPDOs, the period in 0x1006 only, 0x6076 = 0 (the rated torque from driver.toml),
    # 0x6060 as UNSIGNED8, only a max-torque limit object, SYNC counter
    "narrow": VendorDrive(
        "acme-narrow",
        entries=4,
        rpdos=2,
        period="1006",
        torque="rated_zero",
        mode_type=0x5,
        limits=("max_torque",),
        sync_counter=True,
    ),
    # no 0x6502 default, current instead of torque, IP as the only cyclic mode
    # no heartbeat producer (0x1017), no heartbeat consumer: node guarding and life guarding instead
    "guarded": VendorDrive("acme-guarded", heartbeat=False),
    "ip-current": VendorDrive(
        "acme-ip",
        modes=("pp", "pv", "hm", "ip"),
        declare_modes=False,
        torque="current",
        limits=("max_velocity", "position_limits"),
    ),
}


def session_config(folder: Path, period_s=1.0, duration_s=3.0):
    cfg = load_config(CONFIG)
    # ten times real time (2500 SYNC cycles a second): at twenty a CI run's busy host held back enough set-points
    # (each a held torque that rings the mode) to have a family's resonance rejected
    emu = replace(cfg.emulator, time_scale=10.0)
    return replace(
        cfg,
        # 250 Hz: a host as busy as a test run sends its set-points in time (at 1 kHz a few in a hundred are held)
        run=replace(cfg.run, sample_rate_hz=250.0),
        device=replace(cfg.device, driver=str(folder), acquisition="streamed"),
        emulator=emu,
        friction_test=replace(cfg.friction_test, enabled=False),
        excitation=replace(cfg.excitation, period_s=period_s, duration_s=duration_s, amplitude_nm=8.0),
    )


@pytest.mark.parametrize("name", ["narrow"])
def test_a_whole_session_on_a_vendor_drive(tmp_path, name):
    folder = write_vendor_drive(tmp_path / "drivers", DRIVES[name])
    # three periods: a few set-points a busy host held back (each a held torque that sets the mode ringing) do
    # not hide the resonance, as they can in two
    cfg = session_config(folder, duration_s=4.0)
    session = Session(cfg, tmp_path / "out", plots=False)
    summary = session.run()
    ((true_f, _),) = true_modes(cfg.emulator)
    (res,) = summary["resonances"]
    assert abs(res["frequency_hz"] - true_f) / true_f < 0.005
    stream = summary["stream"]
    run = read_run(tmp_path / "out" / "identification.h5")
    n = run.n_samples
    assert n >= 2 * cfg.run.sample_rate_hz and stream["samples"] == n and stream["lost_samples"] == 0
    assert not session.emulator.drive.enabled
    assert run.complete and np.array_equal(run.samples["sample_index"], np.arange(n))
    # no filter capability described: the notch is designed and reported, not uploaded, and nothing is verified
    assert summary["upload"]["written"] is False and "no filter capability" in summary["upload"]["not_uploaded"]
    assert summary["verification"]["peak_reduction_db"] is None
    # the excitation column is the set-point the host sent (the drive has no object reporting it)
    assert np.ptp(run.samples["excitation"]) > 1.0


@pytest.fixture
def twin(tmp_path):
    opened = []

    def make(name, **device):
        folder = write_vendor_drive(tmp_path, DRIVES[name])
        driver = load_driver(folder)
        cfg = load_config(CONFIG)
        emu = start(replace(cfg.emulator, time_scale=20.0), driver, replace(cfg.device, driver=str(folder)))
        ad = CanopenDriveAdapter.open_device(
            replace(emu.device, acquisition="streamed", timeout_s=0.5, **device), driver
        )
        opened.append((ad, emu))
        lim = cfg.limits
        ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        return ad, emu

    yield make
    for ad, emu in opened:
        ad.close()
        emu.close()


def test_pdo_mapping_stays_within_the_drives_capacity(twin):
    ad, emu = twin("narrow")
    ad.configure(FS, "torque")
    fw = emu.server.firmware
    tpdos = [cfg for (kind, _), cfg in fw.pdos.items() if kind == "tpdo" and cfg.valid and cfg.entries]
    assert len(tpdos) == 2 and all(len(cfg.entries) <= 4 for cfg in tpdos)  # 4 channels of 16-32 bits, 4 a PDO
    assert fw.sync_divider == 4  # 0x1006 = 1000 us at a 4 kHz loop
    assert fw.node.sdo.upload(0x6060, 0) == bytes([10])  # CST, in the drive's UNSIGNED8
    result = ad.stream(np.zeros(500), lambda i, rows: None)
    assert result.completed and result.stats.samples == 500 and result.stats.lost_samples == 0


def test_modes_come_from_what_the_drive_reports(twin):
    # the EDS gives 0x6502 no default: the host asks the drive, which runs IP only among the cyclic modes
    ad, emu = twin("ip-current")
    assert ad.supported_modes == ("pp", "pv", "hm", "ip")
    assert set(ad.desc.modes) == {"position"} and ad.desc.modes["position"].code == 7
    with pytest.raises(DeviceError, match=r"no mode for 'torque'.*0x6502 says it supports pp, pv, hm, ip"):
        ad.configure(FS, "torque")
    ad.configure(FS, "position")
    fw = emu.server.firmware
    assert fw.interpolation_period == [1, -3] and fw.sync_divider == 4
    seen = []
    x = 1e-3 * np.sin(2 * np.pi * 5.0 * np.arange(1000) / FS)  # +-1 mm around where the axis holds
    result = ad.stream(x, lambda i, rows: seen.append(rows))
    rows = np.vstack(seen)
    assert result.stats.lost_samples == 0 and len(rows) == 1000
    position = rows[:, ad.channel_names.index("position_m")]
    assert 0.5e-3 < np.ptp(position) < 3e-3  # the axis followed the interpolated positions
    # torque from the current actual value times the torque constant: finite and not all zero
    torque = rows[:, ad.channel_names.index("torque_nm")]
    assert np.all(np.isfinite(torque)) and np.ptp(torque) > 0


def test_lost_tpdos_are_counted_at_their_sample_never_filled(tmp_path):
    drive = DRIVES["plain"]
    folder = write_vendor_drive(tmp_path, drive)
    driver = load_driver(folder)
    cfg = load_config(CONFIG)
    emu = start(
        replace(cfg.emulator, time_scale=20.0, faults=replace(cfg.emulator.faults, drop_pdo_rate=0.01)),
        driver,
        replace(cfg.device, driver=str(folder)),
    )
    ad = CanopenDriveAdapter.open_device(replace(emu.device, acquisition="streamed", timeout_s=0.5), driver)
    try:
        ad.set_limits(19.0, 0.4, -0.6, 0.6)
        ad.configure(FS, "torque")
        got = []
        x = np.sin(2 * np.pi * 3.0 * np.arange(2000) / FS)
        result = ad.stream(x, lambda i, rows: got.append((i, rows)))
        index = np.concatenate([i for i, _ in got])
        rows = np.vstack([r for _, r in got])
        fw = emu.server.firmware
        dropped = [(k, cob) for k, cob in fw.dropped if k < 2000]  # the drive clocks on after the run's last cycle
        assert dropped
        stats = result.stats
        gaps = stats.setpoints_skipped if result.clock["source"] == "host" else 0  # the host's clock skips cycles
        assert stats.samples + stats.lost_samples + gaps == 2000 and len(index) == stats.samples
        skipped = [
            np.arange(e["sample_index"], e["sample_index"] + int(e["value"]))
            for e in result.events
            if e["kind"] == "sync_skipped" and result.clock["source"] == "host"  # each marks a gap
        ]
        n_tpdos = len(ad.layout.tpdos)
        per_sample = {}
        for k, _ in dropped:
            per_sample[k] = per_sample.get(k, 0) + 1
        whole = sorted(k for k, count in per_sample.items() if count == n_tpdos)
        trusted = whole[0] if whole else 2000  # matched by order, samples after an unanswered SYNC shift
        partial = sorted(k for k, count in per_sample.items() if count < n_tpdos and k < trusted)
        # a set with a frame missing is a lost sample; a whole set missing shifts the samples after it by one
        # (the answers to the SYNCs after the run's last fill the end), which only the count tells
        assert stats.lost_frames == sum(count for count in per_sample.values() if count < n_tpdos)
        lost = np.setdiff1d(np.setdiff1d(np.arange(trusted), index), np.concatenate([[], *skipped]))
        assert np.array_equal(lost, partial)  # a set with a frame missing is lost at exactly its sample
        early = index < trusted
        # the drive's torque demand is the set-point of the very sample the host says it is (CST: demand = target):
        # the one it sent, or the one the drive held when the host could not send in time; a set-point sent a
        # few µs before its deadline may still reach the drive after it (rare: under 2 % on a busy machine)
        demand = rows[early, ad.channel_names.index("torque_cmd_nm")]
        recorded = rows[early, ad.channel_names.index("excitation")]
        assert np.count_nonzero(np.abs(demand - recorded) >= 2e-3) <= 0.02 * len(demand)
        unanswered = [e for e in result.events if e["kind"] == "sync_unanswered"]
        counted = unanswered[0]["value"] if unanswered else 0
        # by order alone the host cannot tell whether a drive answers the SYNC it stopped producing after: on
        # the drive's clock the last one is given the benefit of the doubt
        assert counted == len(whole) or (result.clock["source"] == "drive" and counted == len(whole) - 1)
    finally:
        ad.close()
        emu.close()


def test_the_host_checks_limits_the_drive_does_not_hold(twin):
    # the narrow drive holds only a torque limit: speed is checked by the host on every sample
    ad, emu = twin("narrow")
    ad.set_limits(19.0, 0.05, -0.6, 0.6)
    ad.configure(FS, "torque")
    x = np.full(3000, 3.0)  # 3 N*m on the free axis: it speeds up past 0.05 m/s
    got = []
    with pytest.raises(LimitTrip, match=r"velocity_limit: velocity_mps = .* \(checked by the host\)"):
        ad.stream(x, lambda i, rows: got.append(rows))
    rows = np.vstack(got)
    speed = rows[:, ad.channel_names.index("velocity_mps")]
    assert abs(speed[-1]) > 0.05 and np.all(np.abs(speed[:-1]) <= 0.05)  # delivered up to the tripping sample
    assert not emu.drive.enabled


def test_placeholders_run_on_the_emulator_and_are_refused_on_a_real_port(tmp_path):
    drive = VendorDrive("acme-guessed", extra_toml="")
    folder = write_vendor_drive(tmp_path, drive)
    text = (
        (folder / "driver.toml")
        .read_text()
        .replace(
            "default_baudrate = 1000000",
            'default_baudrate = 1000000\nplaceholders = ["canopen.scaling.position_unit_m"]',
        )
    )
    (folder / "driver.toml").write_text(text)
    driver = load_driver(folder)
    assert driver.placeholders == ("canopen.scaling.position_unit_m",)
    cfg = session_config(folder)
    check_run_against_driver(cfg, driver)  # the emulator takes guesses
    real = replace(cfg, device=replace(cfg.device, port="can0"))
    with pytest.raises(ConfigError, match=r"driver\.placeholders.*canopen\.scaling\.position_unit_m") as err:
        check_run_against_driver(real, driver)
    assert str(folder / "driver.toml") in str(err.value)


@pytest.mark.parametrize("drive", FILTER_DRIVES, ids=lambda d: d.filters)
def test_the_notch_goes_into_a_vendor_encoding_and_the_resonance_is_gone(tmp_path, drive):
    # REAL32 coefficients in the drive's own order, a Copley-style word block in one octet string, and
    # Kollmorgen-style pole/zero frequency and Q pairs: fitted to the encoding, read back, verified
    folder = write_vendor_drive(tmp_path / "drivers", drive)
    cfg = session_config(folder, duration_s=5.0)  # four periods averaged: a busy host's held set-points average out
    save = drive.filters == "biquad"  # --save on one of them: stored only after the verification
    session = Session(cfg, tmp_path / "out", plots=False, save=save)
    summary = session.run()
    upload = summary["upload"]
    assert upload["written"] and upload["verified_readback"], summary["warnings"]
    assert summary["verification"]["peak_reduction_db"] >= 20.0
    biquad, enabled = session.emulator.drive.filters.read(0)
    assert enabled and biquad.b == tuple(upload["slots"][0]["readback_b"])
    fw = session.emulator.server.firmware
    assert upload["saved"] is save and fw.saves == int(save)  # nothing stored in the drive without --save
    if save:  # what the drive stored is the verified notch
        stored, stored_enabled = fw.stored_parameters[0]
        assert stored_enabled and stored.b == biquad.b and "0x1010:1" in upload["saved_with"]


def test_a_drive_without_heartbeat_is_node_guarded_and_stops_when_the_host_goes_silent(twin):
    ad, emu = twin("guarded")
    assert "life guarding 0x100C x 0x100D: 50 ms" in ad.connect_report.device_net
    ad.configure(FS, "torque")
    result = ad.stream(np.zeros(500), lambda i, rows: None)
    assert result.completed and result.stats.lost_samples == 0  # the guard answers kept the link alive
    ad.enable()
    assert emu.drive.enabled
    ad.node.nmt.stop_node_guarding()  # the host dies: no more guard requests, life guarding not disarmed
    silent = time.monotonic()
    lifetime_s = 50 * int(emu.server.firmware.stored(0x100D, 0)) / 1000.0
    stopped = wait_until(lambda: not emu.drive.enabled, lifetime_s + 2.0)
    assert stopped - silent < lifetime_s + 0.5 and emu.server.firmware.heartbeat_events == 1
