"""The CANopen adapter against the emulated drive on the virtual bus: runs, faults, filters, traces."""

from __future__ import annotations

import shutil
import time
from dataclasses import replace
from pathlib import Path

import can
import numpy as np
import pytest

from hilident.adapters.backends import adapter_class
from hilident.adapters.canopen.drive import CanopenDriveAdapter
from hilident.adapters.canopen.link import bus_arguments, parse_socketcand_port
from hilident.config.tables import CanopenDeviceConfig, DeviceConfig, load_config
from hilident.drivers.description import find_driver, load_driver
from hilident.emulator.canopen.server import start
from hilident.errors import ConfigError, DeviceError, LimitTrip
from hilident.filters.notch import NotchSpec, design_notch
from hilident.protocol import cia402
from hilident.protocol.canopen_types import ObjectAddress

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "emulated-canopen-gantry.toml"
FS = 1000.0


class Rig:
    """An emulated drive and an adapter on it, limits loaded."""

    def __init__(self, acquisition="buffered", driver="canopen-servo", time_scale=20.0, device=None, **faults):
        cfg = load_config(CONFIG)
        self.cfg = cfg
        emu = replace(cfg.emulator, time_scale=time_scale, faults=replace(cfg.emulator.faults, **faults))
        self.driver = find_driver(driver)
        self.emulated = start(emu, self.driver, cfg.device)
        self.device = replace(self.emulated.device, acquisition=acquisition, timeout_s=0.5, **(device or {}))
        self.adapter = None
        self.adapter = CanopenDriveAdapter.open_device(self.device, self.driver)
        lim = cfg.limits
        self.adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)

    def run(self, x, mode="torque", channels=None):
        self.adapter.configure(FS, mode, channels)
        got = []
        result = self.adapter.stream(x, lambda i, r: got.append((i, r)))
        return result, *_joined(got)

    def close(self):
        if self.adapter is not None:
            self.adapter.close()
        self.emulated.close()


def _joined(got):
    if not got:
        return np.zeros(0, np.int64), np.zeros((0, 0))
    return np.concatenate([g[0] for g in got]), np.concatenate([g[1] for g in got])


@pytest.fixture
def rig():
    made = []

    def make(*args, **kwargs):
        r = Rig(*args, **kwargs)
        made.append(r)
        return r

    yield make
    for r in made:
        r.close()


def multisine(n, amplitude=4.0):
    t = np.arange(n) / FS
    return amplitude / 3 * (np.sin(2 * np.pi * 5 * t) + np.sin(2 * np.pi * 21 * t + 1) + np.sin(2 * np.pi * 40 * t + 2))


def test_entry_point_and_identity(rig):
    assert adapter_class("canopen") is CanopenDriveAdapter
    r = rig()
    ident = r.adapter.identity
    assert ident.name == "hilident CiA 402 servo" and ident.firmware == "1.0"
    assert (ident.loop_rate_hz, ident.filter_slots) == (4000.0, 4)
    assert r.device.port in r.adapter.port and "node 1" in r.adapter.port
    assert r.emulated.drive.torque_limit_nm == pytest.approx(19.0)


def test_both_acquisitions_record_the_same_physics(rig):
    n = 600
    x = np.round(multisine(n) * 8) / 8  # multiples of 125 mN*m: exact in INTEGER16 mN*m and in REAL32
    results = {}
    for acquisition in ("streamed", "buffered"):
        r = rig(acquisition)
        result, index, rows = r.run(x)
        assert result.completed and result.stats.samples == n and result.stats.lost_samples == 0
        assert np.array_equal(index, np.arange(n))
        names = r.adapter.channel_names
        assert names == ["excitation", "torque_cmd_nm", "torque_nm", "position_m", "velocity_mps"]
        assert np.allclose(rows[:, 1], rows[:, 0], atol=1.5e-3)  # CST: torque demand = the applied set-point
        assert not r.emulated.drive.enabled and r.adapter.drive_state() is cia402.State.SWITCH_ON_DISABLED
        results[acquisition] = rows
        if acquisition == "streamed":
            # the drive keeps the clock: a set-point the host could not send in time is held, and recorded so
            # the drive keeps the clock: a set-point that came too late for its cycle is held (one of the drive's
            # underruns; a held value may equal the late one); the drive reports the one it applied
            held = np.flatnonzero(~np.isclose(rows[:, 0], x, atol=1e-6))
            assert len(held) <= result.stats.underruns
            x = rows[:, 0].copy()  # the buffered run plays what the drive applied
        else:
            assert np.allclose(rows[:, 0], x, atol=1e-6)
            assert any(e["kind"] == "capture_end" for e in result.events)
    # same plant, same seed, same applied set-points: the same samples whichever way they travelled
    assert np.array_equal(results["streamed"], results["buffered"])


def test_buffered_run_over_segmented_transfer(rig, tmp_path):
    folder = tmp_path / "segmented-servo"
    shutil.copytree(find_driver("canopen-servo").folder, folder)
    toml = folder / "driver.toml"
    toml.write_text(toml.read_text().replace("block_transfer = true", "block_transfer = false"))
    r = rig("buffered")
    adapter = CanopenDriveAdapter.open_device(r.device, load_driver(folder))
    try:
        assert not adapter.desc.block_transfer
        adapter.set_limits(19.0, 0.4, -0.6, 0.6)
        adapter.configure(FS, "torque")
        got = []
        x = multisine(300)
        result = adapter.stream(x, lambda i, rows: got.append(rows))
        assert result.completed and np.allclose(np.concatenate(got)[:, 0], x, atol=1e-6)
    finally:
        adapter.close()


@pytest.mark.parametrize("acquisition", ["streamed", "buffered"])
def test_velocity_and_torque_injection_modes(rig, acquisition):
    r = rig(acquisition)
    push = np.full(500, 2.0)  # 20 N on the cart, ten times its Coulomb friction
    _, _, rows = r.run(push, mode="torque_injection")
    assert r.emulated.drive.mode == "torque_injection" and np.allclose(rows[:, 0], push)
    held = np.ptp(rows[:, 3])
    _, _, rows = r.run(push, mode="torque")
    free = np.ptp(rows[:, 3])
    assert held < 1e-3 < 2e-2 < free  # injected: the position loop holds; torque mode: the cart runs off
    _, _, rows = r.run(np.full(800, 0.05), mode="velocity")
    assert r.emulated.drive.mode == "velocity"
    assert np.mean(rows[-200:, 4]) == pytest.approx(0.05, rel=0.02)


@pytest.mark.parametrize("acquisition", ["streamed", "buffered"])
def test_position_mode_is_relative_to_where_the_axis_stands(rig, acquisition):
    r = rig(acquisition)
    _, _, rows = r.run(np.full(300, 3.0), mode="torque")  # push the cart away from zero first
    time.sleep(0.3)  # the drive lets the axis coast to rest (2 s at time scale 20)
    start = r.emulated.drive.sensors.encoder(r.emulated.drive.plant.p1)
    assert abs(start) > 5e-3
    _, _, rows = r.run(np.full(1500, 2e-3), mode="position")  # 2 mm step
    assert np.allclose(rows[:, 0], 2e-3, atol=1.5e-7)  # the applied set-point, relative (one increment: 1e-7 m)
    assert rows[0, 3] == pytest.approx(start, abs=1e-6)
    assert rows[-1, 3] == pytest.approx(start + 2e-3, abs=1e-4)


def test_limit_trip_delivers_samples_then_raises(rig):
    r = rig("streamed")
    x = np.concatenate([np.full(100, 2.0), np.full(100, 25.0)])  # beyond limits.torque_nm = 19
    got, applied = [], []
    r.adapter.configure(FS, "torque")
    column = r.adapter.channel_names.index("excitation")
    with pytest.raises(LimitTrip, match="torque_limit"):
        r.adapter.stream(x, lambda i, rows: (got.append(i), applied.append(rows[:, column])))
    index = np.concatenate(got)
    # every sample up to and including the trip (and, on the drive's clock, those already on their way)
    assert np.array_equal(index[:101], np.arange(101)) and np.array_equal(index, np.arange(len(index)))
    trip = [e for e in r.adapter.last_result.events if e["kind"] == "limit_trip"]
    # at the first sample the drive applied 25 N*m: sample 100, or later when a busy host's set-point came too late
    # for its cycle and the drive held the one before (the recording holds what was applied)
    first = int(np.flatnonzero(np.concatenate(applied) > 19.0)[0])
    assert first == 100 or r.adapter.last_result.stats.setpoints_skipped > 0
    assert trip and trip[0]["sample_index"] == first and trip[0]["code"] == 0x8311
    assert not r.emulated.drive.enabled and r.adapter.drive_state() is cia402.State.FAULT


def test_fault_reset_only_when_allowed(rig):
    r = rig("buffered")
    r.adapter.configure(FS, "torque")
    with pytest.raises(LimitTrip):
        r.adapter.stream(np.full(200, 25.0), lambda i, rows: None)
    with pytest.raises(DeviceError, match="allow_fault_reset") as err:
        r.adapter.stream(np.zeros(100), lambda i, rows: None)
    assert "0x8311" in str(err.value)  # the drive's error code, with its meaning
    r.adapter.device = replace(r.adapter.device, allow_fault_reset=True)
    result = r.adapter.stream(np.zeros(100), lambda i, rows: None)
    assert result.completed


def test_drive_fault_emergency_stops_the_run(rig):
    r = rig("buffered", drive_fault_after_s=0.3)
    with pytest.raises(DeviceError, match="EMCY 0x4310") as err:
        r.run(np.zeros(1000))
    assert "temperature" in str(err.value)
    ev = [e for e in r.adapter.last_result.events if e["kind"] == "emergency"]
    assert ev and ev[0]["sample_index"] == 300  # 0.3 s into the run
    assert r.adapter.last_result.stats.samples == 300
    assert not r.emulated.drive.enabled


def test_heartbeat_loss_stops_the_run(rig):
    r = rig("streamed", heartbeat_stops_after_s=0.2)
    with pytest.raises(DeviceError, match="heartbeat lost"):
        r.run(np.zeros(2000))
    assert not r.emulated.drive.enabled
    assert 200 <= r.adapter.last_result.stats.samples < 2000


def test_sdo_abort_names_object_and_meaning(rig):
    with pytest.raises(DeviceError) as err:
        rig("buffered", abort_object="0x6072")
    text = str(err.value)
    assert "0x6072:0 (Max torque)" in text and "0x06060000" in text and "hardware error" in text


def test_lost_tpdos_are_counted_never_filled(rig):
    r = rig("streamed", drop_pdo_rate=0.05)
    result, index, rows = r.run(multisine(1000))
    s = result.stats
    assert s.lost_frames > 0 and s.lost_samples > 0 and s.lost_blocks == s.lost_samples
    assert s.samples + s.lost_samples == 1000 == len(index) + s.lost_samples
    assert np.all(np.diff(index) >= 1) and not np.all(np.diff(index) == 1)
    assert np.all(np.isfinite(rows))
    assert 0.5 < s.lost_frames / (3 * 1000 * 0.05) < 1.5  # 3 TPDOs a sample, 5 % dropped
    assert any(e["kind"] == "lost_blocks" for e in result.events)


def test_silent_tpdos_end_a_streamed_run(rig):
    r = rig("streamed", drop_pdo_rate=1.0)  # the drive runs but no TPDO ever reaches the host
    with pytest.raises(DeviceError, match="lag .* behind the SYNCs"):
        r.run(np.zeros(5000))
    res = r.adapter.last_result
    assert res.stats.samples == 0 and res.stats.lost_samples > 0 and 1000 <= r.emulated.drive.tick // 4 < 5000
    assert not r.emulated.drive.enabled


def test_short_capture_is_reported(rig):
    r = rig("buffered", capture_stops_after_s=0.25)
    got = []
    r.adapter.configure(FS, "torque")
    with pytest.raises(DeviceError, match="captured only 250 of 1000"):
        r.adapter.stream(np.zeros(1000), lambda i, rows: got.append(i))
    assert np.array_equal(np.concatenate(got), np.arange(250))
    res = r.adapter.last_result
    assert res.stats.lost_samples == 750 and any(e["kind"] == "capture_short" for e in res.events)
    assert not r.emulated.drive.enabled


def test_table_too_long_names_the_key(rig):
    r = rig("buffered")
    r.adapter.configure(FS, "torque")
    with pytest.raises(DeviceError, match='acquisition = "streamed"'):
        r.adapter.stream(np.zeros(131073), lambda i, rows: None)


@pytest.mark.parametrize("driver", ["canopen-servo", "canopen-servo-fixed"])
def test_filters_round_trip_through_the_drive(rig, driver):
    r = rig("buffered", driver=driver)
    ad = r.adapter
    spec = NotchSpec(center_hz=21.8, width_hz=6.5, depth_db=40.0)
    design = design_notch(spec, ad.identity.loop_rate_hz)
    saved = ad.save_filter(0)
    ad.write_filter(0, design, spec, enabled=False)
    stored, enabled = ad.read_filter(0)
    assert stored == ad.stored_form(design, spec) and not enabled
    assert r.emulated.drive.filters.read(0) == (stored, False)  # the plant's filter is what was read back
    ad.write_filter(0, design, spec, enabled=True)
    assert r.emulated.drive.filters.read(0) == (stored, True)
    h = stored.response(np.array([21.8]), ad.identity.loop_rate_hz)
    assert 20 * np.log10(abs(h[0])) < -35
    ad.restore_filter(0, saved)
    biquad, on = r.emulated.drive.filters.read(0)
    assert not on and np.allclose(biquad.b, (1, 0, 0)) and np.allclose(biquad.a, (1, 0, 0))


@pytest.mark.parametrize("suffix, reader", [(".asc", can.ASCReader), (".blf", can.BLFReader)])
def test_trace_of_a_run(rig, tmp_path, suffix, reader):
    r = rig("streamed")
    path = tmp_path / f"run{suffix}"
    r.adapter.set_trace(path)
    result, _, _ = r.run(np.zeros(50))
    frames = list(reader(str(path)))
    ids = [m.arbitration_id for m in frames]
    syncs = ids.count(0x80)  # every SYNC the drive produced from the run's first to when it was told to stop
    assert 50 <= syncs <= 300 and result.clock["source"] == "drive"  # the stop is an SDO round trip away
    assert ids.count(0x181) >= 50  # a TPDO1 per cycle
    assert ids.count(0x201) == 50 - result.stats.setpoints_skipped  # an RPDO1 per set-point sent
    r.run(np.zeros(10))  # the trace covers one run only
    assert [m.arbitration_id for m in reader(str(path))].count(0x80) == syncs


def test_identity_mismatch_and_silent_node(rig, tmp_path):
    r = rig("buffered")
    folder = tmp_path / "other-servo"
    shutil.copytree(r.driver.folder, folder)
    toml = folder / "driver.toml"
    toml.write_text(toml.read_text().replace("product_code = 0x00040201", "product_code = 0x00040299"))
    with pytest.raises(DeviceError, match="0x1018:2") as err:
        CanopenDriveAdapter.open_device(r.device, load_driver(folder))
    assert "0x00040299" in str(err.value)
    with pytest.raises(DeviceError, match="no valid SDO answer") as err:
        CanopenDriveAdapter.open_device(
            replace(r.device, canopen=replace(r.device.canopen, node_id=9), timeout_s=0.1), r.driver
        )
    assert "node 9" in str(err.value)


def test_the_adapter_owns_its_parts_and_inherits_from_the_template_only(rig):
    # the parts are members, never bases: no part's method can come before AdapterBase's in the adapter's MRO
    from hilident.adapters.base import AdapterBase
    from hilident.adapters.canopen.common import RunLayout
    from hilident.adapters.canopen.mapping import ChannelMapping
    from hilident.adapters.canopen.net import NetWatch
    from hilident.adapters.canopen.sdo import SdoAccess
    from hilident.adapters.canopen.slots import CanopenFilterSlots

    assert CanopenDriveAdapter.__mro__ == (CanopenDriveAdapter, AdapterBase, object)
    ad = rig("streamed").adapter
    assert isinstance(ad.sdo, SdoAccess) and isinstance(ad.net, NetWatch)
    assert isinstance(ad.mapping, ChannelMapping) and isinstance(ad.slots, CanopenFilterSlots)
    assert ad.net.sdo is ad.sdo and ad.mapping.sdo is ad.sdo and ad.slots.sdo is ad.sdo
    assert ad.layout == RunLayout()  # nothing configured yet
    ad.configure(FS, "torque")
    layout = ad.layout
    assert layout.acquisition == "streamed" and layout.mode == "torque" and layout.sample_rate_hz == FS
    assert [c.name for c in layout.channels] == ad.channel_names
    assert layout.rpdo is not None and layout.rpdo.setpoint_role == ad.desc.modes["torque"].setpoint
    assert sorted(j for t in layout.tpdos for j in t.columns) == [
        j for j, c in enumerate(layout.channels) if not c.on_host
    ]


def test_bus_arguments_from_the_device_table():
    assert parse_socketcand_port("127.0.0.1:29536/can0") == ("127.0.0.1", 29536, "can0")
    with pytest.raises(ConfigError, match="device.port"):
        parse_socketcand_port("127.0.0.1/can0")
    args = bus_arguments(
        DeviceConfig(canopen=CanopenDeviceConfig(can_interface="socketcand"), port="10.0.0.2:29536/vcan1"), 500000
    )
    assert args == {
        "interface": "socketcand",
        "bitrate": 500000,
        "channel": "vcan1",
        "host": "10.0.0.2",
        "port": 29536,
        "tcp_tune": True,
    }
    args = bus_arguments(
        DeviceConfig(canopen=CanopenDeviceConfig(can_interface="pcan"), port="PCAN_USBBUS1", baudrate=250000), 1000000
    )
    assert args == {"interface": "pcan", "bitrate": 250000, "channel": "PCAN_USBBUS1"}
    with pytest.raises(DeviceError, match="no-such-interface"):
        CanopenDriveAdapter.open_device(
            DeviceConfig(
                driver="canopen-servo", port="x", canopen=CanopenDeviceConfig(can_interface="no-such-interface")
            ),
            find_driver("canopen-servo"),
        )


@pytest.mark.parametrize(
    "stale",
    [b"\x60\x40\x60\x00\x00\x00\x00\x00", b"\x05\x11\x22\x33\x44\x55\x66\x77"],
    ids=["late download answer", "late block upload segment"],
)
def test_a_stale_answer_in_the_queue_is_drained_and_the_request_asked_again(rig, stale):
    # a late download answer, or a late segment of an aborted block upload, arrives just after canopen
    # cleared its queue: read as the answer to the next request, it used to fail that request and leave
    # the channel one answer behind for every request after it
    r = rig("buffered")
    sdo = r.adapter.sdo
    max_torque = ObjectAddress(0x6072, 0)
    expected = sdo.read_object(max_torque)
    client = r.adapter.node.sdo
    real_send = client.send_request
    sent = []

    def send_after_a_stale_frame(request):
        sent.append(bytes(request))
        if len(sent) == 1:
            client.responses.put(stale)
        real_send(request)

    client.send_request = send_after_a_stale_frame
    assert sdo.read_object(max_torque) == expected
    assert len(sent) == 2  # asked once more, after the drain
    sdo.write_object(max_torque, expected - 1)
    assert sdo.read_object(max_torque) == expected - 1  # still in step
    assert client.responses.empty()
