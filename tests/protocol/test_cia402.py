"""CiA 402 state machine: statusword/controlword coding and transitions, checked against the profile's tables."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilident.protocol import cia402
from hilident.protocol.cia402 import Command, State, transition

S = State

# CiA 402-2, "state coding" of the statusword (x = don't care): bits 6,5,3,2,1,0
STATE_CODING = {
    S.NOT_READY_TO_SWITCH_ON: 0x0000,
    S.SWITCH_ON_DISABLED: 0x0040,
    S.READY_TO_SWITCH_ON: 0x0021,
    S.SWITCHED_ON: 0x0023,
    S.OPERATION_ENABLED: 0x0027,
    S.QUICK_STOP_ACTIVE: 0x0007,
    S.FAULT_REACTION_ACTIVE: 0x000F,
    S.FAULT: 0x0008,
}
# bits that never change the state: voltage enabled (4), warning (7), remote (9),
# target reached (10), internal limit (11), mode-specific (12, 13), manufacturer (8, 14, 15)
FREE_BITS = 0x0010 | 0x0080 | 0x0100 | 0x0200 | 0x0400 | 0x0800 | 0x1000 | 0x2000 | 0x4000 | 0x8000


@given(st.sampled_from(sorted(STATE_CODING, key=lambda s: s.value)), st.integers(0, 0xFFFF))
def test_statusword_decodes_whatever_the_other_bits(state, noise):
    sw = STATE_CODING[state] | (noise & FREE_BITS)
    if state in (S.NOT_READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED, S.FAULT, S.FAULT_REACTION_ACTIVE):
        sw |= noise & 0x20  # bit 5 is don't-care in these states
    assert cia402.decode_statusword(sw) is state


@pytest.mark.parametrize("state", list(S))
def test_drive_statusword_round_trips(state):
    for flags in ({}, {"warning": True, "target_reached": True, "internal_limit": True}):
        assert cia402.decode_statusword(cia402.statusword(state, **flags)) is state
    sw = cia402.statusword(state, internal_limit=True)
    assert sw & (1 << 11) and sw & (1 << 9)  # internal limit, remote


def test_unknown_statusword_is_refused():
    with pytest.raises(ValueError, match="0x0001"):
        cia402.decode_statusword(0x0001)  # "ready" bit without "switch on disabled" or bit 5


# CiA 402-2 "command coding": controlword bits 7, 3, 2, 1, 0 (x = don't care)
@pytest.mark.parametrize(
    "cw, command",
    [
        (0x0006, "shutdown"),
        (0x000E, "shutdown"),  # 0 x 1 1 0
        (0x0007, "switch_on"),  # 0 0 1 1 1 (also disable operation)
        (0x000F, "enable_operation"),  # 0 1 1 1 1
        (0x0000, "disable_voltage"),
        (0x0001, "disable_voltage"),
        (0x000D, "disable_voltage"),  # 0 x x 0 x
        (0x0002, "quick_stop"),
        (0x000B, "quick_stop"),  # 0 x 0 1 x
        (0x0080, "fault_reset"),
        (0x008F, "fault_reset"),
    ],
)
def test_controlword_command_coding(cw, command):
    assert cia402.command_of(cw) == command


# transitions numbered as in CiA 402-2 figure "state machine"
@pytest.mark.parametrize(
    "state, cw, new, number",
    [
        (S.SWITCH_ON_DISABLED, 0x06, S.READY_TO_SWITCH_ON, 2),
        (S.READY_TO_SWITCH_ON, 0x07, S.SWITCHED_ON, 3),
        (S.SWITCHED_ON, 0x0F, S.OPERATION_ENABLED, 4),
        (S.OPERATION_ENABLED, 0x07, S.SWITCHED_ON, 5),
        (S.SWITCHED_ON, 0x06, S.READY_TO_SWITCH_ON, 6),
        (S.READY_TO_SWITCH_ON, 0x00, S.SWITCH_ON_DISABLED, 7),
        (S.READY_TO_SWITCH_ON, 0x02, S.SWITCH_ON_DISABLED, 7),
        (S.OPERATION_ENABLED, 0x06, S.READY_TO_SWITCH_ON, 8),
        (S.OPERATION_ENABLED, 0x00, S.SWITCH_ON_DISABLED, 9),
        (S.SWITCHED_ON, 0x00, S.SWITCH_ON_DISABLED, 10),
        (S.OPERATION_ENABLED, 0x02, S.QUICK_STOP_ACTIVE, 11),
        (S.QUICK_STOP_ACTIVE, 0x00, S.SWITCH_ON_DISABLED, 12),
        (S.QUICK_STOP_ACTIVE, 0x0F, S.OPERATION_ENABLED, 16),
    ],
)
def test_numbered_transitions(state, cw, new, number):
    assert transition(state, cw, 0) == (new, number)


def test_commands_that_do_not_apply_leave_the_state():
    assert transition(S.SWITCH_ON_DISABLED, 0x0F, 0) == (S.SWITCH_ON_DISABLED, 0)  # no 2->4 jump
    assert transition(S.OPERATION_ENABLED, 0x0F, 0x0F) == (S.OPERATION_ENABLED, 0)
    assert transition(S.FAULT, 0x0F, 0) == (S.FAULT, 0)
    assert transition(S.FAULT_REACTION_ACTIVE, 0x80, 0) == (S.FAULT_REACTION_ACTIVE, 0)
    assert transition(S.NOT_READY_TO_SWITCH_ON, 0x06, 0) == (S.NOT_READY_TO_SWITCH_ON, 0)


def test_fault_reset_needs_a_rising_edge_of_bit_7():
    assert transition(S.FAULT, 0x80, 0x80) == (S.FAULT, 0)
    assert transition(S.FAULT, 0x80, 0x00) == (S.SWITCH_ON_DISABLED, 15)
    assert transition(S.FAULT, 0x86, 0x06) == (S.SWITCH_ON_DISABLED, 15)
    assert transition(S.OPERATION_ENABLED, 0x80, 0) == (S.OPERATION_ENABLED, 0)  # no fault: nothing to reset


def _walk(state, controlwords):
    previous = 0
    for cw in controlwords:
        state, _ = transition(state, cw, previous)
        previous = cw
    return state


@pytest.mark.parametrize("state", [s for s in S if s is not S.NOT_READY_TO_SWITCH_ON])
def test_host_path_reaches_operation_enabled_on_the_drive_side(state):
    path = cia402.path_to_operation_enabled(state, allow_fault_reset=True)
    assert _walk(state, path) is S.OPERATION_ENABLED or state is S.FAULT_REACTION_ACTIVE


def test_path_refuses_fault_reset_unless_allowed():
    with pytest.raises(ValueError, match="Fault"):
        cia402.path_to_operation_enabled(S.FAULT)
    assert Command.FAULT_RESET in cia402.path_to_operation_enabled(S.FAULT, allow_fault_reset=True)
    with pytest.raises(ValueError, match="initialising"):
        cia402.path_to_operation_enabled(S.NOT_READY_TO_SWITCH_ON)


@pytest.mark.parametrize("state", list(S))
def test_safe_path_switches_the_power_stage_off(state):
    end = _walk(state, cia402.path_to_safe_state(state))
    if state is not S.FAULT_REACTION_ACTIVE:  # left by the drive itself
        assert not end.torque_on and end in cia402.SAFE_STATES


def test_mode_codes_and_names():
    assert (cia402.ModeCode.CST, cia402.ModeCode.CSV, cia402.ModeCode.CSP) == (10, 9, 8)
    assert "CST" in cia402.mode_name(10) and "CSP" in cia402.mode_name(8)
    assert "manufacturer" in cia402.mode_name(-3)


@pytest.mark.parametrize(
    "code, text",
    [
        (0x8311, "excess torque"),
        (0x8612, "reference limit"),
        (0x4310, "temperature"),
        (0x2311, "current"),
        (0x3222, "voltage"),
        (0xFF42, "device specific"),
        (0x8130, "heartbeat"),
    ],
)
def test_emcy_meanings(code, text):
    assert text in cia402.emcy_meaning(code)
