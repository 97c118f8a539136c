"""Replay recorded wire exchanges to an adapter: :func:`expected_exchanges`, in the style of pymeasure's
``expected_protocol``.

A transcript is what the host sent and what the device answered, recorded once
from hilident's twins (``tests/support/record_transcripts.py``) and stored as JSON in
``tests/data/transcripts/``. Replaying it needs no twin: a fake device answers
every request with the recorded answer, fails on any request the transcript
does not expect next, and the ``with`` block asserts at its end that every
exchange was used.

Two fakes, one per kind of wire:

- a byte stream (the serial board's COBS frames over ``socket://``, Modbus TCP's
  MBAP frames): :class:`StreamDevice`, a TCP server on 127.0.0.1 that matches
  the bytes the host writes against the next request, whatever chunks they
  arrive in;
- CAN frames (CANopen): :class:`CanDevice`, a participant of a python-can
  ``virtual`` channel that matches each frame the host sends against the next
  request frame (frames the host sends on its own timer, its heartbeat, are
  listed in ``periodic`` and never matched).

Transcript format (JSON)::

    {"transport": "serial" | "modbus" | "canopen",
     "wire": "stream" | "can",
     "settings": {...},                    # what the recording used (driver, seed, ...)
     "periodic": [cob_id, ...],            # CAN only: host frames never matched
     "exchanges": [{"send": REQUEST, "receive": [ANSWER, ...]}, ...]}

where a stream REQUEST or ANSWER is a hex string and a CAN one is
``[arbitration_id, hex data]``.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

TRANSCRIPTS = Path(__file__).resolve().parents[1] / "data" / "transcripts"


@dataclass
class Exchange:
    """One request of the host and what the device answered before the next one."""

    send: object
    receive: list = field(default_factory=list)


@dataclass
class Transcript:
    """A recorded conversation, loaded from or saved to ``tests/data/transcripts/NAME.json``."""

    transport: str
    wire: str
    exchanges: list[Exchange]
    settings: dict = field(default_factory=dict)
    periodic: list[int] = field(default_factory=list)

    @classmethod
    def load(cls, name: str) -> Transcript:
        raw = json.loads((TRANSCRIPTS / f"{name}.json").read_text())
        decode = _decode_stream if raw["wire"] == "stream" else _decode_can
        exchanges = [Exchange(decode(e["send"]), [decode(r) for r in e["receive"]]) for e in raw["exchanges"]]
        return cls(raw["transport"], raw["wire"], exchanges, raw.get("settings", {}), raw.get("periodic", []))

    def save(self, name: str) -> Path:
        encode = _encode_stream if self.wire == "stream" else _encode_can
        raw = {
            "transport": self.transport,
            "wire": self.wire,
            "settings": self.settings,
            "periodic": self.periodic,
            "exchanges": [{"send": encode(e.send), "receive": [encode(r) for r in e.receive]} for e in self.exchanges],
        }
        path = TRANSCRIPTS / f"{name}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(raw, indent=1) + "\n")
        return path


def _encode_stream(data: bytes) -> str:
    return data.hex()


def _decode_stream(text: str) -> bytes:
    return bytes.fromhex(text)


def _encode_can(frame: tuple[int, bytes]) -> list:
    return [frame[0], frame[1].hex()]


def _decode_can(item: list) -> tuple[int, bytes]:
    return int(item[0]), bytes.fromhex(item[1])


class UnexpectedExchange(AssertionError):
    """The host sent something the transcript does not expect next."""


class _Replay:
    """What both fakes share: the exchanges still to come, and the first failure."""

    def __init__(self, transcript: Transcript):
        self.transcript = transcript
        self.pending = list(transcript.exchanges)
        self.used = 0
        self.failure: str | None = None
        self.lock = threading.Lock()

    def fail(self, message: str) -> None:
        with self.lock:
            self.failure = self.failure or message

    def check(self) -> None:
        """Raise the first failure, then fail when exchanges were left unused."""
        if self.failure:
            raise UnexpectedExchange(self.failure)
        if self.pending:
            nxt = self.pending[0].send
            raise AssertionError(
                f"{len(self.pending)} of {self.used + len(self.pending)} exchanges were never "
                f"used; the next one expected the host to send {_show(nxt)}"
            )


def _show(item) -> str:
    if isinstance(item, (bytes, bytearray)):
        return bytes(item).hex(" ")
    return f"0x{item[0]:03X} [{item[1].hex(' ')}]"


class StreamDevice(_Replay):
    """A device on a TCP byte stream that answers from a transcript (one connection, then it is done).

    Attributes
    ----------
    port : int
        The listening port on 127.0.0.1.
    """

    def __init__(self, transcript: Transcript):
        super().__init__(transcript)
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.settimeout(0.1)
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="replay-stream", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        conn = self._accept()
        if conn is None:
            return
        with conn:
            conn.settimeout(0.05)
            buffer = b""
            while not self._stop.is_set() and self.failure is None:
                try:
                    chunk = conn.recv(65536)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not chunk:
                    return
                buffer = self._answer(conn, buffer + chunk)

    def _accept(self):
        while not self._stop.is_set():
            try:
                return self._server.accept()[0]
            except TimeoutError:
                continue
            except OSError:
                return None
        return None

    def _answer(self, conn: socket.socket, buffer: bytes) -> bytes:
        """Answer every whole request at the start of ``buffer``; the rest (a request's first part) is kept."""
        while buffer:
            if not self.pending:
                self.fail(f"the host sent {_show(buffer)} after the transcript's last exchange")
                return b""
            want = self.pending[0].send
            if buffer.startswith(want):
                exchange = self.pending.pop(0)
                self.used += 1
                buffer = buffer[len(want) :]
                for answer in exchange.receive:
                    conn.sendall(answer)
            elif want.startswith(buffer):
                return buffer  # the rest of the request is on its way
            else:
                self.fail(f"exchange {self.used}: expected the host to send {_show(want)}, got {_show(buffer)}")
                return b""
        return b""

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self._server.close()
        self._thread.join(2.0)


class CanDevice(_Replay):
    """A device on a python-can ``virtual`` channel that answers from a transcript."""

    def __init__(self, transcript: Transcript, channel: str):
        import can

        super().__init__(transcript)
        self._can = can
        self.channel = channel
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._periodic = set(transcript.periodic)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="replay-can", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set() and self.failure is None:
            msg = self._bus.recv(0.05)
            if msg is None or msg.arbitration_id in self._periodic:
                continue
            self._answer((msg.arbitration_id, bytes(msg.data)))

    def _answer(self, frame: tuple[int, bytes]) -> None:
        if not self.pending:
            self.fail(f"the host sent {_show(frame)} after the transcript's last exchange")
            return
        want = self.pending[0].send
        if frame != want:
            self.fail(f"exchange {self.used}: expected the host to send {_show(want)}, got {_show(frame)}")
            return
        exchange = self.pending.pop(0)
        self.used += 1
        for cob_id, data in exchange.receive:
            self._bus.send(self._can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._bus.shutdown()


@contextlib.contextmanager
def expected_exchanges(transcript: Transcript | str, channel: str | None = None):
    """A fake device that answers from ``transcript``; on leaving the block, every exchange must have been used.

    Parameters
    ----------
    transcript : Transcript or str
        The transcript, or its name in ``tests/data/transcripts/``.
    channel : str, optional
        CAN transcripts: the python-can ``virtual`` channel the fake device
        joins (the adapter opens the same one).

    Yields
    ------
    StreamDevice or CanDevice
        ``.port`` (stream) or ``.channel`` (CAN) is where the adapter connects.

    Raises
    ------
    UnexpectedExchange
        The host sent a request the transcript does not expect next.
    AssertionError
        Exchanges were left unused.
    """
    if isinstance(transcript, str):
        transcript = Transcript.load(transcript)
    if transcript.wire == "stream":
        device: _Replay = StreamDevice(transcript)
    else:
        device = CanDevice(transcript, channel or f"replay-{id(transcript)}")
    try:
        yield device
        _settle(device)
    except BaseException as exc:
        device.close()
        if device.failure:  # the adapter's error is a consequence: name the cause
            raise UnexpectedExchange(device.failure) from exc
        raise
    device.close()
    device.check()


def _settle(device: _Replay, timeout_s: float = 2.0) -> None:
    """Give the fake device's thread time to take the host's last request."""
    deadline = time.monotonic() + timeout_s
    while device.pending and device.failure is None and time.monotonic() < deadline:
        time.sleep(0.01)
