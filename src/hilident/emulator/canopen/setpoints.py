"""Set-points and modes of operation of the emulated CANopen drive (CiA 402).

The host selects a mode of operation (0x6060) and sends the set-point of that
mode (target torque, velocity or position, interpolation data, a torque
offset) by SDO or RPDO; :meth:`SetPoints.drive_input` turns them into the
drive loop's input, in SI units.

A drive that produces SYNC latches, at each SYNC, the newest set-point
received before it: RPDO set-points then wait, stamped with their bus time,
until :meth:`SetPoints.latch` takes those older than the SYNC. In
interpolated position mode with its buffer set up (0x60C4,
:class:`~hilident.emulator.canopen.ip_buffer.InterpolationBuffer`) the
interpolation data queue up instead, and each SYNC takes the next one.
"""

from __future__ import annotations

from collections import deque

from hilident.emulator.canopen.ip_buffer import InterpolationBuffer
from hilident.emulator.canopen.roles import TARGET_ROLES
from hilident.emulator.drive import DriveLoop
from hilident.protocol.canopen_objects import CanopenDescription
from hilident.protocol.canopen_profile import mode_name_of_code

__all__ = ["SetPoints"]

#: CiA 402 modes of operation and the drive loop mode that runs them (torque offsets are added in each).
_LOOP_MODE_OF_CODE = {10: "torque", 9: "velocity", 8: "position", 7: "position"}
_SETPOINT_OF_CODE = {10: "target_torque", 9: "target_velocity", 8: "target_position"}
_PENDING_MAX = 64  # set-points kept per role until a SYNC latches them (a few cycles' worth)


class SetPoints:
    """The selected mode of operation and the set-points the host sent.

    Parameters
    ----------
    desc : CanopenDescription
    scales : dict
        Role -> SI per object unit.
    supported : tuple of str
        The modes this drive runs.
    mode_code : int
        The mode of operation at power-up (0x6060's default).
    drive : DriveLoop
        Where the torque offset goes and the hold position comes from.
    buffer_size : int
        0x60C4:1, the records the interpolation data buffer can hold (1: no buffer).

    Attributes
    ----------
    targets : dict
        Set-point role -> raw value as last written.
    rx_counter : int
        The set-point counter as last written (a fresh set-point for each sample).
    pending : dict
        Role -> deque of (bus timestamp s, raw value) received and not yet latched (SYNC producer only).
    """

    def __init__(
        self,
        desc: CanopenDescription,
        scales: dict,
        supported: tuple[str, ...],
        mode_code: int,
        drive: DriveLoop,
        buffer_size: int = 1,
    ):
        self.desc = desc
        self.scales = scales
        self.supported = supported
        self.mode_code = mode_code
        self.drive = drive
        self.targets = {role: 0 for role in TARGET_ROLES if desc.has(role)}
        self.rx_counter = 0
        self.new = False  # a set-point came since the drive's last cycle asked
        self.pending: dict[str, deque[tuple[float, int]]] = {}
        self.buffer = InterpolationBuffer(buffer_size)
        self.at_sync: dict[str, int] = {}  # queued roles a synchronous RPDO carried: the newest, pushed at the SYNC

    @property
    def mode_spec(self):
        return self.desc.mode_by_code(self.mode_code)

    def loop_mode(self, code: int | None = None) -> str | None:
        """The drive loop mode of mode of operation ``code`` (the selected one by default; None: not one this
        drive runs)."""
        code = self.mode_code if code is None else code
        if self.desc.explicit_modes:
            spec = self.desc.mode_by_code(code)
            return spec.name if spec is not None else None
        return _LOOP_MODE_OF_CODE.get(code) if mode_name_of_code(code) in self.supported else None

    def queued(self, role: str | None) -> bool:
        """Whether a write of ``role`` goes into the interpolation data buffer (interpolated position mode,
        buffer active), not straight to the drive."""
        return role in ("interpolation_data", "setpoint_counter") and self.mode_code == 7 and self.buffer.active

    def receive_synchronous(self, role: str, value: int) -> None:
        """A queued role (:meth:`queued`) in a synchronous RPDO: CiA 301 passes its data on at the next SYNC, the
        newest received, so the buffer takes at most one record a cycle from it."""
        self.at_sync[role] = value

    def receive(self, role: str | None, value: int) -> bool:
        """A set-point or the set-point counter, written by SDO or RPDO; False when ``role`` is neither."""
        if role == "interpolation_data" and self.queued(role):
            self.buffer.push(self.rx_counter, value)  # with the counter the same RPDO carried before it
        elif role in self.targets:
            self.targets[role] = value
            self.new = True
        elif role == "setpoint_counter":
            self.rx_counter = value
        else:
            return False
        return True

    def take_new(self, fresh: bool = True) -> bool:
        """Whether a set-point came since the last call (a cycle asks once: was there a new one for it).

        With the interpolation data buffer active, a cycle a SYNC started (``fresh``) takes the next record
        from it instead; a cycle the drive's own clock ran without a SYNC takes none.
        """
        if self.queued("interpolation_data"):
            if fresh:
                for role in ("setpoint_counter", "interpolation_data"):  # the RPDO's order: the counter first
                    if role in self.at_sync:
                        self.receive(role, self.at_sync.pop(role))
            record = self.buffer.pop() if fresh else None
            if record is None:
                return False
            self.rx_counter, self.targets["interpolation_data"] = record
            return True
        new, self.new = self.new, False
        return new

    def holds(self, role: str | None) -> bool:
        """Whether ``role`` is a set-point or the set-point counter."""
        return role in self.targets or role == "setpoint_counter"

    def defer(self, role: str, value: int, stamp: float) -> None:
        """A set-point (:meth:`holds` ``role``) received at bus time ``stamp`` (s), applied by :meth:`latch`."""
        self.pending.setdefault(role, deque(maxlen=_PENDING_MAX)).append((stamp, value))

    def latch(self, before: float | None = None) -> None:
        """Apply the deferred set-points stamped before bus time ``before`` (s; None: all), oldest first."""
        for role, entries in self.pending.items():
            while entries and (before is None or entries[0][0] < before):
                self.receive(role, entries.popleft()[1])

    def _si(self, role: str) -> float:
        return self.targets.get(role, 0) * self.scales.get(role, 1.0)

    def drive_input(self) -> float:
        """The drive loop's input for the next ticks; the torque offset (0x60B2) goes to the loop on its own."""
        if self.desc.explicit_modes:
            spec = self.mode_spec
            x = self._si(spec.setpoint)
            if spec.name == "position":
                x -= self.drive.hold_position_m  # CSP targets are absolute; the drive loop takes them relative
            return x
        self.drive.torque_offset_nm = self._si("torque_offset")
        if self.mode_code in (10, 9):
            return self._si(_SETPOINT_OF_CODE[self.mode_code])
        target = "target_position" if self.mode_code == 8 else "interpolation_data"
        return self._si(target) - self.drive.hold_position_m
