"""Record the wire transcripts of ``tests/data/transcripts/`` from hilident's twins.

Run from the repository root when a protocol or an adapter changes what it
sends on purpose::

    PYTHONPATH=src:tests python tests/support/record_transcripts.py [serial modbus modbus-rtu canopen]

For each transport a twin of the shipped emulated config is served (serial
board and Modbus drive on TCP, the Modbus drive's RTU line through a TCP tap, the CANopen drive on
python-can's ``virtual`` bus), the adapter runs :func:`conversation` against it through a recording
tap, and what the host sent and the device answered is saved as one
transcript. ``tests/adapters/test_replay.py`` plays each one back with no twin.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

from hilident.adapters.backends import adapter_class
from hilident.config.tables import load_config
from hilident.drivers.description import find_driver
from hilident.filters.notch import NotchSpec, design_notch
from support.exchanges import Exchange, Transcript

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

#: transport -> (shipped config, driver)
SOURCES = {
    "serial": "emulated-gantry.toml",
    "modbus": "emulated-modbus-gantry.toml",
    "canopen": "emulated-canopen-gantry.toml",
}

#: The serial adapter starts its sequence numbers at a random value; a transcript needs a fixed one.
SERIAL_SEQ_START = 0x1234

#: The notch written and read back in every transcript.
NOTCH = NotchSpec(center_hz=21.8, width_hz=6.0, depth_db=20.0)


def settings(transport: str):
    """The shipped config's emulator and ``[device]`` settings, and its driver: a clean, deterministic twin."""
    cfg = load_config(CONFIGS / SOURCES[transport])
    emulator = replace(cfg.emulator, preset="clean", time_scale=1.0)
    return emulator, cfg.device, find_driver(cfg.device.driver, cfg.device.driver_paths)


def conversation(adapter_cls, device, driver, sample_rate_hz: float) -> None:
    """What every transcript records: connect and identify, write a notch and read it back, stop, close."""
    adapter = adapter_cls.open_device(device, driver)
    try:
        upload = adapter.upload_filter(0, design_notch(NOTCH, sample_rate_hz), NOTCH)
        assert upload.matches, upload
        adapter.safe_stop()
    finally:
        adapter.close()


def fixed_serial_sequence():
    """Patch the serial adapter's random first sequence number (returns the undo)."""
    from hilident.adapters.serial import board as serial_board

    real = serial_board.secrets.randbelow
    serial_board.secrets.randbelow = lambda n: SERIAL_SEQ_START % n

    def undo():
        serial_board.secrets.randbelow = real

    return undo


# --- byte streams: a recording TCP tap -------------------------------------------------------------------------


class StreamTap:
    """A TCP relay between the host and a twin that keeps every chunk, in order, with its direction."""

    def __init__(self, upstream: tuple[str, int] | str):
        self.upstream = upstream  # (host, port) of a TCP twin, or the pseudo-terminal of an RTU twin
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.chunks: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        host, _ = self.server.accept()
        host.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if isinstance(self.upstream, str):
            device = _LineEnd(self.upstream)
        else:
            device = socket.create_connection(self.upstream)
            device.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=self._relay, args=(host, device, "send"), daemon=True).start()
        self._relay(device, host, "receive")

    def _relay(self, src: socket.socket, dst: socket.socket, direction: str) -> None:
        while True:
            try:
                data = src.recv(65536)
            except OSError:
                data = b""
            if not data:
                for sock in (src, dst):
                    try:
                        sock.shutdown(socket.SHUT_RDWR)
                    except OSError:
                        pass
                return
            with self.lock:
                self.chunks.append((direction, data))
            dst.sendall(data)

    def exchanges(self) -> list[Exchange]:
        """Host chunks in a row make one request; the device's chunks after it are its answers."""
        out: list[Exchange] = []
        for direction, data in self.chunks:
            if direction == "send":
                if out and not out[-1].receive:
                    out[-1].send += data
                else:
                    out.append(Exchange(bytes(data)))
            else:
                assert out, "the device spoke first"
                out[-1].receive.append(bytes(data))
        return out


class _LineEnd:
    """A serial line (the RTU twin's pseudo-terminal) with the socket calls the tap uses."""

    def __init__(self, port: str):
        import serial

        self.line = serial.serial_for_url(port, timeout=0.01)
        self.closed = False

    def recv(self, size: int) -> bytes:
        while not self.closed:
            data = self.line.read(size)
            if data:
                return data
        return b""

    def sendall(self, data: bytes) -> None:
        self.line.write(data)

    def shutdown(self, how) -> None:
        self.closed = True


def record_stream(transport: str, link: str = "tcp") -> Transcript:
    from hilident.emulator.factory import start_standalone

    emulator, device, driver = settings(transport)
    emu = start_standalone(emulator, driver, device, link)
    undo = fixed_serial_sequence()
    try:
        if link == "rtu":
            tap = StreamTap(emu.device.port)
            reach = replace(emu.device, port=f"socket://127.0.0.1:{tap.port}")
        else:
            prefix = "socket://" if transport == "serial" else "tcp://"
            host, _, port = emu.device.port[len(prefix) :].rpartition(":")
            tap = StreamTap((host, int(port)))
            reach = replace(emu.device, port=f"{prefix}127.0.0.1:{tap.port}")
        conversation(adapter_class(transport), reach, driver, sample_rate_hz(transport))
        time.sleep(0.3)  # the last answers through the tap
    finally:
        undo()
        emu.close()
    return Transcript(transport, "stream", tap.exchanges(), _settings_note(transport, driver) | {"link": link})


# --- CAN: a listener on the twin's virtual channel ---------------------------------------------------------------


def _from_host(cob_id: int, node: int) -> bool:
    """Frames the host sends: NMT, SYNC, RPDOs and SDO requests to ``node``, and its own heartbeat."""
    function = cob_id & ~0x7F
    return (
        cob_id in (0x000, 0x080)
        or (cob_id & 0x7F == node and function in (0x200, 0x300, 0x400, 0x500, 0x600))
        or (function == 0x700 and cob_id & 0x7F != node)
    )


def record_can() -> Transcript:
    import can

    from hilident.emulator.canopen.server import start

    emulator, device, driver = settings("canopen")
    emu = start(emulator, driver, device)
    listener = can.Bus(interface="virtual", channel=emu.device.port, receive_own_messages=False)
    frames: list[tuple[int, bytes]] = []
    stop = threading.Event()

    def listen():
        while not stop.is_set():
            msg = listener.recv(0.05)
            if msg is not None:
                frames.append((msg.arbitration_id, bytes(msg.data)))

    thread = threading.Thread(target=listen, daemon=True)
    thread.start()
    try:
        conversation(adapter_class("canopen"), emu.device, driver, sample_rate_hz("canopen"))
        time.sleep(0.3)
    finally:
        stop.set()
        thread.join()
        listener.shutdown()
        emu.close()
    node = emu.device.canopen.node_id
    host_heartbeat = 0x700 + int(driver.sections.get("canopen", {}).get("host_node_id", 127))
    exchanges: list[Exchange] = []
    for cob_id, data in frames:
        if cob_id == host_heartbeat:
            continue  # sent on the host's own timer: never matched
        if _from_host(cob_id, node):
            exchanges.append(Exchange((cob_id, data)))
        elif exchanges:
            exchanges[-1].receive.append((cob_id, data))
    note = _settings_note("canopen", driver)
    return Transcript("canopen", "can", exchanges, note, periodic=[host_heartbeat])


def sample_rate_hz(transport: str) -> float:
    return load_config(CONFIGS / SOURCES[transport]).run.sample_rate_hz


def _settings_note(transport: str, driver) -> dict:
    return {
        "config": SOURCES[transport],
        "driver": driver.name,
        "notch": [NOTCH.center_hz, NOTCH.width_hz, NOTCH.depth_db],
        "serial_seq_start": SERIAL_SEQ_START if transport == "serial" else None,
        "conversation": "open_device (connect, identify, known state), upload_filter(0) "
        "(save, write disabled, read back, write enabled, read back), safe_stop, close",
    }


#: transcript name -> how it is recorded
RECORDINGS = {
    "serial": lambda: record_stream("serial"),
    "modbus": lambda: record_stream("modbus"),
    "modbus-rtu": lambda: record_stream("modbus", "rtu"),
    "canopen": record_can,
}


def record(name: str) -> Path:
    return RECORDINGS[name]().save(name)


if __name__ == "__main__":
    for name in sys.argv[1:] or list(RECORDINGS):
        path = record(name)
        print(f"{name}: {path} ({path.stat().st_size} bytes)")
