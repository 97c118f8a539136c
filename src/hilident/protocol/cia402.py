"""CiA 402 drive profile: statusword, controlword, the power state machine, mode codes, EMCY codes.

Both sides of the CANopen transport use this module: the host adapter decodes
the statusword and picks the next controlword on its way to *Operation
Enabled* (and back to a safe state), and the emulated drive runs
:func:`transition` on every controlword it receives. Pure functions on
integers; no bus, no clock.

The state machine (CiA 402-2, figure "Finite state automaton")::

    Not Ready To Switch On --1--> Switch On Disabled --2--> Ready To Switch On
        --3--> Switched On --4--> Operation Enabled
    Operation Enabled --5--> Switched On --6--> Ready To Switch On --7--> Switch On Disabled
    Operation Enabled --8 (shutdown)--> Ready To Switch On
    Operation Enabled / Switched On / Ready --9/10/7 (disable voltage)--> Switch On Disabled
    Operation Enabled --11 (quick stop)--> Quick Stop Active --12--> Switch On Disabled
    any --13 (fault)--> Fault Reaction Active --14--> Fault --15 (fault reset, bit 7 rising)--> Switch On Disabled

Examples
--------
>>> decode_statusword(0x0637) is State.OPERATION_ENABLED
True
>>> [hex(cw) for cw in path_to_operation_enabled(State.SWITCH_ON_DISABLED)]
['0x6', '0x7', '0xf']
>>> transition(State.SWITCHED_ON, 0x000F, 0x0007)
(<State.OPERATION_ENABLED: 'Operation Enabled'>, 4)
"""

from __future__ import annotations

from enum import Enum, IntEnum

from hilident.protocol.emcy_codes import CODES, emcy_name

__all__ = [
    "State",
    "Command",
    "ModeCode",
    "decode_statusword",
    "statusword",
    "command_of",
    "transition",
    "path_to_operation_enabled",
    "path_to_safe_state",
    "SAFE_STATES",
    "mode_name",
    "emcy_meaning",
    "EMCY_CODES",
    "FAULT_RESET_BIT",
]


class State(Enum):
    """Power states of a CiA 402 drive."""

    NOT_READY_TO_SWITCH_ON = "Not Ready To Switch On"
    SWITCH_ON_DISABLED = "Switch On Disabled"
    READY_TO_SWITCH_ON = "Ready To Switch On"
    SWITCHED_ON = "Switched On"
    OPERATION_ENABLED = "Operation Enabled"
    QUICK_STOP_ACTIVE = "Quick Stop Active"
    FAULT_REACTION_ACTIVE = "Fault Reaction Active"
    FAULT = "Fault"

    @property
    def torque_on(self) -> bool:
        """True when the power stage may produce torque."""
        return self in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)


#: States in which the power stage is off: where every exit path leaves the drive.
SAFE_STATES = (
    State.SWITCH_ON_DISABLED,
    State.READY_TO_SWITCH_ON,
    State.SWITCHED_ON,
    State.NOT_READY_TO_SWITCH_ON,
    State.FAULT,
)

# statusword bits 0-3, 5, 6: (mask, value) per state, CiA 402-2 table "state coding"
_STATE_CODING = (
    (0x4F, 0x00, State.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, State.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State.SWITCHED_ON),
    (0x6F, 0x27, State.OPERATION_ENABLED),
    (0x6F, 0x07, State.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State.FAULT),
)
_STATE_BITS = {state: value for _, value, state in _STATE_CODING}

SW_VOLTAGE_ENABLED = 1 << 4
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
FAULT_RESET_BIT = 1 << 7


def decode_statusword(sw: int) -> State:
    """The power state a statusword (0x6041) reports.

    Raises
    ------
    ValueError
        The bits match no state (a corrupt or non-CiA 402 value).
    """
    for mask, value, state in _STATE_CODING:
        if sw & mask == value:
            return state
    raise ValueError(f"statusword 0x{sw:04X} codes no CiA 402 state")


def statusword(
    state: State,
    *,
    voltage_enabled: bool = True,
    warning: bool = False,
    remote: bool = True,
    target_reached: bool = False,
    internal_limit: bool = False,
) -> int:
    """The statusword a drive reports in ``state`` (drive side)."""
    sw = _STATE_BITS[state]
    if state is State.QUICK_STOP_ACTIVE:
        sw &= ~0x20  # bit 5 (quick stop) is active-low: cleared while quick stop is active
    elif state not in (
        State.NOT_READY_TO_SWITCH_ON,
        State.SWITCH_ON_DISABLED,
        State.FAULT,
        State.FAULT_REACTION_ACTIVE,
    ):
        sw |= 0x20
    if voltage_enabled:
        sw |= SW_VOLTAGE_ENABLED
    if warning:
        sw |= SW_WARNING
    if remote:
        sw |= SW_REMOTE
    if target_reached:
        sw |= SW_TARGET_REACHED
    if internal_limit:
        sw |= SW_INTERNAL_LIMIT
    return sw


class Command(IntEnum):
    """Controlword (0x6040) device-control commands (bits 0-3 and 7)."""

    DISABLE_VOLTAGE = 0x0000
    QUICK_STOP = 0x0002
    SHUTDOWN = 0x0006
    SWITCH_ON = 0x0007
    DISABLE_OPERATION = 0x0007  # same coding as SWITCH_ON; the state decides
    ENABLE_OPERATION = 0x000F
    FAULT_RESET = 0x0080


def command_of(cw: int) -> str:
    """Which device-control command a controlword codes (drive side, CiA 402-2 table 'command coding').

    Returns one of ``"disable_voltage"``, ``"quick_stop"``, ``"shutdown"``,
    ``"switch_on"`` (also *disable operation*), ``"enable_operation"``,
    ``"fault_reset"`` (bit 7 set; a reset happens only on its rising edge).
    """
    if cw & FAULT_RESET_BIT:
        return "fault_reset"
    if not cw & 0x02:
        return "disable_voltage"
    if not cw & 0x04:
        return "quick_stop"
    if not cw & 0x01:
        return "shutdown"
    if not cw & 0x08:
        return "switch_on"
    return "enable_operation"


def transition(state: State, cw: int, previous_cw: int = 0) -> tuple[State, int]:
    """The state a drive enters on receiving controlword ``cw`` (drive side).

    Parameters
    ----------
    state : State
        Present state.
    cw, previous_cw : int
        New and previous controlword; a fault reset needs bit 7 to rise.

    Returns
    -------
    (State, int)
        New state and the CiA 402 transition number (0 when the state does not change).
    """
    cmd = command_of(cw)
    rising_reset = bool(cw & FAULT_RESET_BIT) and not previous_cw & FAULT_RESET_BIT
    S = State
    if state is S.FAULT:
        return (S.SWITCH_ON_DISABLED, 15) if rising_reset else (state, 0)
    if state in (S.NOT_READY_TO_SWITCH_ON, S.FAULT_REACTION_ACTIVE):
        return state, 0  # left automatically, never by command
    if cmd == "fault_reset":
        return state, 0  # bit 7 outside Fault: no command (CiA 402: fault reset has priority)
    table = {
        (S.SWITCH_ON_DISABLED, "shutdown"): (S.READY_TO_SWITCH_ON, 2),
        (S.READY_TO_SWITCH_ON, "switch_on"): (S.SWITCHED_ON, 3),
        (S.READY_TO_SWITCH_ON, "enable_operation"): (S.OPERATION_ENABLED, 4),  # "switch on + enable": 3 then 4
        (S.READY_TO_SWITCH_ON, "disable_voltage"): (S.SWITCH_ON_DISABLED, 7),
        (S.READY_TO_SWITCH_ON, "quick_stop"): (S.SWITCH_ON_DISABLED, 7),
        (S.SWITCHED_ON, "enable_operation"): (S.OPERATION_ENABLED, 4),
        (S.SWITCHED_ON, "shutdown"): (S.READY_TO_SWITCH_ON, 6),
        (S.SWITCHED_ON, "disable_voltage"): (S.SWITCH_ON_DISABLED, 10),
        (S.SWITCHED_ON, "quick_stop"): (S.SWITCH_ON_DISABLED, 10),
        (S.OPERATION_ENABLED, "switch_on"): (S.SWITCHED_ON, 5),
        (S.OPERATION_ENABLED, "shutdown"): (S.READY_TO_SWITCH_ON, 8),
        (S.OPERATION_ENABLED, "disable_voltage"): (S.SWITCH_ON_DISABLED, 9),
        (S.OPERATION_ENABLED, "quick_stop"): (S.QUICK_STOP_ACTIVE, 11),
        (S.QUICK_STOP_ACTIVE, "disable_voltage"): (S.SWITCH_ON_DISABLED, 12),
        (S.QUICK_STOP_ACTIVE, "enable_operation"): (S.OPERATION_ENABLED, 16),
    }
    return table.get((state, cmd), (state, 0))


def path_to_operation_enabled(state: State, allow_fault_reset: bool = False) -> list[int]:
    """Controlwords that take a drive from ``state`` to Operation Enabled (host side).

    Raises
    ------
    ValueError
        ``state`` is Fault (or Fault Reaction Active) and ``allow_fault_reset``
        is False, or the drive is still initialising.
    """
    S, C = State, Command
    if state in (S.FAULT, S.FAULT_REACTION_ACTIVE):
        if not allow_fault_reset:
            raise ValueError(f"drive is in {state.value}; a fault reset was not allowed")
        # bit 7 must rise: clear it first, then set it
        return [C.DISABLE_VOLTAGE, C.FAULT_RESET, C.SHUTDOWN, C.SWITCH_ON, C.ENABLE_OPERATION]
    paths = {
        S.NOT_READY_TO_SWITCH_ON: None,
        S.SWITCH_ON_DISABLED: [C.SHUTDOWN, C.SWITCH_ON, C.ENABLE_OPERATION],
        S.READY_TO_SWITCH_ON: [C.SWITCH_ON, C.ENABLE_OPERATION],
        S.SWITCHED_ON: [C.ENABLE_OPERATION],
        S.OPERATION_ENABLED: [],
        S.QUICK_STOP_ACTIVE: [C.DISABLE_VOLTAGE, C.SHUTDOWN, C.SWITCH_ON, C.ENABLE_OPERATION],
    }
    path = paths[state]
    if path is None:
        raise ValueError(f"drive is still initialising ({state.value})")
    return [int(c) for c in path]


def path_to_safe_state(state: State) -> list[int]:
    """Controlwords that switch the power stage off from ``state`` (host side).

    Disable Voltage (transitions 7, 9, 10, 12) drops to Switch On Disabled at
    once: zero torque, whatever the state. A drive in Fault stays there (its
    power stage is already off).
    """
    if state in (State.FAULT, State.FAULT_REACTION_ACTIVE, State.NOT_READY_TO_SWITCH_ON, State.SWITCH_ON_DISABLED):
        return []
    return [int(Command.DISABLE_VOLTAGE)]


class ModeCode(IntEnum):
    """Modes of operation (0x6060 / 0x6061) used here."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CSP = 8  # cyclic synchronous position
    CSV = 9  # cyclic synchronous velocity
    CST = 10  # cyclic synchronous torque


def mode_name(code: int) -> str:
    """Readable name of a mode-of-operation code; negative codes are manufacturer specific."""
    names: dict[int, str] = {
        ModeCode.NO_MODE: "no mode",
        ModeCode.PROFILE_POSITION: "profile position",
        ModeCode.PROFILE_VELOCITY: "profile velocity",
        ModeCode.PROFILE_TORQUE: "profile torque",
        ModeCode.HOMING: "homing",
        ModeCode.INTERPOLATED_POSITION: "interpolated position",
        ModeCode.CSP: "cyclic synchronous position (CSP)",
        ModeCode.CSV: "cyclic synchronous velocity (CSV)",
        ModeCode.CST: "cyclic synchronous torque (CST)",
    }
    if code < 0:
        return f"manufacturer-specific mode {code}"
    return names.get(code, f"reserved mode {code}")


#: Emergency error codes of CiA 301 and CiA 402 with their names (see :mod:`hilident.protocol.emcy_codes`).
EMCY_CODES = CODES


def emcy_meaning(code: int) -> str:
    """What an emergency error code means: its CiA 301/402 name, else its group's or class's.

    See :func:`hilident.protocol.emcy_codes.emcy_name` (0xFF00-0xFFFF read
    ``"manufacturer-specific 0xFFnn (device specific)"``). A value outside
    0x0000-0xFFFF reads ``"invalid error code ..."`` rather than raising: the
    text goes into error messages.
    """
    try:
        return emcy_name(code)
    except ValueError:
        return f"invalid error code {code!r}"
