"""What the emulated CANopen drive's parts ask of the firmware that composes them.

:class:`~hilident.emulator.canopen.firmware.CanopenDriveFirmware` is built of
parts (:mod:`.guarding`, :mod:`.parameters`, :mod:`.pdo`, :mod:`.playback`,
:mod:`.recorder`), each given the firmware when it is made. A part reaches
its drive through :class:`FirmwareHost`: the firmware's state and the few
calls the parts share, declared once, so a type checker sees every use and
the parts never import the firmware module (which imports them).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Protocol

import numpy as np

import canopen
from hilident.config.tables import FaultsConfig
from hilident.drivers.description import DriverDescription
from hilident.emulator.canopen.setpoints import SetPoints
from hilident.emulator.clock import SimClock
from hilident.emulator.drive import DriveLoop
from hilident.protocol import cia402
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_types import ObjectAddress
from hilident.protocol.filter_encoding import FilterEncoding

__all__ = ["FirmwareHost", "FrameHandler"]

#: A bus subscriber: ``handler(can_id, data, timestamp)``.
FrameHandler = Callable[[int, bytearray, float], None]


class _Playing(Protocol):
    @property
    def playing(self) -> bool: ...


class FirmwareHost(Protocol):
    """The firmware as its parts see it (see the module docstring).

    Attributes
    ----------
    drive, driver, desc
        The physics, the driver description, the CANopen description built from it.
    od, node, node_id, network
        The object dictionary, the local node on it, its node id, the bus (None before it is attached).
    lock
        Held while the bus handlers and the clock touch the drive.
    faults
        The fault switches.
    loop_rate, time_scale
        Drive loop rate (Hz) and simulated seconds per wall second.
    scales, columns, role_of, encoding
        SI per raw unit of each role; column of each drive channel; role of each object; filter encoding.
    rated_torque_nm, rated_current_a
        What the torque and current objects are scaled by.
    setpoints, playback, clock
        The set-points part, the table playback (only whether it plays), the simulated clock.
    state, sample_index, last_row
        CiA 402 state; sample index of the run; the drive's latest output row.
    """

    drive: DriveLoop
    driver: DriverDescription
    desc: CanopenDescription
    od: canopen.ObjectDictionary
    node: canopen.LocalNode
    node_id: int
    network: canopen.Network | None
    lock: threading.RLock
    faults: FaultsConfig
    loop_rate: float
    time_scale: float
    scales: dict[str, float]
    columns: dict[str, int]
    role_of: dict[ObjectAddress, str]
    encoding: FilterEncoding | None
    rated_torque_nm: float
    rated_current_a: float
    setpoints: SetPoints
    clock: SimClock
    state: cia402.State
    sample_index: int
    last_row: np.ndarray

    @property
    def playback(self) -> _Playing: ...

    def stored(self, index: int, sub: int): ...

    def default(self, addr: ObjectAddress): ...

    def send(self, cob_id: int, payload: bytes) -> None: ...

    def send_stamped(self, cob_id: int, payload: bytes, stamp: float) -> None: ...

    def guarded(self, callback: FrameHandler) -> FrameHandler: ...

    def live(self, role: str | None, addr: ObjectAddress, row: np.ndarray, k: int): ...

    def receive_setpoint(self, role: str | None, value: int) -> None: ...

    def divider(self) -> int: ...

    def start_run(self) -> None: ...

    def power_off(self) -> None: ...

    def fault(self, code: int, sample_index: int) -> None: ...

    def check_faults(self) -> None: ...

    def pending_fault_times(self) -> list[float]: ...

    def abort_connection(self) -> None: ...
