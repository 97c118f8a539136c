"""Each adapter against its recorded wire transcript, with no twin (``tests/support/exchanges.py``).

The transcripts in ``tests/data/transcripts/`` were recorded from the twins by
``tests/support/record_transcripts.py``: connect and identify, a notch written and read
back, the stop, the close. A request the transcript does not expect fails the
test; so does an exchange left unused.
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from hilident.adapters.backends import adapter_class
from support.exchanges import Exchange, Transcript, UnexpectedExchange, expected_exchanges
from support.record_transcripts import conversation, fixed_serial_sequence, sample_rate_hz, settings

#: Every transcript (``tests/data/transcripts/NAME.json``); Modbus RTU reaches its fake line over ``socket://``.
TRANSCRIPTS = ["serial", "modbus", "modbus-rtu", "canopen"]


def _reach(name: str, fake) -> object:
    """The ``[device]`` settings that reach the fake device."""
    _, device, _ = settings(_transport(name))
    if name == "canopen":
        return replace(device, can_interface="virtual", port=fake.channel, timeout_s=0.5)
    prefix = "tcp://" if name == "modbus" else "socket://"
    return replace(device, port=f"{prefix}127.0.0.1:{fake.port}", timeout_s=0.5)


def _transport(name: str) -> str:
    return name.split("-")[0]


@pytest.fixture
def fixed_sequence():
    undo = fixed_serial_sequence()
    yield
    undo()


def _converse(name: str, transcript) -> None:
    transport = _transport(name)
    _, _, driver = settings(transport)
    with expected_exchanges(transcript) as fake:
        conversation(adapter_class(transport), _reach(name, fake), driver, sample_rate_hz(transport))


@pytest.mark.parametrize("name", TRANSCRIPTS)
def test_the_adapter_holds_the_recorded_conversation(name, fixed_sequence):
    transcript = Transcript.load(name)
    assert transcript.transport == _transport(name) and transcript.exchanges
    _converse(name, transcript)


@pytest.mark.parametrize("name", TRANSCRIPTS)
def test_a_request_the_transcript_does_not_expect_fails(name, fixed_sequence):
    transcript = Transcript.load(name)
    first = transcript.exchanges[0]
    wrong = (
        bytes([first.send[0] ^ 0xFF]) + first.send[1:]
        if transcript.wire == "stream"
        else (first.send[0], bytes([first.send[1][0] ^ 0xFF]) + first.send[1][1:])
    )
    transcript.exchanges[0] = Exchange(wrong, first.receive)
    with pytest.raises(UnexpectedExchange, match="exchange 0: expected the host to send"):
        _converse(name, transcript)


@pytest.mark.parametrize("name", TRANSCRIPTS)
def test_an_exchange_left_unused_fails(name, fixed_sequence):
    transcript = Transcript.load(name)
    transcript.exchanges.append(Exchange(transcript.exchanges[-1].send, []))
    with pytest.raises(AssertionError, match="1 of .* exchanges were never used"):
        _converse(name, transcript)
