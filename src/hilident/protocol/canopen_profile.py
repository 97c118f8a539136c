"""The standard CiA 301 / CiA 402 objects a drive has, found by their index, and what hilident does with them.

A vendor drive is its EDS plus a short ``driver.toml``: the host finds the
standard objects (controlword 0x6040, position actual 0x6064, ...) by their
standard index in the EDS and uses only those present. A missing object is an
absent capability, not an error, until an experiment needs it. From what is
present this module derives

* the roles the host and the emulated drive address (:func:`standard_objects`),
* which CiA 402 mode of operation and which set-point object serve each
  hilident mode (:func:`standard_modes`), from the modes the drive supports
  (0x6502, :func:`decode_supported_modes`) and the driver's preference,
* which object carries each recorded channel (:func:`standard_channels`),
* the interpolation time period 0x60C2 of a sample period (:func:`period_fields`).

All pure: dicts and numbers in, dicts and numbers out.

Examples
--------
>>> decode_supported_modes(0x3EF)
('pp', 'vl', 'pv', 'tq', 'hm', 'ip', 'csp', 'csv', 'cst')
>>> period_fields(0.001), period_fields(0.008), period_fields(0.00025)
((1, -3), (8, -3), (25, -5))
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

from hilident.protocol.canopen_types import ModeSpec, ObjectAddress

__all__ = [
    "STANDARD_OBJECTS",
    "MODE_CODES",
    "MODE_BITS",
    "CYCLIC_MODES",
    "SETPOINT_OF_MODE",
    "CHANNEL_UNITS",
    "decode_supported_modes",
    "encode_supported_modes",
    "mapping_capacity",
    "standard_objects",
    "standard_modes",
    "standard_channels",
    "period_fields",
    "period_from_fields",
    "mode_name_of_code",
]

#: Standard objects by role (CiA 301 communication profile, CiA 402 drive profile).
STANDARD_OBJECTS: dict[str, ObjectAddress] = {
    "error_register": ObjectAddress(0x1001),
    "error_history": ObjectAddress(0x1003),
    "sync_cob_id": ObjectAddress(0x1005),  # COB-ID SYNC; bit 30: this node produces SYNC
    "cycle_period": ObjectAddress(0x1006),  # communication cycle period, us
    "device_name": ObjectAddress(0x1008),
    "hardware_version": ObjectAddress(0x1009),
    "software_version": ObjectAddress(0x100A),
    "store_parameters": ObjectAddress(0x1010, 1),
    "heartbeat_time": ObjectAddress(0x1017),
    "vendor_id": ObjectAddress(0x1018, 1),
    "product_code": ObjectAddress(0x1018, 2),
    "sync_overflow": ObjectAddress(0x1019),
    "abort_connection": ObjectAddress(0x6007),
    "error_code": ObjectAddress(0x603F),
    "controlword": ObjectAddress(0x6040),
    "statusword": ObjectAddress(0x6041),
    "modes_of_operation": ObjectAddress(0x6060),
    "modes_display": ObjectAddress(0x6061),
    "position_actual": ObjectAddress(0x6064),
    "following_error_window": ObjectAddress(0x6065),  # position increments; 0xFFFFFFFF: monitor off
    "following_error_timeout": ObjectAddress(0x6066),  # ms
    "velocity_actual": ObjectAddress(0x606C),
    "target_torque": ObjectAddress(0x6071),
    "max_torque": ObjectAddress(0x6072),
    "torque_demand": ObjectAddress(0x6074),
    "rated_current": ObjectAddress(0x6075),
    "rated_torque": ObjectAddress(0x6076),
    "torque_actual": ObjectAddress(0x6077),
    "current_actual": ObjectAddress(0x6078),
    "target_position": ObjectAddress(0x607A),
    "position_limit_min": ObjectAddress(0x607D, 1),
    "position_limit_max": ObjectAddress(0x607D, 2),
    "max_velocity": ObjectAddress(0x6080),
    "encoder_increments": ObjectAddress(0x608F, 1),
    "motor_revolutions": ObjectAddress(0x608F, 2),
    "gear_motor_revs": ObjectAddress(0x6091, 1),
    "gear_shaft_revs": ObjectAddress(0x6091, 2),
    "feed": ObjectAddress(0x6092, 1),
    "feed_shaft_revs": ObjectAddress(0x6092, 2),
    "velocity_offset": ObjectAddress(0x60B1),
    "torque_offset": ObjectAddress(0x60B2),
    "interpolation_data": ObjectAddress(0x60C1, 1),
    "interpolation_period": ObjectAddress(0x60C2, 1),
    "interpolation_exponent": ObjectAddress(0x60C2, 2),
    "ip_buffer_max": ObjectAddress(0x60C4, 1),
    "ip_buffer_size": ObjectAddress(0x60C4, 2),
    "ip_buffer_organization": ObjectAddress(0x60C4, 3),
    "ip_buffer_clear": ObjectAddress(0x60C4, 6),
    "target_velocity": ObjectAddress(0x60FF),
    "supported_modes": ObjectAddress(0x6502),
}

#: CiA 402 modes of operation (0x6060 values).
MODE_CODES = {"pp": 1, "vl": 2, "pv": 3, "tq": 4, "hm": 6, "ip": 7, "csp": 8, "csv": 9, "cst": 10, "cstca": 11}
#: Bits of the supported drive modes object 0x6502.
MODE_BITS = {"pp": 0, "vl": 1, "pv": 2, "tq": 3, "hm": 5, "ip": 6, "csp": 7, "csv": 8, "cst": 9, "cstca": 10}
#: Modes in which the drive takes a new set-point every SYNC: the ones a host-streamed run uses.
CYCLIC_MODES = ("cst", "csv", "csp", "ip")
#: The set-point object of each cyclic mode.
SETPOINT_OF_MODE = {
    "cst": "target_torque",
    "csv": "target_velocity",
    "csp": "target_position",
    "ip": "interpolation_data",
}
#: Units of the channels hilident records from a CiA 402 drive.
CHANNEL_UNITS = {
    "excitation": "1",
    "torque_cmd_nm": "N*m",
    "torque_nm": "N*m",
    "position_m": "m",
    "velocity_mps": "m/s",
    "load_position_m": "m",
}


def decode_supported_modes(value: int) -> tuple[str, ...]:
    """Names of the modes a 0x6502 value declares, in bit order."""
    return tuple(name for name, bit in sorted(MODE_BITS.items(), key=lambda kv: kv[1]) if int(value) >> bit & 1)


def encode_supported_modes(names: Iterable[str]) -> int:
    """The 0x6502 value of a set of mode names (inverse of :func:`decode_supported_modes`)."""
    return sum(1 << MODE_BITS[n] for n in set(names))


def mode_name_of_code(code: int) -> str | None:
    """``"csp"`` for 8, ...; None for a manufacturer-specific or unknown code."""
    return next((name for name, c in MODE_CODES.items() if c == code), None)


def standard_objects(present: Callable[[ObjectAddress], bool]) -> dict[str, ObjectAddress]:
    """The standard roles whose object ``present(address)`` says the drive has."""
    return {role: addr for role, addr in STANDARD_OBJECTS.items() if present(addr)}


def standard_modes(
    objects: dict[str, ObjectAddress],
    supported: Iterable[str] | None,
    preference: Sequence[str] = CYCLIC_MODES,
    unmappable: Iterable[str] = (),
) -> dict[str, ModeSpec]:
    """hilident mode -> CiA 402 mode and set-point object, from what the drive has.

    Parameters
    ----------
    objects : dict
        Role -> address of the objects the drive has.
    supported : iterable of str or None
        Mode names the drive supports (0x6502); None: not known yet, every
        cyclic mode whose set-point object exists is assumed.
    preference : sequence of str
        Cyclic modes in the order the driver prefers them; modes not listed are not used.
    unmappable : iterable of str
        Roles whose object cannot be mapped into a PDO: a mode whose set-point is one of them is not streamed
        (a holding mode's set-point may be, it is written once by SDO).

    Returns
    -------
    dict
        ``torque`` (CST, 0x6071), ``velocity`` (CSV, 0x60FF), ``position`` (CSP
        0x607A, or IP 0x60C1:1), ``torque_injection`` (the excitation on the
        torque offset 0x60B2 while CSP, IP or CSV holds the axis), each only when
        the drive has the mode and its objects.
    """
    usable = [m for m in preference if m in CYCLIC_MODES and (supported is None or m in set(supported))]
    setpoint_of = SETPOINT_OF_MODE
    usable = [m for m in usable if setpoint_of[m] in objects]
    fixed = set(unmappable)
    streamable = [m for m in usable if setpoint_of[m] not in fixed]
    modes: dict[str, ModeSpec] = {}
    if "cst" in streamable:
        modes["torque"] = ModeSpec("torque", MODE_CODES["cst"], "target_torque")
    if "csv" in streamable:
        modes["velocity"] = ModeSpec("velocity", MODE_CODES["csv"], "target_velocity")
    position = next((m for m in streamable if m in ("csp", "ip")), None)
    if position is not None:
        modes["position"] = ModeSpec("position", MODE_CODES[position], setpoint_of[position])
    if "torque_offset" in objects and "torque_offset" not in fixed:
        # a position hold (CSP, else IP) is stiffer than a velocity hold (CSV)
        hold = next((m for m in ("csp", "ip", "csv") if m in usable), None)
        if hold is not None:
            modes["torque_injection"] = ModeSpec(
                "torque_injection", MODE_CODES[hold], "torque_offset", hold=setpoint_of[hold]
            )
    return modes


def standard_channels(objects: dict[str, ObjectAddress], current_as_torque: bool) -> dict[str, str | None]:
    """Channel name -> role of the object that carries it (None: recorded by the host).

    ``excitation`` is the set-point the host sent, unless the drive reports the
    one it applied (a vendor ``applied_excitation`` object). ``torque_nm`` is
    the torque actual value 0x6077, or the current actual value 0x6078 times
    the torque constant when ``current_as_torque``, or else the torque demand
    0x6074 (or the vendor object standing in for it).
    """
    channels: dict[str, str | None] = {"excitation": "applied_excitation" if "applied_excitation" in objects else None}
    if "torque_demand" in objects:
        channels["torque_cmd_nm"] = "torque_demand"
    if "torque_actual" in objects:
        channels["torque_nm"] = "torque_actual"
    elif current_as_torque and "current_actual" in objects:
        channels["torque_nm"] = "current_actual"
    elif "torque_demand" in objects:  # nothing measures the torque: the drive's command is the best there is
        channels["torque_nm"] = channels.pop("torque_cmd_nm")
    if "position_actual" in objects:
        channels["position_m"] = "position_actual"
    if "velocity_actual" in objects:
        channels["velocity_mps"] = "velocity_actual"
    return channels


def mapping_capacity(mapping) -> int:
    """How many objects a PDO mapping record (a canopen ``ODRecord``) takes: the highest sub-index its EDS
    declares (CiA 301: at most 64), and no more than the count sub-index 0 accepts (its HighLimit).

    Only when the EDS declares no entry at all is the highest count sub-index 0
    accepts taken: an entry the EDS does not declare cannot be written by name,
    even when sub-index 0 accepts a larger count (some files declare one entry
    with a limit of 64).
    """
    subs = getattr(mapping, "subindices", {})
    declared = max((sub for sub in subs if sub > 0), default=0)
    head = subs.get(0)
    high = head.max if head is not None and isinstance(head.max, int) else 0
    if declared and high:
        return min(64, declared, high)
    return min(64, declared or high)


def period_fields(period_s: float) -> tuple[int, int]:
    """0x60C2 (interpolation time period value, index) of ``period_s``: ``value * 10**index`` s.

    The largest exponent (-3 down to -6) that represents the period exactly in
    an UNSIGNED8 value.
    """
    for exponent in (-3, -4, -5, -6):
        value = period_s / 10.0**exponent
        if abs(value - round(value)) < 1e-6 and 1 <= round(value) <= 255:
            return int(round(value)), exponent
    raise ValueError(f"a period of {period_s:g} s has no 0x60C2 form (value 1..255 times 1e-3..1e-6 s)")


def period_from_fields(value: int, exponent: int) -> float:
    """Inverse of :func:`period_fields`: the period in s (0 when the value is 0)."""
    exponent = exponent - 256 if exponent > 127 else exponent  # INTEGER8 read as UNSIGNED8 by some EDS files
    return float(value) * math.pow(10.0, exponent)
