"""Two drives of one session on one CANopen bus, through hilident's own adapters
(:mod:`hilident.adapters.canopen.group`): one bus opened once, each node checked and brought to a known state as
a session of one node is, both enabled, both switched off together, the bus released once by the group and not by
a node."""

from __future__ import annotations

import re
import time
from dataclasses import replace

import can
import numpy as np
import pytest

from hilident.adapters.canopen.group import NodeGroup
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.factory import start_emulator
from hilident.errors import DeviceError, LimitTrip
from hilident.ident.mimo import zippered_multisine

pytestmark = pytest.mark.twin

CONFIG = """
[device]
driver = "canopen-servo"
[device.canopen]
node_ids = [1, 2]
[emulator]
preset = "clean"
[emulator.mechanism]
masses_kg = [20.0, 16.0, 10.0]
links = [[0, 2, 2.0e5, 150.0], [1, 2, 1.5e5, 120.0], [0, 1, 5.0e4, 30.0]]
motors = [[0, 10.0], [1, 10.0]]
sensors = [2, 2]
"""


@pytest.fixture
def twin():
    cfg = parse_config(CONFIG, "two.toml")
    driver = find_driver(cfg.device.driver)
    emulated = start_emulator(cfg.emulator, driver, cfg.device)
    try:
        yield emulated, driver
    finally:
        emulated.close()


def test_both_nodes_open_on_one_bus_enable_and_stop_together(twin):
    emulated, driver = twin
    group = NodeGroup.open(emulated.device, driver)
    try:
        assert group.node_ids == [1, 2]
        assert all(a.network is group.network and not a.owns_network for a in group.adapters)
        assert all(a.connect_report.device_net.startswith("heartbeat consumer") for a in group.adapters)
        assert group.states() == {1: "Switch On Disabled", 2: "Switch On Disabled"}  # the known state at connect
        # one host on the bus, one heartbeat: both nodes' consumers watch the same frames, not two producers'
        host = group.adapters[0].desc.host_node_id
        beats: list[float] = []
        with can.Bus(interface=emulated.device.canopen.can_interface, channel=emulated.device.port) as listener:
            end = time.monotonic() + 1.2
            while time.monotonic() < end:
                msg = listener.recv(0.05)
                if msg is not None and msg.arbitration_id == 0x700 + host:
                    beats.append(msg.timestamp)
        gaps = np.diff(beats)
        period = round(emulated.device.host_timeout_s * 1000) / 3000  # a third of the consumer's time
        assert len(beats) >= 3 and np.all(np.abs(gaps - period) < 0.3 * period), gaps
        group.set_limits(19.0, 0.4, -0.6, 0.6)
        names = group.configure(1000.0, "torque")
        assert {"torque_nm_node1", "position_m_node1", "torque_nm_node2", "position_m_node2"} <= set(names)
        assert len(group.channel_units) == len(names)
        group.enable()
        assert group.states() == {1: "Operation Enabled", 2: "Operation Enabled"}
        assert all(d.enabled for d in emulated.drives)
        group.safe_stop()
        assert group.last_stop_s is not None and group.last_stop_s < 0.1
        assert group.states() == {1: "Switch On Disabled", 2: "Switch On Disabled"}
        deadline = time.monotonic() + 1.0
        while any(d.enabled for d in emulated.drives) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not any(d.enabled for d in emulated.drives)
    finally:
        group.close()
    assert group.network.bus is None  # released once, by the group
    assert all(d.enabled is False for d in emulated.drives)


def test_a_node_that_is_not_on_the_bus_closes_the_ones_opened_and_names_itself(twin):
    emulated, driver = twin
    device = emulated.device
    absent = replace(device, canopen=replace(device.canopen, node_ids=[1, 2, 3]))
    with pytest.raises(DeviceError, match="node 3"):
        NodeGroup.open(absent, driver)
    # node 1 and 2 were left switched off with their consumers disarmed: a new group opens them again
    group = NodeGroup.open(emulated.device, driver)
    try:
        assert group.states() == {1: "Switch On Disabled", 2: "Switch On Disabled"}
    finally:
        group.close()


def _zipper(seconds: float, rms: float = 1.0) -> np.ndarray:
    one, _ = zippered_multisine(2, 1000, 1000.0, (2.0, 100.0), rms=rms, seed=3)
    return np.tile(one, (int(seconds), 1))


@pytest.mark.parametrize("source", ["host", "drive"])
def test_one_run_plays_each_node_its_column_on_one_sync_and_delivers_joint_rows(twin, source):
    emulated, driver = twin
    device = replace(emulated.device, canopen=replace(emulated.device.canopen, sync_source=source))
    group = NodeGroup.open(device, driver)
    try:
        group.set_limits(19.0, 0.4, -0.6, 0.6)
        names = group.configure(1000.0, "torque")
        x = _zipper(2.0)
        blocks = []
        result = group.stream(x, lambda index, rows: blocks.append((index, rows)))
        index = np.concatenate([i for i, _ in blocks])
        rows = np.concatenate([r for _, r in blocks])
    finally:
        group.close()
    assert result.completed and result.clock["source"] == source and result.clock["nodes"] == [1, 2]
    assert np.array_equal(index, np.unique(index)) and result.stats.samples == len(index)
    assert len(index) + result.stats.lost_samples == len(x) or result.clock["setpoints_skipped"]
    # the rest skipped or lost, each counted (above): a drive's clock misses next to none; a host's clock, a Python
    # thread keeping 1 ms cycles on a busy two-core machine, skipped 13 % in one CI run
    assert len(index) >= (0.9 if source == "drive" else 0.75) * len(x)
    # the set-point each node reports it applied is its own column's, but where the host was late and the node
    # held the one before (each such set-point counted)
    held = sum(
        int(np.count_nonzero(np.abs(rows[:, names.index(f"excitation_node{node}")] - x[index, column]) > 1e-3))
        for node, column in ((1, 0), (2, 1))
    )
    assert held <= result.stats.setpoints_skipped + 4, (held, result.stats)
    assert not any(d.enabled for d in emulated.drives)


def test_a_fault_on_one_node_switches_every_node_off_and_names_it(twin):
    emulated, driver = twin
    group = NodeGroup.open(emulated.device, driver)
    try:
        group.set_limits(19.0, 0.4, -0.6, 0.6)
        group.configure(1000.0, "torque")
        x = _zipper(4.0)
        x[:, 1] += np.linspace(0.0, 60.0, len(x))  # node 2 pushes the gantry along until a speed limit trips
        delivered: list[np.ndarray] = []
        with pytest.raises(LimitTrip, match=r"node [12]: velocity_limit") as caught:
            group.stream(x, lambda index, rows: delivered.append(index))
        assert group.last_result is not None and not group.last_result.completed
        assert group.last_result.stats.samples < len(x)
        assert not any(d.enabled for d in emulated.drives), str(caught.value)
        # the node whose limit tripped first, and where, named in the error; both nodes read the one gantry's
        # speed, so the other may trip at the same sample, and the error then adds it ("(then: ...)")
        text = str(caught.value)
        tripped = text.split(" node ", 1)[1][0]
        at = int(re.search(r"at sample (\d+)", text).group(1))
        assert delivered and np.concatenate(delivered).max() <= at  # nothing after the fault
        assert any(e["message"].startswith(f"node {tripped}: ") for e in group.events)
    finally:
        group.close()
