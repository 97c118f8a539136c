"""Two CiA 402 drives of one axis on one CANopen bus: the twin of two nodes driving one gantry, seen by a bare host.

The host is python ``canopen`` on the twin's virtual channel: it finds both nodes, configures their PDOs,
enables both in cyclic synchronous torque mode, sends one SYNC per cycle and each node's set-point by RPDO, and
records their TPDOs. The physics is checked through the protocol: every position both nodes report equals, to
the encoder count, a single-threaded :class:`~hilident.emulator.coupled_plant.CoupledPlant` fed the torques they
report, so a torque on one node moves the other's carriage as the coupled model says, and both nodes' cycles of
one SYNC are the same ticks of the mechanism.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

import canopen
from hilident.adapters.canopen.link import bus_arguments
from hilident.config.tables import parse_config
from hilident.drivers.description import find_driver
from hilident.emulator.canopen.server import CanopenBusServer, start, start_socketcand
from hilident.emulator.coupled_plant import CoupledPlant, PlantPort
from hilident.emulator.device import mechanism_model
from hilident.emulator.factory import host_device_table, start_emulator
from hilident.errors import ConfigError
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import consumer_entry, mapping_entry
from hilident.protocol.canopen_types import ObjectAddress
from support.canopen_cycles import CycleClock, map_pdo

NODES = (1, 2)
T = 1e-3  # SYNC period, s
RATE = 4000.0  # the drive's loop rate (canopen-servo), Hz
TICKS = round(T * RATE)  # loop ticks per cycle
POSITION_UNIT = 1e-7  # m per increment of 0x6064 (and the encoder's count)
VELOCITY_UNIT = 1e-6  # m/s per unit of 0x606C
HOST = 127  # the host's node id (its heartbeat 0x77F)
#: Two carriages of unequal mass on one beam, a load between them, the beam's own stiffness between its ends.
MECHANISM = """
[emulator.mechanism]
masses_kg = [20.0, 16.0, 10.0]                                          # left carriage, right carriage, load
links = [[0, 2, 2.0e5, 150.0], [1, 2, 1.5e5, 120.0], [0, 1, 5.0e4, 30.0]]
motors = [[0, 10.0], [1, 10.0]]                                         # node 1 left, node 2 right
sensors = [2, 2]
"""
CONFIG = (
    """
[device]
driver = "canopen-servo"

[device.canopen]
node_ids = [1, 2]

[emulator]
preset = "clean"                 # exact physics: no process disturbance, ideal current loop, no delay
seed = 5

[emulator.sensors]
encoder_resolution_m = 1e-7
torque_noise_nm = 0.0
"""
    + MECHANISM
)


class Host:
    """A bare CANopen master on the twins' bus: SDO to each node, PDOs, one SYNC per cycle."""

    def __init__(self, emulated, driver):
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05
        self.network.connect(**bus_arguments(emulated.device, driver.default_baudrate))
        eds = str(driver.folder / driver.sections["canopen"]["eds"])
        self.nodes = {n: self.network.add_node(n, eds) for n in NODES}
        self.heartbeats: dict[int, list[int]] = {n: [] for n in NODES}
        self.tpdos: dict[int, list[tuple[int, int, int]]] = {n: [] for n in NODES}  # (counter, position, torque)
        self.velocities: dict[int, list[tuple[int, int]]] = {n: [] for n in NODES}  # (counter, velocity)
        self.setpoints = {n: 0 for n in NODES}  # target torque of the next cycles, per mille of the rated torque
        self.clock: CycleClock | None = None
        self.syncs: int | None = None  # SYNCs node 1 produced (None: the host sends them)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        for n in NODES:
            self.network.subscribe(0x700 + n, self._on_heartbeat)

    def _on_heartbeat(self, can_id, data, timestamp) -> None:
        self.heartbeats[can_id - 0x700].append(data[0])

    def write(self, node: int, index: int, sub: int, value: int) -> None:
        obj = self.nodes[node].sdo[index]
        (obj[sub] if isinstance(obj, canopen.sdo.SdoRecord | canopen.sdo.SdoArray) else obj).raw = value

    def read(self, node: int, index: int, sub: int = 0):
        obj = self.nodes[node].sdo[index]
        return (obj[sub] if isinstance(obj, canopen.sdo.SdoRecord | canopen.sdo.SdoArray) else obj).raw

    def state(self, node: int) -> cia402.State:
        return cia402.decode_statusword(self.read(node, 0x6041))

    def configure(self) -> None:
        """Per node: TPDO1 sample counter, position actual and torque actual; TPDO2 sample counter and velocity
        actual; RPDO1 set-point counter and target torque; the SYNC period; the limits; torque mode."""
        counter = mapping_entry(ObjectAddress(0x2100), 16)
        for n in NODES:

            def write(index, sub, value, n=n):
                self.write(n, index, sub, value)

            tpdo1 = [counter, mapping_entry(ObjectAddress(0x6064), 32), mapping_entry(ObjectAddress(0x6077), 16)]
            map_pdo(write, 0x1800, 0x1A00, 0x180 + n, tpdo1)
            map_pdo(write, 0x1801, 0x1A01, 0x280 + n, [counter, mapping_entry(ObjectAddress(0x606C), 32)])
            rpdo = [mapping_entry(ObjectAddress(0x2101), 16), mapping_entry(ObjectAddress(0x6071), 16)]
            map_pdo(write, 0x1400, 0x1600, 0x200 + n, rpdo)
            write(0x1006, 0, int(T * 1e6))
            write(0x6072, 0, 19_000)  # torque limit, per mille of the rated 1 N*m
            write(0x6080, 0, 400_000)  # velocity limit, 0.4 m/s
            write(0x607D, 1, -6_000_000)  # position window, +-0.6 m
            write(0x607D, 2, 6_000_000)
            write(0x6060, 0, 10)  # cyclic synchronous torque
            self.network.subscribe(0x180 + n, self._tpdo1)
            self.network.subscribe(0x280 + n, self._tpdo2)

    def _tpdo1(self, can_id, data, timestamp) -> None:
        self.tpdos[can_id - 0x180].append(struct.unpack("<Hih", bytes(data)))

    def _tpdo2(self, can_id, data, timestamp) -> None:
        self.velocities[can_id - 0x280].append(struct.unpack("<Hi", bytes(data)))

    def enable(self, node: int) -> None:
        for cw in cia402.path_to_operation_enabled(self.state(node)):
            self.write(node, 0x6040, 0, cw)
        assert self.state(node) is cia402.State.OPERATION_ENABLED

    def send_setpoints(self, j: int) -> None:
        """Each node's set-point for cycle ``j`` (RPDO, the cycle its counter: both nodes' runs start at the first
        SYNC)."""
        for n in NODES:
            self.network.send_message(0x200 + n, struct.pack("<Hh", j & 0xFFFF, self.setpoints[n]))

    def start_cycles(self, source: str = "host") -> None:
        """SYNC from ``source``: ``"host"``, a thread that sends at each cycle's instant the set-points and the
        SYNC; ``"drive"``, node 1's SYNC production (0x1005 bit 30), the set-points of the next cycle sent when
        a SYNC is heard."""
        if source == "drive":
            self.syncs = 0

            def on_sync(can_id, data, timestamp):
                self.syncs += 1
                self.send_setpoints(self.syncs)

            self.send_setpoints(0)
            self.network.subscribe(0x80, on_sync)
            self.write(1, 0x1005, 0, 0x40000080)
            return
        clock = self.clock = CycleClock(T)
        self._stop.clear()

        def send(j: int) -> None:
            self.send_setpoints(j)
            self.network.send_message(0x80, b"")

        def cycles():
            j = 0
            while not self._stop.is_set():
                clock.at([j], send)
                j += 1

        self._thread = threading.Thread(target=cycles, name="host-sync", daemon=True)
        self._thread.start()

    def cycle(self) -> int:
        """The last cycle sent (-1: none yet)."""
        if self.syncs is not None:
            return self.syncs - 1
        return self.clock.sent[-1] if self.clock is not None and self.clock.sent else -1

    def wait_cycles(self, count: int) -> None:
        """Until ``count`` more cycles have been sent."""
        first = self.cycle()
        assert _wait_for(lambda: self.cycle() >= first + count, 10.0)

    def stop_cycles(self) -> None:
        if self.syncs is not None and 0x80 in self.network.subscribers:
            self.write(1, 0x1005, 0, 0x80)
            time.sleep(0.01)  # a SYNC the drive sent as it was told to stop
            self.network.unsubscribe(0x80)
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def close(self) -> None:
        self.stop_cycles()
        self.network.disconnect()


def _settle(host: Host) -> None:
    """Until every TPDO of the cycles sent is in: none came for 50 ms."""
    count = -1
    deadline = time.monotonic() + 2.0
    while count != (count := sum(map(len, host.tpdos.values()))) and time.monotonic() < deadline:
        time.sleep(0.05)


def _wait_for(condition, timeout_s: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.002)
    return condition()


@pytest.fixture
def bus():
    """The twin of two nodes started from its config, and a host on its bus."""
    cfg = parse_config(CONFIG)
    driver = find_driver(cfg.device.driver)
    emulated = start_emulator(cfg.emulator, driver, cfg.device)
    host = Host(emulated, driver)
    try:
        yield host, emulated
    finally:
        host.close()
        emulated.close()


def _applied(host: Host, node: int, scale: float, cycles: int) -> np.ndarray:
    """The torque (N*m) node ``node`` applied in each of the first ``cycles`` cycles of its run: what its TPDO
    reports, held through a cycle that ran without a SYNC (no TPDO)."""
    reported = {k: torque for k, _, torque in host.tpdos[node]}
    out, held = np.zeros(cycles), 0
    for k in range(cycles):
        held = reported.get(k, held)
        out[k] = held * scale
    return out


def _reference(model, torques: np.ndarray, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Encoder counts of each port's motor mass, and each drive's velocity estimate (m/s), at the start of every
    cycle: one thread steps the mechanism from rest with ``torques`` (cycles x ports, N*m held over a cycle), and
    runs the drives' velocity estimate (a backward difference through a first-order low-pass at 500 Hz) on the
    encoders."""
    plant = CoupledPlant(model)
    motors = list(model.motor_masses)
    counts = np.zeros((cycles, len(motors)), dtype=np.int64)
    velocity = np.zeros((cycles, len(motors)))
    alpha = -math.expm1(-2.0 * math.pi * 500.0 / RATE)
    last, vf = np.zeros(len(motors)), np.zeros(len(motors))
    for k in range(cycles):
        for t in range(TICKS):
            pm = np.floor(plant.positions[motors] / POSITION_UNIT)
            vf += alpha * ((pm - last) * POSITION_UNIT * RATE - vf)
            last = pm
            if t == 0:
                counts[k], velocity[k] = pm, vf
            plant.step(torques[k], 1.0 / RATE)
    return counts, velocity


def _counts(host: Host, node: int) -> dict[int, int]:
    return {k: position for k, position, _ in host.tpdos[node]}


# --- the configuration -----------------------------------------------------------------------------------------


TWO = "[device.canopen]\nnode_ids = [1, 2]\n"
#: (what is wrong, config, the key its error names)
BAD_CONFIGS = [
    ("nodes-without-mechanism", TWO, "emulator.mechanism"),
    ("duplicate-id", "[device.canopen]\nnode_ids = [1, 2, 1]\n" + MECHANISM, "device.canopen.node_ids"),
    ("node-id-not-first", "[device.canopen]\nnode_id = 3\nnode_ids = [1, 3]\n" + MECHANISM, "device.canopen.node_ids"),
    ("id-out-of-range", "[device.canopen]\nnode_ids = [1, 200]\n" + MECHANISM, "device.canopen.node_ids[1]"),
    ("nine-nodes", "[device.canopen]\nnode_ids = [1, 2, 3, 4, 5, 6, 7, 8, 9]\n", "device.canopen.node_ids"),
    ("three-nodes-two-motors", "[device.canopen]\nnode_ids = [1, 2, 3]\n" + MECHANISM, "emulator.mechanism.motors"),
    ("one-node-two-motors", MECHANISM, "emulator.mechanism.motors"),
    ("link-to-no-mass", TWO + MECHANISM.replace("[1, 2, 1.5e5", "[1, 5, 1.5e5"), "emulator.mechanism.links[1].j"),
    ("link-too-short", TWO + MECHANISM.replace("[0, 1, 5.0e4, 30.0]", "[0, 1, 5.0e4]"), "emulator.mechanism.links[2]"),
    ("motor-c-zero", TWO + MECHANISM.replace("[1, 10.0]]", "[1, 0.0]]"), "emulator.mechanism.motors[1].c"),
    ("sensor-of-no-mass", TWO + MECHANISM.replace("[2, 2]", "[2, 3]"), "emulator.mechanism.sensors[1]"),
    ("no-masses", "[emulator.mechanism]\nmotors = [[0, 10.0]]\nsensors = [0]\n", "emulator.mechanism.masses_kg"),
]


@pytest.mark.parametrize(("toml", "key"), [b[1:] for b in BAD_CONFIGS], ids=[b[0] for b in BAD_CONFIGS])
def test_a_config_error_names_its_key(toml, key):
    with pytest.raises(ConfigError) as err:
        parse_config(toml)
    assert err.value.key == key, err.value


def test_nodes_on_a_real_bus_need_no_mechanism_and_the_mechanism_checks_name_their_key():
    cfg = parse_config('[device]\nport = "can0"\n[device.canopen]\nnode_ids = [1, 2]\n')
    assert cfg.device.canopen.node_ids == [1, 2] and not cfg.emulator.mechanism.defined
    emu = parse_config(CONFIG).emulator
    bad = replace(emu, mechanism=replace(emu.mechanism, masses_kg=[20.0, -1.0, 10.0]))
    with pytest.raises(ConfigError) as err:
        mechanism_model(bad)  # the model's own check, under the config's key
    assert err.value.key == "emulator.mechanism.masses_kg[1]"
    with pytest.raises(ConfigError) as err:
        start_emulator(emu, find_driver("dsy-rs"), parse_config(CONFIG).device)
    assert err.value.key == "emulator.mechanism"


# --- on the bus -----------------------------------------------------------------------------------------------


def test_both_nodes_answer_on_one_bus_and_idle_in_lockstep(bus):
    host, emulated = bus
    assert isinstance(emulated.server, CanopenBusServer) and len(emulated.drives) == 2
    assert emulated.drive is emulated.drives[0] and emulated.mechanism is not None
    driver = find_driver("canopen-servo")
    for n in NODES:
        assert host.read(n, 0x1018, 1) == driver.sections["canopen"]["vendor_id"]
        assert host.read(n, 0x1018, 2) == driver.sections["canopen"]["product_code"]
        host.write(n, 0x1017, 0, 20)
    assert _wait_for(lambda: all(len(host.heartbeats[n]) >= 3 for n in NODES))
    assert {host.heartbeats[n][-1] for n in NODES} == {0x7F}  # both pre-operational
    plant = emulated.mechanism
    ticks = plant.ticks
    time.sleep(0.1)
    assert plant.ticks - ticks > 0.05 * RATE  # both disabled, the mechanism steps on at the loop rate
    assert plant.held_steps == [0, 0]
    assert all(isinstance(d.plant, PlantPort) and d.plant.attached for d in emulated.drives)
    assert host_device_table(emulated.device)["canopen"]["node_ids"] == [1, 2]


@pytest.mark.parametrize("source", ["host", "drive"])
def test_a_torque_on_each_node_moves_both_carriages_as_the_coupled_model_says(bus, source):
    host, emulated = bus
    host.configure()
    host.network.nmt.state = "OPERATIONAL"
    for n in NODES:
        host.enable(n)  # both before the first SYNC: their runs start at it
    plant = emulated.mechanism
    host.start_cycles(source)
    host.wait_cycles(100)
    host.setpoints[1] = 500  # 0.5 N*m on the left carriage alone
    host.wait_cycles(250)
    host.setpoints[2] = -300  # and -0.3 N*m on the right one
    host.wait_cycles(250)
    held = list(plant.held_steps)
    host.stop_cycles()
    last = host.cycle()
    _settle(host)
    assert held == [0, 0]  # every tick of the run waited for both nodes: the lockstep kept its order
    fws = emulated.server.firmwares
    scale = fws[0].scales["target_torque"]
    cycles = last + 1
    torques = np.column_stack([_applied(host, n, scale, cycles) for n in NODES])
    assert torques[-1].tolist() == [0.5, -0.3]
    counts, velocity = _reference(mechanism_model(parse_config(CONFIG).emulator), torques, cycles)
    for i, n in enumerate(NODES):
        got = _counts(host, n)
        assert min(got) == 0  # each node's sample counter starts at 0 on the run's first SYNC
        assert len(got) >= 0.5 * cycles  # (the cycles a loaded machine sent late were skipped: no TPDOs)
        off = [(k, got[k] - counts[k, i]) for k in sorted(got) if abs(got[k] - counts[k, i]) > 1]
        assert off == [], (n, off[:8], len(off))  # to the encoder count, every cycle of both nodes
        speeds = dict(host.velocities[n])
        err = [abs(speeds[k] * VELOCITY_UNIT - velocity[k, i]) for k in speeds]
        assert max(err) < 5e-4, n
    on = [int(np.argmax(torques[:, i] != 0)) for i in range(2)]
    assert 0 < on[0] < on[1]
    assert counts[on[0], 1] == 0 and counts[on[1], 1] > 1000  # node 1's torque alone moved node 2's carriage
    assert all(fw.pdo.sync_errors == 0 for fw in fws)


def test_a_node_enabled_later_joins_the_moving_mechanism_in_step(bus):
    host, emulated = bus
    host.configure()
    host.network.nmt.state = "OPERATIONAL"
    host.enable(1)
    plant = emulated.mechanism
    host.start_cycles()
    host.wait_cycles(20)
    host.setpoints[1] = 800
    host.wait_cycles(200)
    # node 2, disabled, has read its encoder all along: its velocity estimate is the right carriage's
    speed = host.read(2, 0x606C) * VELOCITY_UNIT
    assert speed == pytest.approx(plant.velocities[1], abs=3e-3) and speed > 0.01
    host.enable(2)  # a few cycles later than node 1: its run starts at the next SYNC
    host.wait_cycles(200)
    host.stop_cycles()
    last = host.cycle()
    _settle(host)
    assert plant.held_steps == [0, 0]
    scale = emulated.server.firmwares[0].scales["target_torque"]
    torques = np.column_stack([_applied(host, 1, scale, last + 1), np.zeros(last + 1)])
    counts, velocity = _reference(mechanism_model(parse_config(CONFIG).emulator), torques, last + 1)
    assert max(abs(p - counts[k, 0]) for k, p in _counts(host, 1).items()) <= 1
    got = _counts(host, 2)
    assert min(got) == 0
    # node 2's cycle k is node 1's cycle k + offset: whole cycles of the same mechanism, to the count
    fits = {
        offset: max(abs(p - counts[k + offset, 1]) for k, p in got.items()) for offset in range(1, last + 1 - max(got))
    }
    offset = min(fits, key=fits.__getitem__)
    assert fits[offset] <= 1, sorted(fits.items(), key=lambda kv: kv[1])[:3]  # (offset, worst count) that fit best
    first = dict(host.velocities[2])[0] * VELOCITY_UNIT  # no jump when its run starts
    assert first == pytest.approx(velocity[offset, 1], abs=5e-4) and first > 0.01


def test_both_nodes_switch_off_when_the_host_stops_and_when_the_server_closes(bus):
    host, emulated = bus
    host.configure()
    for n in NODES:
        host.write(n, 0x1016, 1, consumer_entry(HOST, 150))  # watch the host's heartbeat
        host.write(n, 0x6007, 0, 2)  # when it stops: disable voltage (Switch On Disabled)
    host.network.nmt.state = "OPERATIONAL"
    beat = host.network.send_periodic(0x700 + HOST, [0x05], 0.02)
    for n in NODES:
        host.enable(n)
    host.setpoints = {1: 300, 2: 300}
    host.start_cycles()
    host.wait_cycles(100)
    assert all(d.enabled for d in emulated.drives)
    beat.stop()  # the host is gone: no heartbeat (its SYNC goes on, as an interface's own SYNC would)
    assert _wait_for(lambda: not any(d.enabled for d in emulated.drives), 1.0)
    for n in NODES:
        assert host.state(n) is cia402.State.SWITCH_ON_DISABLED
        assert _wait_for(lambda n=n: host.read(n, 0x6077) == 0, 0.5)  # no torque from the next tick on
    beat = host.network.send_periodic(0x700 + HOST, [0x05], 0.02)  # the host is back: both on again
    time.sleep(0.05)
    for n in NODES:
        host.enable(n)
    host.wait_cycles(50)
    held = list(emulated.mechanism.held_steps)
    emulated.close()  # SYNC still coming
    beat.stop()
    fws = emulated.server.firmwares
    assert all(fw.state is cia402.State.SWITCH_ON_DISABLED for fw in fws)
    assert not any(d.enabled for d in emulated.drives)
    assert not any(isinstance(d.plant, PlantPort) and d.plant.attached for d in emulated.drives)
    assert emulated.mechanism.held_steps == held  # closing waits for no node


@pytest.mark.parametrize("serve", [start, start_socketcand], ids=["virtual", "socketcand"])
def test_every_node_answers_on_the_one_channel_the_twin_serves(serve):
    cfg = parse_config(CONFIG)
    driver = find_driver("canopen-servo")
    emulated = serve(cfg.emulator, driver, cfg.device)
    host = Host(emulated, driver)
    try:
        assert emulated.device.canopen.node_ids == [1, 2]
        assert [fw.node_id for fw in emulated.server.firmwares] == [1, 2]
        assert len({s.channel for s in emulated.server.servers}) == 1
        assert [host.read(n, 0x1018, 1) for n in NODES] == [driver.sections["canopen"]["vendor_id"]] * 2
    finally:
        host.close()
        emulated.close()
