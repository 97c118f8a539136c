"""What the emulated CANopen drive's objects mean: sampled signals, set-points, limits, emergency codes.

Pure tables shared by the firmware's parts (and the recorder): which drive
loop column an object role samples, which roles are set-points and limits, and
the EMCY codes (CiA 301/402) the drive sends.
"""

from __future__ import annotations

__all__ = [
    "COLUMN_OF_ROLE",
    "EMCY_DRIVE_FAULT",
    "EMCY_FOLLOWING_ERROR",
    "EMCY_HEARTBEAT",
    "EMCY_INTERNAL",
    "EMCY_OF_TRIP",
    "EMCY_SYNC_ERROR",
    "EMCY_SYNC_TIMEOUT",
    "LIMIT_ROLES",
    "TARGET_ROLES",
    "error_register",
]

EMCY_OF_TRIP = {"torque_limit": 0x8311, "velocity_limit": 0x8400, "position_limit": 0x8612}
EMCY_DRIVE_FAULT = 0x4310  # excess temperature, drive (the injected fault)
EMCY_SYNC_TIMEOUT = 0x8250  # no SYNC for the driver's loss_timeout_ms in a SYNC-driven run
EMCY_SYNC_ERROR = 0x8700  # sync controller (CiA 402): too many SYNCs off the drive's clock
EMCY_FOLLOWING_ERROR = 0x8611  # position demand and actual apart beyond 0x6065 for longer than 0x6066
EMCY_INTERNAL = 0x6100  # internal software error
EMCY_HEARTBEAT = 0x8130  # life guard or heartbeat error (the host's heartbeat stopped)

#: Sampled objects: the drive loop column (``DriveLoop.CHANNELS``) each role reads.
COLUMN_OF_ROLE = {
    "position_actual": "position_m",
    "velocity_actual": "velocity_mps",
    "torque_actual": "torque_nm",
    "current_actual": "torque_nm",
    "torque_demand": "torque_cmd_nm",
    "applied_excitation": "excitation",
    "load_position": "load_position_m",
}
TARGET_ROLES = ("target_torque", "torque_offset", "target_velocity", "target_position", "interpolation_data")
LIMIT_ROLES = ("max_torque", "max_velocity", "position_limit_min", "position_limit_max")


def error_register(code: int) -> int:
    """The error register (0x1001) bits that go with emergency ``code`` (CiA 301: generic, current, voltage,
    temperature, communication)."""
    bits = 0x01
    bits |= {0x2: 0x02, 0x3: 0x04, 0x4: 0x08}.get(code >> 12, 0)
    if code & 0xFF00 in (0x8100, 0x8200):
        bits |= 0x10
    return bits
