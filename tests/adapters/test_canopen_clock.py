"""Who keeps the bus clock of a streamed CANopen run, and that the host's own clock never bursts."""

from __future__ import annotations

import gc
import shutil
import threading
import time
from dataclasses import replace

import can
import numpy as np
import pytest

from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.adapters.canopen.streamed import StreamedRun
from hilident.adapters.canopen.sync_source import SyncTiming, choose_sync_source
from hilident.config.tables import load_config, parse_config
from hilident.drivers.description import find_driver, load_driver
from hilident.emulator.canopen.server import start
from hilident.emulator.factory import start_emulator
from hilident.errors import ConfigError, DeviceError
from hilident.protocol.canopen_sync import SyncCapability

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "emulated-cia402-gantry.toml"
FS = 1000.0

PRODUCER = SyncCapability(producer=True, window_us=400)
CONSUMER = SyncCapability(producer=False, window_us=400)


# --- the choice ---------------------------------------------------------------------------------------------


def test_auto_takes_the_drive_first_then_the_interface_then_the_host():
    assert choose_sync_source("auto", PRODUCER, True, None).source == "drive"
    assert choose_sync_source("auto", PRODUCER, False, True).source == "interface"  # 0x1005 read-only
    assert choose_sync_source("auto", CONSUMER, True, True).source == "interface"
    host = choose_sync_source("auto", CONSUMER, True, False)
    assert host.source == "host" and "Python loop" in host.why


def test_a_source_asked_for_that_is_not_there_is_a_config_error_naming_the_key():
    with pytest.raises(ConfigError, match=r"device\.canopen\.sync_source.*producer = true"):
        choose_sync_source("drive", CONSUMER, True, None)
    with pytest.raises(ConfigError, match=r"sync_source.*Python thread"):
        choose_sync_source("interface", PRODUCER, True, False)
    assert choose_sync_source("host", PRODUCER, True, True).source == "host"


def test_the_host_stays_within_three_quarters_of_the_drives_window_and_below_0_4_period():
    assert SyncCapability(window_us=400).host_window_s(1e-3) == pytest.approx(300e-6)
    assert SyncCapability(window_us=4000).host_window_s(1e-3) == pytest.approx(400e-6)
    assert SyncCapability(window_us=0).host_window_s(4e-3) == pytest.approx(1.6e-3)


def test_the_timing_report_measures_period_jitter_and_syncs_outside_the_window():
    rng = np.random.default_rng(1)
    period = 1e-3
    cycles = np.arange(5000)
    instants = 1.0001 * period * cycles + rng.normal(0, 5e-6, len(cycles))
    instants[1000] += 0.8e-3  # one SYNC far outside a 100 µs window: two intervals out
    timing = SyncTiming(period, 100e-6, len(cycles))
    for k, t in zip(cycles, instants, strict=True):
        timing.add(int(k), float(t))
    report = timing.report()
    assert report["period_s"] == pytest.approx(1.0001e-3, rel=1e-5)
    assert 2e-6 < report["jitter_p50_s"] < 6e-6
    assert report["jitter_max_s"] == pytest.approx(0.8e-3, rel=0.05)
    assert report["outside_window"] == 2
    assert sum(report["histogram_us"]["counts"]) == len(cycles)


def emulated_drive(ad):
    return ad.emulated_for_test.server.firmware.drive


# --- the host's clock on the twin ---------------------------------------------------------------------------


class SyncListener(can.Listener):
    """Every SYNC on a virtual channel, with the sender's timestamp."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.instants: list[float] = []
        self.notifier = can.Notifier(self.bus, [self])

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == 0x80:
            self.instants.append(msg.timestamp)

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def host_clock_adapter(tmp_path, loss_timeout_ms: int, source: str = "host"):
    """The shipped drive's twin with ``loss_timeout_ms``, and an adapter that runs it on the ``source`` clock."""
    cfg = load_config(CONFIG)
    folder = tmp_path / "cia402-standard"
    shutil.copytree(find_driver("cia402-standard").folder, folder)
    toml = folder / "driver.toml"
    text = toml.read_text()
    assert "loss_timeout_ms = 100" in text
    toml.write_text(text.replace("loss_timeout_ms = 100", f"loss_timeout_ms = {loss_timeout_ms}"))
    driver = load_driver(folder)
    emulated = start(cfg.emulator, driver, cfg.device)
    dev = replace(emulated.device, acquisition="streamed", canopen=replace(emulated.device.canopen, sync_source=source))
    ad = CanopenDriveAdapter.open_device(dev, driver)
    lim = cfg.limits
    ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
    return ad, emulated


@pytest.fixture
def host_clock_run(tmp_path):
    # a SYNC loss timeout of a second: a machine as busy as the test suite can hold the host's clock thread up
    # for longer than the drive's 100 ms (these tests are about the host's clock)
    ad, emulated = host_clock_adapter(tmp_path, 1000)
    listener = SyncListener(emulated.server.channel)
    ad.emulated_for_test = emulated
    yield ad, listener
    listener.close()
    ad.close()
    emulated.close()


def test_a_stalled_host_skips_the_cycles_it_missed_and_never_bursts(host_clock_run, monkeypatch):
    ad, listener = host_clock_run
    ad.configure(FS, "torque")
    stalled = threading.Event()
    send_due = StreamedRun._send_due

    def stall_once_then_send(self, now):  # half a second in, the host's clock thread stalls for 30 ms
        if not stalled.is_set() and self.sent > 500:
            stalled.set()
            time.sleep(0.030)
            now = time.perf_counter()
        send_due(self, now)

    monkeypatch.setattr(StreamedRun, "_send_due", stall_once_then_send)
    indices: list[np.ndarray] = []
    result = ad.stream(np.zeros(1500), lambda i, rows: indices.append(i))
    assert stalled.is_set() and result.completed
    gaps = np.diff(listener.instants)
    # no burst after the stall: never three SYNCs within one period (two may meet when the OS holds up a send)
    assert np.all(gaps[:-1] + gaps[1:] > 0.75e-3) and np.count_nonzero(gaps < 0.25e-3) <= 3
    assert gaps.max() > 25e-3  # the stall shows on the bus as a pause, not as a catch-up
    skipped = result.stats.setpoints_skipped
    assert skipped >= 25
    got = np.concatenate(indices)
    stats = result.stats
    # skipped cycles have no sample and are not counted lost (on a busy machine a send the OS held up may
    # still reach the drive too early for its cycle: that SYNC's sample is lost, and counted)
    assert len(got) == stats.samples and stats.samples + stats.lost_samples + skipped == 1500
    assert stats.lost_samples <= 3
    assert result.clock["source"] == "host" and result.clock["setpoints_skipped"] == skipped
    assert any(e["kind"] == "sync_skipped" for e in result.events)


COUNTED = """
[device]
driver = "canopen-servo"
acquisition = "streamed"
[device.canopen]
sync_source = "host"
[emulator]
preset = "clean"
"""


def test_a_clock_thread_that_starts_late_names_every_sample_by_the_cycle_the_drive_ran(monkeypatch):
    cfg = parse_config(COUNTED, "counted.toml")
    driver = find_driver(cfg.device.driver)
    emulated = start_emulator(cfg.emulator, driver, cfg.device)
    host_clock = StreamedRun._host_clock

    def start_late(self):  # the thread begins 5 periods after it was started, as on a busy machine
        time.sleep(0.005)
        host_clock(self)

    monkeypatch.setattr(StreamedRun, "_host_clock", start_late)
    x = np.random.default_rng(4).uniform(-1.0, 1.0, 1000)
    blocks: list[tuple[np.ndarray, np.ndarray]] = []
    ad = CanopenDriveAdapter.open_device(emulated.device, driver, link=emulated.link)
    try:
        ad.set_limits(19.0, 0.4, -0.6, 0.6)
        channels = ad.configure(FS, "torque")
        result = ad.stream(x, lambda i, rows: blocks.append((i, rows)))
    finally:
        ad.close()
        emulated.close()
    index = np.concatenate([i for i, _ in blocks])
    applied = np.concatenate([r for _, r in blocks])[:, channels.index("excitation")]
    # the set-point the drive reports it applied at each sample (its own object, on a drive with the hilident
    # counters) is the host's for that sample: no sample is named by a cycle the drive never saw a SYNC of
    assert np.mean(np.abs(applied - x[index]) < 1e-3) > 0.98
    assert result.stats.underruns <= result.stats.setpoints_skipped + 3


def test_the_strict_twin_faults_a_host_that_bursts_after_a_stall(host_clock_run, monkeypatch):
    """The loop of earlier releases sent every overdue SYNC at once after a stall: the drive's sync error."""
    ad, listener = host_clock_run
    ad.configure(FS, "torque")
    stalled = threading.Event()

    def burst_send_due(self, now):
        if not stalled.is_set() and self.sent > 100:  # the host stalls for 30 ms once ...
            stalled.set()
            time.sleep(0.030)
            now = time.perf_counter()
        while self.sent < self.n and now >= self.t0 + self.sent * self.period:  # ... then catches up at once
            self.ad.network.send_message(self.rpdo.cob_id, self._pack(self.sent, self.setpoints[self.sent]))
            self.ad.network.send_message(0x80, b"")
            self.sync_cycle[self.syncs] = self.sent
            self.syncs += 1
            self.sent = self.next_cycle = self.sent + 1

    monkeypatch.setattr(StreamedRun, "_send_due", burst_send_due)
    with pytest.raises(DeviceError, match=r"EMCY 0x8700 sync controller"):
        ad.stream(np.zeros(1500), lambda i, rows: None)
    assert np.count_nonzero(np.diff(listener.instants) < 0.2e-3) >= 2  # SYNCs went out back to back ...
    assert not emulated_drive(ad).enabled  # ... and the drive stopped the axis
    assert ad.last_result is not None and not ad.last_result.completed


def test_the_host_clock_stops_the_drive_before_its_syncs_stop(tmp_path, monkeypatch):
    """A drive in a cyclic mode faults when the SYNCs stop (loss timeout, EMCY 0x8250): the run's ending commands
    it safe first, however long the host then takes to finish the run."""
    ad, emulated = host_clock_adapter(tmp_path, 100)
    settle = StreamedRun._settle

    def slow_settle(self):  # the host is held up for three loss timeouts after its last SYNC, then talks
        time.sleep(0.3)
        self.ad.sdo.read("statusword")  # a frame after the deadline: the drive knows the SYNC is missing
        time.sleep(0.05)
        settle(self)

    monkeypatch.setattr(StreamedRun, "_settle", slow_settle)
    try:
        ad.configure(250.0, "torque")
        result = ad.stream(np.zeros(250), lambda i, rows: None)
        firmware = emulated.server.firmware
        assert result.completed and ad.run_fault is None
        assert firmware.drive.fault is None and not firmware.drive.enabled
        assert not any("0x8250" in e.get("message", "") for e in result.events)
    finally:
        ad.close()
        emulated.close()


@pytest.mark.parametrize("source", ["drive", "host"])
def test_a_run_leaves_no_frames_piling_up_in_the_process(tmp_path, source):
    """Every frame of a run is taken by whoever receives it: a bus that only sends (the twin's SYNC producer)
    must not keep a copy of each, or the heap grows and the collector's pauses stall the clock threads."""
    ad, emulated = host_clock_adapter(tmp_path, 1000, source)
    try:
        ad.configure(FS, "torque")
        result = ad.stream(np.zeros(3000), lambda i, rows: None)
        assert result.completed and result.clock["source"] == source
        gc.collect()
        frames = sum(type(o) is can.Message for o in gc.get_objects())
        assert frames < 1000  # a run of 3000 cycles sends more than 6000 frames
    finally:
        ad.close()
        emulated.close()


# --- the interpolation data buffer ------------------------------------------------------------------------


def ip_drive_adapter(tmp_path, buffer_records: int):
    """The shipped drive, its position runs in interpolated position mode, its buffer ``buffer_records`` deep."""
    cfg = load_config(CONFIG)
    folder = tmp_path / "cia402-standard"
    shutil.copytree(find_driver("cia402-standard").folder, folder)
    toml, eds = folder / "driver.toml", folder / "cia402-standard.eds"
    text = toml.read_text()
    assert 'cyclic_modes = ["cst", "csv", "csp", "ip"]' in text
    toml.write_text(text.replace('cyclic_modes = ["cst", "csv", "csp", "ip"]', 'cyclic_modes = ["cst", "csv", "ip"]'))
    text = eds.read_text()
    maximum = "ParameterName=Maximum buffer size\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\nPDOMapping=0\n"
    assert maximum + "DefaultValue=16" in text
    eds.write_text(text.replace(maximum + "DefaultValue=16", maximum + f"DefaultValue={buffer_records}"))
    driver = load_driver(folder)
    emulated = start(cfg.emulator, driver, cfg.device)
    dev = replace(
        emulated.device, acquisition="streamed", canopen=replace(emulated.device.canopen, sync_source="drive")
    )
    ad = CanopenDriveAdapter.open_device(dev, driver)
    lim = cfg.limits
    ad.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
    return ad, emulated


@pytest.mark.parametrize("records", [16, 1])
def test_a_drive_that_buffers_its_set_points_rides_out_a_host_held_up_for_three_cycles(tmp_path, monkeypatch, records):
    """In interpolated position mode with a buffer (0x60C4) the host keeps the set-points cycles ahead: a stall
    shorter than that costs nothing; without one, every set-point the stall made late is held."""
    ad, emulated = ip_drive_adapter(tmp_path, records)
    on_sync = StreamedRun.on_sync
    stalled = threading.Event()

    def stall_once(self, can_id, data, timestamp):
        if self.heard == 100 and not stalled.is_set():
            stalled.set()
            time.sleep(3 * self.period)  # the host does nothing for three cycles
        on_sync(self, can_id, data, timestamp)

    monkeypatch.setattr(StreamedRun, "on_sync", stall_once)
    try:
        ad.configure(250.0, "position")
        assert ad.layout.pdo_plan.rpdos[0].transmission == 255  # the EDS has 0x60C4: event-driven set-points
        x = 2e-4 * np.sin(2 * np.pi * 3.0 * np.arange(500) / 250.0)
        buffers = []

        def sink(index, rows):
            buffers.append(emulated.server.firmware.setpoints.buffer.size)

        result = ad.stream(x, sink)
        assert stalled.is_set() and result.completed and result.stats.lost_samples == 0
        buffer = emulated.server.firmware.setpoints.buffer
        if records > 1:
            assert max(buffers) == records and result.stats.setpoints_skipped == 0
            assert buffer.overflows == 0
        else:
            assert result.stats.setpoints_skipped >= 2  # the stall's cycles, held
        assert not buffer.enabled  # cleared and disabled when the run ended
    finally:
        ad.close()
        emulated.close()


def test_a_position_run_on_a_drive_whose_following_error_window_is_0_is_refused_before_anything_moves(tmp_path):
    """CiA 402: with 0x6065 = 0 any distance from the set-point is a following error, and the drive faults on the
    first sample (an EDS without a default gives its twin 0): refused at configure, naming the object."""
    cfg = load_config(CONFIG)
    folder = tmp_path / "cia402-standard"
    shutil.copytree(find_driver("cia402-standard").folder, folder)
    eds = folder / "cia402-standard.eds"
    window = "ParameterName=Following error window\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\nPDOMapping=0\n"
    assert window + "DefaultValue=0x186A0" in eds.read_text()
    eds.write_text(eds.read_text().replace(window + "DefaultValue=0x186A0", window + "DefaultValue=0"))
    driver = load_driver(folder)
    emulated = start(cfg.emulator, driver, cfg.device)
    dev = replace(emulated.device, acquisition="streamed")
    ad = CanopenDriveAdapter.open_device(dev, driver)
    try:
        ad.configure(250.0, "torque")  # no position loop: nothing to refuse
        with pytest.raises(DeviceError, match=r"0x6065.* is 0: with its position loop closed"):
            ad.configure(250.0, "position")
        assert not emulated.server.firmware.drive.enabled
    finally:
        ad.close()
        emulated.close()


def test_the_twin_holds_the_following_error_window_its_driver_folder_gives_where_the_eds_gives_none(tmp_path):
    cfg = load_config(CONFIG)
    folder = tmp_path / "cia402-standard"
    shutil.copytree(find_driver("cia402-standard").folder, folder)
    eds, toml = folder / "cia402-standard.eds", folder / "driver.toml"
    eds.write_text(eds.read_text().replace("DefaultValue=0x186A0\n", ""))  # 0x6065 without a default
    toml.write_text(toml.read_text() + '\n[emulator]\nvalues = { "0x6065" = 50000 }\n')
    driver = load_driver(folder)
    emulated = start(cfg.emulator, driver, cfg.device)
    ad = CanopenDriveAdapter.open_device(replace(emulated.device, acquisition="streamed"), driver)
    try:
        assert int(ad.sdo.read("following_error_window")) == 50000
        ad.configure(250.0, "position")  # not refused: the drive holds a window
    finally:
        ad.close()
        emulated.close()
    toml.write_text(toml.read_text().replace('values = { "0x6065" = 50000 }', 'values = { "0x6099" = 1 }'))
    with pytest.raises(ConfigError, match=r"emulator.values.*0x6099"):
        start(cfg.emulator, load_driver(folder), cfg.device)
